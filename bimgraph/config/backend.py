"""Settings of the backend (bimgraph run): noise models, association, iSAM2, offline estimation."""

from __future__ import annotations

from pydantic import Field

from bimgraph.config.section import Section


class NoiseConfig(Section):
    """Backend noise models (one sigma)."""

    prior_first_pose_rot_deg: float = Field(0.001, gt=0, le=180, description="prior on the first keyframe pose: fixes the gauge of S (rotation)")
    prior_first_pose_trans_m: float = Field(0.0001, gt=0, le=1000, description="prior on the first keyframe pose: fixes the gauge of S (translation)")
    odometry_rot_deg: float = Field(0.1, gt=0, le=180, description="front-end relative pose between keyframes when a keyframe has no cov (rotation)")
    odometry_trans_m: float = Field(0.005, gt=0, le=1000, description="front-end relative pose between keyframes when a keyframe has no cov (translation)")
    plane_normal_deg: float = Field(1.0, gt=0, le=180, description="plane observation when it has no cov: normal")
    plane_offset_m: float = Field(0.02, gt=0, le=1000, description="plane observation when it has no cov: offset")
    plane_min_normal_deg: float = Field(0.01, gt=0, le=180, description="a plane observation's covariance is floored at this normal sigma... (no sensor resolves a wall's plane finer; far overconfident covariances made iSAM2's system singular)")
    plane_min_offset_m: float = Field(0.0001, gt=0, le=1000, description="...and this offset sigma")
    plane_kernel: str = Field("huber", pattern="^(none|huber|cauchy)$", description="robust kernel on plane observations (none, huber, cauchy)")
    plane_kernel_width: float = Field(2.0, gt=0, description="kernel width of plane observations, in sigmas")
    bim_normal_deg: float = Field(1.0, gt=0, le=180, description="plane-to-BIM factor: how far an as-built wall's normal strays from plan (a tilt about the face's centre)")
    bim_offset_m: float = Field(0.01, gt=0, le=1000, description="plane-to-BIM factor: how far an as-built wall's offset, at the face's centre, strays from plan (one sigma: the common +/-2 cm wall tolerance as a 95 % bound, so that the robust alignment keeps whole only walls within about 3.4 cm of plan; at 1.5 cm it kept walls built 3-5 cm off, which pulled the poses)")
    bim_kernel: str = Field("cauchy", pattern="^(none|huber|cauchy)$", description="robust kernel on plane-to-BIM factors until the robust alignment has judged them (offline; online with isam2.judge_every), Gaussian after (a Gaussian one before lets one wrong match move the extrinsic)")
    bim_kernel_width: float = Field(1.0, gt=0, description="kernel width of plane-to-BIM factors, in sigmas")
    gravity_deg: float = Field(0.1, gt=0, le=180, description="gravity-aligned sequences: error of the front-end's up direction in every keyframe (attitude factors), and of T_B_S's tilt (S and B both have z up)")
    depth_tilt: bool = Field(True, description="runs of a sequence whose planes were extracted from its own depth images (sensor: depth, with its camera): each keyframe's planes share a variable for the depth sensor's tilt across the image (prior sigma depth_noise.tilt_sigma_per_m), which moves all of them at once; taken as independent, they put the extrinsic centimetres off under an overconfident covariance (online and offline; about 2x the time in depth mode)")
    extrinsic_rot_deg: float = Field(2.0, gt=0, le=180, description="prior on T_B_S when the sequence gives no initial alignment uncertainty (rotation)")
    extrinsic_trans_m: float = Field(0.2, gt=0, le=1000, description="prior on T_B_S when the sequence gives no initial alignment uncertainty (translation)")


class SlamAssociationConfig(Section):
    """Observation -> landmark association (SLAM side)."""

    gate_probability: float = Field(0.999, gt=0, lt=1, description="chi-square gate (3 dof) on the Mahalanobis distance with landmark marginal plus observation noise")
    max_normal_angle_deg: float = Field(15.0, gt=0, le=90, description="candidates whose normals differ more than this are not even scored")
    max_offset_m: float = Field(0.5, gt=0, description="candidates whose offsets differ more than this are not even scored")
    max_extent_gap_m: float = Field(0.1, ge=0, description="the observed polygon must come this close to the landmark's extent (coplanar walls of neighbouring rooms, a wall thickness apart, stay apart)")
    extent_max_points: int = Field(64, ge=8, description="a landmark's extent keeps at most this many hull points")


class BimAssociationConfig(Section):
    """Landmark -> BIM face association, its geometric filters and its revision."""

    gate_probability: float = Field(0.999, gt=0, lt=1, description="chi-square gate (3 dof) on the Mahalanobis distance in B with the joint marginal of landmark, anchor and extrinsic")
    face_normal_deg: float = Field(1.5, gt=0, description="as-built tolerance added to the gate covariance: normal, turned about the vertical...")
    face_plumb_deg: float = Field(0.5, gt=0, description="...and leaning out of plumb (the normal turning toward the vertical; a level face, a slab, has this tilt alone): walls stand far more nearly plumb than on their line, while a board leaning on a wall is off by degrees")
    face_offset_m: float = Field(0.05, gt=0, description="...and offset")
    max_normal_angle_deg: float = Field(20.0, gt=0, le=90, description="faces whose normals differ more than this are not scored")
    min_observations: int = Field(3, ge=1, description="a landmark is matched only once observed this many times")
    retry_growth: float = Field(1.5, ge=1, description="an unmatched landmark is scored again once its observation count has grown by this factor")
    min_area_m2: float = Field(0.5, ge=0, description="area filter: a landmark smaller than this is not matched (boxes, boards)")
    max_area_ratio: float = Field(1.3, gt=0, description="area filter: the landmark's extent may exceed the area of the face's convex hull (openings and doorways included, as an extent covers them) by at most this factor")
    corner_margin_m: float = Field(0.5, ge=0, description="corner proximity: every corner of the landmark's extent lies within this of the face's convex hull")
    centre_margin_m: float = Field(0.2, ge=0, description="centre alignment: the landmark's centre lies within this of the face's convex hull (a wall seen whole centres in its doorway)")
    coplanar_normal_deg: float = Field(0.5, gt=0, description="faces this close in normal...")
    coplanar_offset_m: float = Field(0.01, gt=0, description="...and in offset are one plane (sections of one wall), matched as a group")
    ambiguity_margin: float = Field(9.0, ge=0, description="a match is deferred while a second face scores within this many chi-square units of the best")
    shadow_gap_m: float = Field(0.05, ge=0, description="online, a match waits while another landmark parallel to it, at least this far behind it (on the wall's side)...")
    shadow_sigmas: float = Field(3.0, ge=0, description="...and no farther than this many sigmas of the extrinsic's uncertainty at the face, scores for the same face and is not one plane with it: a partition or a cabinet before a wall passes the gate with it while the extrinsic is uncertain, and the wall is the one behind; once the extrinsic is sure, the gate decides")
    revision_normal_deg: float = Field(3.0, gt=0, description="an associated landmark whose normal strays more than this from its face (in B, current estimate) is unmatched, online unless the BIM gate, on the graph's marginal as it stands, still takes the face (after a long stretch without planes the heading has drifted by degrees the poses' covariance allows, and the walls matched again turn it back over a few keyframes; the gate's face_normal_deg alone takes a wall turned about 6 deg from plan, which the online judgement then rules on)")
    revision_plumb_deg: float = Field(2.5, gt=0, description="...or whose normal leans more than this further out of plumb than its face's (a face nearer vertical than level): a board leaning on the wall it hides, not the wall built out of plumb (2.5 deg is 11 cm over a 2.5 m storey)")
    revision_offset_m: float = Field(0.25, gt=0, description="an associated landmark whose offset strays more than this from its face is unmatched...")
    revision_offset_sigmas: float = Field(3.0, gt=0, description="...online, unless the extrinsic's own uncertainty allows it this many sigmas (a wall across a direction the first walls matched left open arrives tens of tolerances off, and its kernel lets it move the extrinsic only slowly)")


class Isam2Config(Section):
    """iSAM2 parameters."""

    relinearize_threshold: float = Field(0.01, gt=0, description="relinearise a variable when its delta exceeds this")
    relinearize_skip: int = Field(1, ge=1, description="check for relinearisation every this many updates")
    partial_relinearization_check: bool = Field(True, description="check relinearisation only where the update reached (about 2x faster updates, slightly less accurate causal estimates)")
    extra_updates: int = Field(1, ge=0, description="further iSAM2 updates after adding plane-to-BIM factors")
    refresh_every: int = Field(25, ge=1, description="refresh the cached estimates of every landmark every this many keyframes (observed ones are refreshed always)")
    covariance_early: int = Field(4, ge=1, description="re-read a landmark's marginal covariance at each of its first this many observations...")
    covariance_every: int = Field(8, ge=1, description="...then at every this many-th observation...")
    covariance_growth: float = Field(0.25, ge=0, le=1, description="...or, once that is more, at every observation count divisible by the power of two at or below this fraction of the count (0.25: a landmark seen 256 times is re-read every 64; 0: always every covariance_every)")
    drift_every: int = Field(50, ge=0, description="every this many keyframes, fit the front-end's drift rates to the estimate so far (as offline: backend.offline.drift_probability, drift_rtol) and, if they changed, re-add every odometry factor without the drift (one large update each time; 0: never)")
    judge_every: int = Field(50, ge=0, description="every this many keyframes, if a plane-to-BIM factor matched since the last judgement misfits beyond the robust alignment's threshold (backend.offline.gnc_probability), run that judgement (the offline one, its studentized tests at judge_studentized_probability, over the rest of the graph reduced to its Gaussian marginal on the variables judged, the odometry stiffened by judge_odometry_scale) and give every factor its verdict. Without it (0), the robust kernel alone lets a wall built off plan that the walk sees first hold the alignment against each sound wall seen after it. Its price is stalls: 0.3-0.7 s at the longest on simulated 600-keyframe walks, 3-4 s with dozens of faces matched at once. Offline always judges")
    judge_studentized_probability: float | None = Field(0.9999, gt=0, lt=1, description="the online judgement's studentized tests (offline.studentized) at this chi-square quantile; null: none. Stricter than offline's: online they run at every judgement, on a walk seen only in part. Their use is the wall seen a few times from poses little else holds, which bends them to the plan and is kept (office 2: a wall built 8.7 cm off, the extrinsic 2.4 -> 1.8 cm); on the simulated walks the closed-form tests alone changed nothing at this quantile and, at 0.99, did better on some walks and worse on others")
    judge_odometry_scale: float = Field(0.2, gt=0, le=1, description="the online judgement (judge_every) sees the odometry's noise sigmas scaled by this (the default equals offline.odometry_noise_floor, the stiffest the offline noise estimate goes): under the noise as given, a conservative default three to five times the simulated front-ends' effective noise, the walk bends around a wall built off plan until its misfit looks like noise. The graph itself keeps the noise as given, so that the covariances stay honest. Set 1 for a front-end whose covariance is honest")
    judge_gap_keyframes: int = Field(20, ge=1, description="...except across a stretch of at least this many keyframes without an upright plane (none, or only floors and ceilings: freeze_max_tilt_deg tells them), and the step out of it, where the judgement sees the odometry's noise as given: there the front-end's errors add up alike (a heading turning steadily), faster than its per-step covariance says, and a walk stiffened over the stretch could not be turned back by the walls seen after it (a heading 8 deg off after 200 keyframes without planes, 3.8 sigma of the noise as given, stayed 7-8 deg off, the walls ruled off plan)")
    gap_odometry_scale: float = Field(3.0, ge=1, description="across such a stretch without upright planes (judge_gap_keyframes, and the step out of it), online and offline, the graph takes the odometry's noise sigmas scaled by this: nothing but the front-end holds the walk there, and a heading turned past what its covariance allows kept the walls seen after it out of the association's gate for good (8 deg after 200 keyframes, 5.7 sigma of the noise as given: 8.5 deg and 85 cm off from then on; with 3, 0.6 deg and 1.7 cm; alike where the floor was seen throughout). 1: the noise as given")
    freeze_after: int = Field(30, ge=2, description="a level landmark (see freeze_max_tilt_deg) that no face of the map could match (its normal beyond bim_association.max_normal_angle_deg from every face's: the floor, in a map of walls) is frozen once observed this many times: later observations tie their keyframe to a copy of it, so that a plane seen from everywhere does not make every iSAM2 update touch the whole tree")
    freeze_max_tilt_deg: float = Field(5.0, ge=0, le=90, description="only a landmark whose normal is within this of the vertical (by the initial alignment) is frozen: a copy holds its anchor where it was at the freeze, which for a level plane fixes only height and tilt; a copy of an upright one (a pallet's side) also held the heading the walk had before its drift was measured, and a return to it pulled the extrinsic 0.6 deg off on a simulated site")


class OfflineConfig(Section):
    """Offline (batch) mode."""

    max_rounds: int = Field(5, ge=1, description="optimise, re-associate, repeat at most this many times (graduated non-convexity may add two rounds after these)")
    max_iterations: int = Field(50, ge=1, description="batch solver (dogleg) iterations per solve")
    relative_error_tol: float = Field(1e-6, gt=0, description="the batch solver stops when an iteration improves the error by less than this fraction")
    merge_gate: float = Field(100.0, gt=0, description="two landmarks matched to one face merge unless their squared Mahalanobis distance as one plane exceeds this; far above the SLAM gate, since landmark covariances ignore the sensor's errors shared by neighbouring keyframes (measured: same wall up to 44, a board leaning on it 140 and more)")
    gnc: bool = Field(True, description="robust alignment: graduated non-convexity (Geman-McClure) decides which plane-to-BIM factors the alignment keeps (walls consistent with each other) and which walls it only measures (built off plan), whatever the walls seen first")
    gnc_probability: float = Field(0.99, gt=0, lt=1, description="GNC keeps a plane-to-BIM factor whole if its squared whitened residual ends below this chi-square quantile (3 dof; 0.99: about 3.4 sigma), else its direction alone if that is below the 2-dof quantile (the wall built parallel to plan, off its line); it also sets the GNC kernel's width")
    gnc_step: float = Field(1.4, gt=1, description="GNC lowers the surrogate's convexity by this factor per step (the paper's 1.4)")
    gnc_iterations: int = Field(5, ge=1, description="batch solver iterations per GNC step (each starts where the last ended)")
    gnc_tolerance_steps: int = Field(4, ge=1, description="the robust alignment's two starts (the robust kernel's estimate, GNC's) are also tried at this many normal tolerances, halving from the current one down to tolerance_floor_deg; a tighter start's verdicts win if their negative log-likelihood under their own estimated tolerance beats the current tolerance's by chi2(gnc_probability, 2 dof) / 2: walls moved alike can bend the walk into a consensus that GNC at a loose tolerance follows (1, or estimate_tolerance off: the current tolerance alone)")
    estimate_tolerance: bool = Field(True, description="after GNC, tighten the plane-to-BIM tolerance (noise.bim_*) to what the kept walls show: variance component estimation (a median over the walls); never looser than configured")
    tolerance_confidence: float = Field(0.5, gt=0, lt=1, description="0.5 takes that estimate itself (and the odometry noise's, estimate_odometry_noise); higher, its upper confidence bound at this confidence (0.95 trusted sound walls 1.5-2x looser than they fit)")
    tolerance_min_samples: int = Field(5, ge=1, description="the tolerance is estimated from at least this many residual components (a kept wall gives one offset and two tilts); fewer leave it as it is, so that a wall or two cannot talk it down")
    tolerance_floor_deg: float = Field(0.05, gt=0, description="the estimated normal tolerance is at least this (0.05 deg: 4 mm over a 5 m wall)...")
    tolerance_floor_m: float = Field(0.002, gt=0, description="...and the offset tolerance at least this (what plans and sensors resolve)")
    tolerance_rounds: int = Field(3, ge=1, description="estimate, re-judge with GNC's thresholds, re-solve: at most this many times per GNC")
    studentized: bool = Field(True, description="then judge each kept (or direction-kept) factor against the rest of the graph, with its own pull taken out, offset and direction apart (Baarda's data snooping: the worst failing one is demoted, the graph re-solved, until all pass): a wall few others check pulls the poses that see it toward the plan and hides its own offset")
    studentized_probability: float = Field(0.99, gt=0, lt=1, description="those tests' chi-square quantile (offset 1 dof, direction 2 dof)")
    estimate_drift: bool = Field(True, description="measure the front-end's systematic drift (constant rates per metre of rotation and translation, in its frame S) from the smoothed poses and take it out of the odometry factors (bimgraph.backend.drift)")
    drift_probability: float = Field(0.999, gt=0, lt=1, description="a drift rate (rotation or translation) is taken out only if significant at this probability against the odometry's noise (a random walk shows a trend too)")
    estimate_odometry_noise: bool = Field(True, description="with the drift taken out, tighten the odometry noise (the front-end's covariance, or noise.odometry_*) to what the smoothed steps show: variance component estimation, as for the walls; never looser than given. Not with the depth tilt variable (noise.depth_tilt), where the tightened odometry cost what the tilt gains")
    odometry_noise_floor: float = Field(0.2, gt=0, le=1, description="the estimated odometry noise is at least this fraction of the given one")
    odometry_noise_steps: int = Field(200, ge=10, description="...estimated from at most this many steps, spread evenly over the walk (each needs the joint marginal of its two poses)")
    drift_iterations: int = Field(6, ge=1, description="fit the drift rates, re-solve: at most this many times per round (each solve recovers a share of what remains; the noise is then estimated once)")
    drift_rtol: float = Field(0.03, gt=0, description="the drift rates have settled when a fit changes them by less than this fraction (the noise: twice this); online, a refit that changes them less re-adds nothing (each solve recovers only a share of the drift left, so at 0.05 the rates stopped a few percent short: site 1 heading 0.184 deg/m against 0.191 at 0.03, truth 0.199)")


class BackendConfig(Section):
    """The backend: graph, association, online and offline estimation."""

    noise: NoiseConfig = NoiseConfig()
    slam_association: SlamAssociationConfig = SlamAssociationConfig()
    bim_association: BimAssociationConfig = BimAssociationConfig()
    isam2: Isam2Config = Isam2Config()
    offline: OfflineConfig = OfflineConfig()
    seed_max_angle_deg: float = Field(10.0, gt=0, le=180, description="--seed pairs: each plane, turned onto the plan by the registration, must lie within this of its face's normal; else the pairs disagree (one names the wrong plane or face) and the run stops")
    unobservable_min_angle_deg: float = Field(10.0, gt=0, le=90, description="a direction of T_B_S is reported unobservable unless matched faces' normals reach this far out of its orthogonal plane")
    lock_rot_deg: float = Field(0.01, gt=0, description="directions of T_B_S that no face of the map can observe (e.g. height when it has only walls) are held at the initial alignment with this sigma (rotation)...")
    lock_trans_m: float = Field(0.001, gt=0, description="...and this sigma (translation)")
    write_every: int = Field(50, ge=1, description="online runs rewrite their JSON outputs every this many keyframes (the trajectories get every keyframe as it comes); each rewrite reads every landmark, about 0.1 s with the 200 landmarks of a 600-keyframe site walk, so at 10 the rewrites took two thirds as long as the backend itself")
