"""Every threshold of bimgraph, in one typed configuration.

The defaults live here, next to their documentation; `bimgraph config --default` prints them
as YAML with each field's description as a comment, and `--config FILE` overrides any subset.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import numpy as np
import yaml
from pydantic import BaseModel, ConfigDict, Field, model_validator

from bimgraph.errors import ConfigError
from bimgraph.validation import describe


class Section(BaseModel):
    model_config = ConfigDict(extra="forbid")


class BimImportConfig(Section):
    """IFC import."""

    min_face_area_m2: float = Field(0.05, description="side faces smaller than this are dropped (wall ends, slivers)")
    include_slabs: bool = Field(False, description="also export slab top and bottom faces as horizontal planes")
    vertical_tol_deg: float = Field(0.5, gt=0, description="a triangle is part of a vertical face when its normal is this close to horizontal")
    axis_tol_deg: float = Field(1.0, gt=0, description="a vertical face of a wall is a side face when it is this close to parallel to the wall's axis")
    coplanar_angle_deg: float = Field(0.05, gt=0, description="triangles whose normals differ by less than this may share a face")
    coplanar_distance_m: float = Field(0.002, gt=0, description="triangles whose planes are closer than this may share a face")
    grid_m: float = Field(1e-5, gt=0, description="precision grid of the 2-D polygon operations on faces")
    opening_slice_depth_m: float = Field(0.001, gt=0, description="openings are cut out of a face where they cross the plane this far behind it")
    boundary_on_face_m: float = Field(0.02, gt=0, description="a space boundary lies on a wall face when all its points are this close to the face's plane")
    probe_distance_m: float = Field(0.1, gt=0, description="rooms are probed this far in front of a wall face")
    min_section_width_m: float = Field(0.5, gt=0, description="in a model without rooms, a face is not cut at a junction closer than this to its end")
    threads: int = Field(0, ge=0, description="threads of the ifcopenshell geometry iterator (0: all cores)")


class AsBuiltConfig(Section):
    """As-built deviations and clutter of one kind of building."""

    offset_fraction: float = Field(0.15, ge=0, le=1, description="fraction of wall faces moved along their normal")
    offset_min_m: float = Field(0.01, ge=0, description="smallest offset of a moved face")
    offset_max_m: float = Field(0.10, ge=0, description="largest offset of a moved face")
    tilt_fraction: float = Field(0.10, ge=0, le=1, description="fraction of wall faces tilted about their bottom edge")
    tilt_max_deg: float = Field(2.0, ge=0, le=10, description="largest tilt of a tilted face")
    missing_wall_fraction: float = Field(0.0, ge=0, le=1, description="fraction of walls not yet built (never all of them)")
    clutter_per_m2: float = Field(0.04, ge=0, description="boxes and cabinets per square metre of floor")
    boards_per_m2: float = Field(0.0, ge=0, description="boards leaning against walls per square metre of floor")
    partitions: int = Field(0, ge=0, description="temporary partitions (walls absent from the model)")

    @model_validator(mode="after")
    def _ranges(self):
        if self.offset_min_m > self.offset_max_m:
            raise ValueError("offset_min_m is above offset_max_m")
        return self


class TrajectoryConfig(Section):
    """Simulated camera path."""

    grid_m: float = Field(0.05, gt=0, description="cell size of the occupancy grid sliced from the as-built walls")
    clearance_m: float = Field(0.3, gt=0, description="closest approach of the camera to any wall or clutter")
    height_min_m: float = Field(1.2, gt=0, description="lowest camera height above the floor")
    height_max_m: float = Field(1.7, gt=0, description="highest camera height above the floor")
    keyframe_distance_m: float = Field(0.3, gt=0, description="a keyframe is taken after this much travel...")
    keyframe_angle_deg: float = Field(10.0, gt=0, description="...or this much rotation since the last one")
    step_m: float = Field(0.02, gt=0, description="spacing of the dense path the keyframes are picked from")
    waypoint_spacing_m: float = Field(2.5, gt=0, description="least distance between the waypoints the path visits")
    smoothing_m: float = Field(0.4, ge=0, description="width of the moving average that rounds the path's corners")
    sweep_deg: float = Field(30.0, ge=0, description="amplitude of the side-to-side look-around about the walking direction")
    sweep_period_m: float = Field(8.0, gt=0, description="distance walked per look-around cycle")
    pitch_deg: float = Field(12.0, ge=0, description="amplitude of the up-and-down look")
    pitch_mean_deg: float = Field(-5.0, description="mean pitch (negative looks down)")
    roll_deg: float = Field(2.0, ge=0, description="amplitude of the hand-held roll")
    spin_probability: float = Field(0.1, ge=0, le=1, description="chance of turning on the spot once around at a waypoint")
    speed_m_s: float = Field(0.7, gt=0, description="walking speed, for the time stamps")
    turn_rate_deg_s: float = Field(45.0, gt=0, description="turning speed on the spot, for the time stamps")

    @model_validator(mode="after")
    def _ranges(self):
        if self.height_min_m > self.height_max_m:
            raise ValueError("height_min_m is above height_max_m")
        return self


class FrontEndConfig(Section):
    """Simulated SLAM front-end: drifting odometry in the frame S of the first camera."""

    gravity_aligned: bool = Field(True, description="S has z up (as AR trackers do); else S is the first camera frame")
    translation_drift: float = Field(0.01, ge=0, description="position drift per metre travelled (0.01 = 1 %)")
    yaw_drift_deg_per_m: float = Field(0.2, ge=0, description="heading drift per metre travelled")
    random_walk_m: float = Field(0.003, ge=0, description="position random walk, metres per square-root metre travelled")
    random_walk_deg: float = Field(0.05, ge=0, description="rotation random walk, degrees per square-root metre travelled")
    noise_m: float = Field(0.002, ge=0, description="white noise on each keyframe position")
    noise_deg: float = Field(0.05, ge=0, description="white noise on each keyframe orientation")


class PlaneNoiseConfig(Section):
    """Error of a plane fitted to a depth sensor's image, dominated by the sensor's systematic
    depth error (calibrated against planes extracted from simulated depth: scripts/bench_sim.py
    calibrate). Used to draw the simulator's plane detections and as the floor of the plane
    extractor's covariance."""

    normal_sigma_deg: float = Field(0.24, ge=0, description="normal noise of a plane seen frontally at 1 m ")
    normal_range_exponent: float = Field(0.95, description="normal noise grows as range^this (range in metres)")
    normal_cos_exponent: float = Field(1.4, description="normal noise scales as cos(viewing angle)^this (the cosine floored at 0.25)")
    offset_sigma_m: float = Field(0.0028, ge=0, description="offset noise of a plane seen frontally at 1 m")
    offset_range_exponent: float = Field(1.6, description="offset noise grows as range^this")
    offset_cos_exponent: float = Field(0.9, description="offset noise scales as cos(viewing angle)^this")

    def sigmas(self, range_m: float, cos_view: float) -> tuple[float, float]:
        """(normal sigma in radians, offset sigma in metres) of a plane seen at `range_m` with
        `cos_view` between its normal and the line of sight. Both shrink at oblique views:
        depth errors lie along the line of sight, which there runs nearly within the plane."""
        cos_view = max(cos_view, 0.25)
        sigma_n = np.radians(self.normal_sigma_deg) * range_m**self.normal_range_exponent * cos_view**self.normal_cos_exponent
        sigma_d = self.offset_sigma_m * range_m**self.offset_range_exponent * cos_view**self.offset_cos_exponent
        return float(sigma_n), float(sigma_d)

    def off(self) -> "PlaneNoiseConfig":
        return self.model_copy(update={"normal_sigma_deg": 0.0, "offset_sigma_m": 0.0})


class ObserveConfig(Section):
    """Simulated plane detections (--sensor planes)."""

    stride_px: int = Field(4, ge=1, description="ray-cast every this many pixels of the 640x480 image to find visible face parts")
    min_range_m: float = Field(0.3, ge=0, description="the sensor sees nothing closer")
    max_range_m: float = Field(5.5, gt=0, description="the sensor sees nothing farther")
    max_obliquity_deg: float = Field(75.0, gt=0, le=90, description="planes seen more obliquely than this are not detected")
    min_area_m2: float = Field(0.25, ge=0, description="smallest visible area of a detected plane")
    min_pixels: int = Field(1500, ge=1, description="smallest number of full-resolution pixels of a detected plane")
    noise: PlaneNoiseConfig = PlaneNoiseConfig()
    floors_and_ceilings: bool = Field(True, description="also detect floor and ceiling planes")
    oversegment_probability: float = Field(0.05, ge=0, le=1, description="chance that a detector splits a plane (twice the minimum area or more) into two detections")


class SimConfig(Section):
    """Simulator (bimgraph simulate)."""

    storey: str = Field("", description="storey of the model to walk (name); empty picks the one with the most wall area")
    width: int = Field(640, gt=0, description="image width in pixels")
    height: int = Field(480, gt=0, description="image height in pixels")
    fx: float = Field(525.0, gt=0, description="focal length in pixels (x)")
    fy: float = Field(525.0, gt=0, description="focal length in pixels (y)")
    initial_rot_error_deg: tuple[float, float] = Field((1.0, 2.0), description="range of the yaw error of the simulated manual alignment")
    initial_trans_error_m: tuple[float, float] = Field((0.1, 0.2), description="range of the horizontal position error of the manual alignment")
    as_built_office: AsBuiltConfig = AsBuiltConfig()
    as_built_site: AsBuiltConfig = AsBuiltConfig(
        offset_fraction=0.25, tilt_fraction=0.15, missing_wall_fraction=0.1, clutter_per_m2=0.08, boards_per_m2=0.03, partitions=3
    )
    as_built_ifc: AsBuiltConfig = AsBuiltConfig(clutter_per_m2=0.03)
    trajectory: TrajectoryConfig = TrajectoryConfig()
    frontend: FrontEndConfig = FrontEndConfig()
    observe: ObserveConfig = ObserveConfig()

    @model_validator(mode="after")
    def _ranges(self):
        for name in ("initial_rot_error_deg", "initial_trans_error_m"):
            lo, hi = getattr(self, name)
            if not 0 <= lo <= hi:
                raise ValueError(f"{name} must be a range [low, high] with 0 <= low <= high")
        return self


class DepthNoiseConfig(Section):
    """Depth sensor noise: what the simulator adds to rendered depth, and what the plane extractor weights by."""

    sigma_a_m: float = Field(0.0012, ge=0, description="depth noise sigma = a + b * z^2 (Kinect-like, after Nguyen et al. 2012): a, metres")
    sigma_b_per_m: float = Field(0.0019, ge=0, description="depth noise sigma = a + b * z^2: b, 1/metres")
    quantum_m: float = Field(0.0002, ge=0, description="depth is rounded to this step (the 16-bit PNG unit, 1/5000 m); 0 keeps floats")
    min_range_m: float = Field(0.3, ge=0, description="no return closer than this")
    max_range_m: float = Field(7.0, gt=0, description="no return farther than this")
    dropout_probability: float = Field(0.01, ge=0, le=1, description="chance of a random hole at any pixel")
    grazing_start_deg: float = Field(70.0, ge=0, le=90, description="incidence angle (from the surface normal) where grazing dropouts begin")
    grazing_end_deg: float = Field(85.0, ge=0, le=90, description="incidence angle beyond which no return comes back (dropout chance rises linearly from start)")
    scale_sigma: float = Field(0.003, ge=0, description="systematic part, drawn once per frame: relative depth scale error (0.003 = 3 mm per metre); 0 turns it off")
    tilt_sigma_per_m: float = Field(0.002, ge=0, description="systematic part, drawn once per frame: sigma of each of two depth error terms linear across and down the image (1 at the image border), per squared metre of depth (0.002 = 2 mm at 1 m, 8 mm at 2 m); tilts fitted planes; 0 turns it off")
    curvature_sigma_per_m: float = Field(0.0002, ge=0, description="systematic part, drawn once per frame: the same for three quadratic terms (saddle, astigmatism, bowl); bends planes, so plane extraction splits walls when it is large; 0 turns it off")

    def sigma(self, z):
        """Standard deviation of the per-pixel depth noise at depth z (metres, scalar or array)."""
        return self.sigma_a_m + self.sigma_b_per_m * z * z

    def systematic_sigma(self, z):
        """Standard deviation of the systematic depth error at depth z at the image corners,
        where it is largest (there both tilt terms, the saddle and the bowl are 1)."""
        return ((self.scale_sigma * z) ** 2 + 2 * z**4 * (self.tilt_sigma_per_m**2 + self.curvature_sigma_per_m**2)) ** 0.5

    def without_systematic(self) -> "DepthNoiseConfig":
        """The same sensor with only per-pixel noise (what the plane extractor's covariance models)."""
        return self.model_copy(update={"scale_sigma": 0.0, "tilt_sigma_per_m": 0.0, "curvature_sigma_per_m": 0.0})


class ExtractionConfig(Section):
    """Plane extraction from depth images (bimgraph planes)."""

    cell_size_px: int = Field(20, ge=4, description="side of the square image cells fitted one by one before region growing")
    min_depth_m: float = Field(0.3, ge=0, description="depth below this is ignored")
    max_depth_m: float = Field(7.0, gt=0, description="depth beyond this is ignored")
    cell_min_valid_fraction: float = Field(0.6, gt=0, le=1, description="a cell needs this fraction of valid depth pixels to be fitted")
    max_mse_ratio: float = Field(3.0, gt=0, description="a cell, and a whole plane, is planar if its mean squared residual is at most this multiple of the one the depth noise predicts")
    grow_max_chi2: float = Field(16.0, gt=0, description="a cell joins a plane if fitting it to that plane costs at most this much chi-square over its own best fit")
    grow_max_angle_deg: float = Field(4.0, gt=0, description="a cell joins a plane only if their normals differ by at most this")
    grow_max_offset_m: float = Field(0.03, gt=0, description="a cell joins a plane only if its centroid lies at most this far from it")
    grow_iterations: int = Field(3, ge=1, description="grow, refit, grow again: this many rounds per plane")
    seed_min_support: int = Field(2, ge=0, le=4, description="a region may start only from a planar cell with this many compatible 4-neighbours")
    min_cells: int = Field(3, ge=1, description="smallest number of cells of a plane")
    min_area_m2: float = Field(0.2, ge=0, description="smallest area of a reported plane")
    polygon_tolerance_px: float = Field(2.0, ge=0, description="the extent polygon may deviate from the region outline by this many pixels")
    systematic: PlaneNoiseConfig = Field(default_factory=PlaneNoiseConfig, description="the sensor's systematic plane error, added to the covariance from the pixels (which averages per-pixel noise away and so alone is far too confident)")


class DeviationConfig(Section):
    """As-built deviations of observed walls from plan (deviations.json, .csv, .bcf)."""

    tolerance_m: float = Field(0.02, gt=0, description="allowed offset of a built face along its normal (common wall tolerance +/-2 cm)")
    tilt_tolerance_deg: float = Field(0.5, gt=0, description="allowed tilt of a built face (about 2 cm over a 2.5 m storey)")
    k_sigma: float = Field(3.0, ge=0, description="a face deviates if |offset| - k*sigma > tolerance, or its tilt likewise (a significance test, so that noise does not make a wall deviate: each flag sends someone to the wall; on 8 simulated sites, k = 2 flagged 3 sound faces, 3 none)")
    min_keyframes: int = Field(3, ge=1, description="faces seen in fewer keyframes have not enough evidence, and unmatched planes seen in fewer are not reported as unplanned (a glimpse sends nobody to the site)")
    max_offset_sigma_m: float = Field(0.01, gt=0, description="a face is within tolerance only if its offset is at least this certain...")
    max_tilt_sigma_deg: float = Field(0.5, gt=0, description="...and its tilt at least this certain")
    match_max_offset_m: float = Field(0.2, gt=0, description="a face no landmark is associated with is measured, for the report, by a landmark passing this close to its centre...")
    match_max_tilt_deg: float = Field(5.0, gt=0, description="...is tilted less than this from it...")
    match_min_overlap_m2: float = Field(0.25, ge=0, description="...and its extent overlaps the face by at least this much...")
    match_margin_m: float = Field(0.3, ge=0, description="...or, for a landmark without an extent polygon, its centre lies within this of the face")
    unplanned_min_area_m2: float = Field(1.0, ge=0, description="unmatched landmarks at least this large are reported as unplanned")
    unplanned_vertical_only: bool = Field(True, description="only near-vertical unmatched planes count as unplanned (floors and ceilings are not walls)")
    vertical_tolerance_deg: float = Field(10.0, gt=0, description="a plane is vertical if its normal is within this of horizontal")
    visibility_grid_m: float = Field(0.25, gt=0, description="spacing of the sample points on each face for the expected-in-view test")
    visibility_min_range_m: float = Field(0.3, ge=0, description="a face point is in view from this distance...")
    visibility_max_range_m: float = Field(5.0, gt=0, description="...up to this one...")
    visibility_max_obliquity_deg: float = Field(70.0, gt=0, le=90, description="...seen at most this obliquely...")
    visibility_min_area_m2: float = Field(0.5, ge=0, description="...and a face is in view if at least this much of it is in view and not occluded by other faces")
    min_expected_keyframes: int = Field(5, ge=1, description="a never-observed face in view in at least this many keyframes is possibly not built")
    bcf_author: str = Field("bimgraph", description="author of the BCF topics")
    bcf_view_distance_m: float = Field(3.0, gt=0, description="the BCF viewpoint looks at the face's centre from this far along its normal")


class NoiseConfig(Section):
    """Backend noise models (one sigma)."""

    prior_first_pose_rot_deg: float = Field(0.001, gt=0, description="prior on the first keyframe pose: fixes the gauge of S (rotation)")
    prior_first_pose_trans_m: float = Field(0.0001, gt=0, description="prior on the first keyframe pose: fixes the gauge of S (translation)")
    odometry_rot_deg: float = Field(0.1, gt=0, description="front-end relative pose between keyframes when a keyframe has no cov (rotation)")
    odometry_trans_m: float = Field(0.005, gt=0, description="front-end relative pose between keyframes when a keyframe has no cov (translation)")
    plane_normal_deg: float = Field(1.0, gt=0, description="plane observation when it has no cov: normal")
    plane_offset_m: float = Field(0.02, gt=0, description="plane observation when it has no cov: offset")
    plane_kernel: str = Field("huber", pattern="^(none|huber|cauchy)$", description="robust kernel on plane observations (none, huber, cauchy)")
    plane_kernel_width: float = Field(2.0, gt=0, description="kernel width of plane observations, in sigmas")
    bim_normal_deg: float = Field(1.0, gt=0, description="plane-to-BIM factor: how far an as-built wall's normal strays from plan (a tilt about the face's centre)")
    bim_offset_m: float = Field(0.01, gt=0, description="plane-to-BIM factor: how far an as-built wall's offset, at the face's centre, strays from plan (one sigma: the common +/-2 cm wall tolerance as a 95 % bound, so that the robust alignment keeps whole only walls within about 3.4 cm of plan; at 1.5 cm it kept walls built 3-5 cm off, which pulled the poses)")
    bim_kernel: str = Field("cauchy", pattern="^(none|huber|cauchy)$", description="robust kernel on plane-to-BIM factors (a Gaussian one lets one wrong match move the extrinsic)")
    bim_kernel_width: float = Field(1.0, gt=0, description="kernel width of plane-to-BIM factors, in sigmas")
    gravity_deg: float = Field(0.1, gt=0, description="gravity-aligned sequences: error of the front-end's up direction in every keyframe (attitude factors), and of T_B_S's tilt (S and B both have z up)")
    extrinsic_rot_deg: float = Field(2.0, gt=0, description="prior on T_B_S when the sequence gives no initial alignment uncertainty (rotation)")
    extrinsic_trans_m: float = Field(0.2, gt=0, description="prior on T_B_S when the sequence gives no initial alignment uncertainty (translation)")


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
    revision_normal_deg: float = Field(3.0, gt=0, description="an associated landmark whose normal strays more than this from its face (in B, current estimate) is unmatched")
    revision_plumb_deg: float = Field(2.5, gt=0, description="...or whose normal leans more than this further out of plumb than its face's (a face nearer vertical than level): a board leaning on the wall it hides, not the wall built out of plumb (2.5 deg is 11 cm over a 2.5 m storey)")
    revision_offset_m: float = Field(0.25, gt=0, description="an associated landmark whose offset strays more than this from its face is unmatched")


class Isam2Config(Section):
    """iSAM2 parameters."""

    relinearize_threshold: float = Field(0.01, gt=0, description="relinearise a variable when its delta exceeds this")
    relinearize_skip: int = Field(1, ge=1, description="check for relinearisation every this many updates")
    partial_relinearization_check: bool = Field(True, description="check relinearisation only where the update reached (about 2x faster updates, slightly less accurate causal estimates)")
    extra_updates: int = Field(1, ge=0, description="further iSAM2 updates after adding plane-to-BIM factors")
    refresh_every: int = Field(25, ge=1, description="refresh the cached estimates of every landmark every this many keyframes (observed ones are refreshed always)")
    covariance_early: int = Field(4, ge=1, description="re-read a landmark's marginal covariance at each of its first this many observations...")
    covariance_every: int = Field(8, ge=1, description="...then at every this many-th observation")
    drift_every: int = Field(50, ge=0, description="every this many keyframes, fit the front-end's drift rates to the estimate so far (as offline: backend.offline.drift_probability, drift_rtol) and, if they changed, re-add every odometry factor without the drift (one large update each time; 0: never)")
    judge_every: int = Field(0, ge=0, description="every this many keyframes, if a plane-to-BIM factor matched since the last judgement misfits beyond the robust alignment's threshold (backend.offline.gnc_probability), run that judgement (graduated non-convexity alone, over the rest of the graph reduced to its Gaussian marginal on the variables judged) and give every factor its verdict: with the robust kernel alone, a wall built off plan that the walk sees first holds the alignment against each sound wall seen after it. On the simulated 600-keyframe walks it judged 6-14 times, 0.05-0.6 s each (the largest stall 0.3-2.4 s, online time up to 2x) and left their accuracy as it was, so it is off by default (0); offline always judges")
    freeze_after: int = Field(30, ge=2, description="a landmark no face of the map could match (its normal beyond bim_association.max_normal_angle_deg from every face's: the floor, in a map of walls) is frozen once observed this many times: later observations tie their keyframe to a copy of it, so that a plane seen from everywhere does not make every iSAM2 update touch the whole tree")


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
    estimate_tolerance: bool = Field(True, description="after GNC, tighten the plane-to-BIM tolerance (noise.bim_*) to what the kept walls show: variance component estimation, its upper confidence bound; never looser than configured")
    tolerance_confidence: float = Field(0.95, gt=0, lt=1, description="confidence of that upper bound (a few walls cannot talk the tolerance down)")
    tolerance_floor_deg: float = Field(0.1, gt=0, description="the estimated normal tolerance is at least this...")
    tolerance_floor_m: float = Field(0.002, gt=0, description="...and the offset tolerance at least this (what plans and sensors resolve)")
    tolerance_rounds: int = Field(3, ge=1, description="estimate, re-judge with GNC's thresholds, re-solve: at most this many times per GNC")
    studentized: bool = Field(True, description="then judge each kept (or direction-kept) factor against the rest of the graph, with its own pull taken out, offset and direction apart (Baarda's data snooping: the worst failing one is demoted, the graph re-solved, until all pass): a wall few others check pulls the poses that see it toward the plan and hides its own offset")
    studentized_probability: float = Field(0.99, gt=0, lt=1, description="those tests' chi-square quantile (offset 1 dof, direction 2 dof)")
    estimate_drift: bool = Field(True, description="measure the front-end's systematic drift (constant rates per metre of rotation and translation, in its frame S) from the smoothed poses and take it out of the odometry factors (bimgraph.backend.drift)")
    drift_probability: float = Field(0.999, gt=0, lt=1, description="a drift rate (rotation or translation) is taken out only if significant at this probability against the odometry's noise (a random walk shows a trend too)")
    estimate_odometry_noise: bool = Field(True, description="with the drift taken out, tighten the odometry noise (the front-end's covariance, or noise.odometry_*) to what the smoothed steps show: variance component estimation, as for the walls; never looser than given")
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
    unobservable_min_angle_deg: float = Field(10.0, gt=0, le=90, description="a direction of T_B_S is reported unobservable unless matched faces' normals reach this far out of its orthogonal plane")
    lock_rot_deg: float = Field(0.01, gt=0, description="directions of T_B_S that no face of the map can observe (e.g. height when it has only walls) are held at the initial alignment with this sigma (rotation)...")
    lock_trans_m: float = Field(0.001, gt=0, description="...and this sigma (translation)")
    write_every: int = Field(50, ge=1, description="online runs rewrite their JSON outputs every this many keyframes (the trajectories get every keyframe as it comes); each rewrite reads every landmark, about 0.1 s with the 200 landmarks of a 600-keyframe site walk, so at 10 the rewrites took two thirds as long as the backend itself")


class BaselineConfig(Section):
    """The seed paper's baselines (bimgraph eval, scripts/reproduce_paper.py)."""

    offset_sigma_m: float = Field(0.02, gt=0, description="global/local: one sigma of a matched plane's offset...")
    prior_trans_m: float = Field(2.0, gt=0, description="...against that of the weak prior toward the manual alignment, so that translations the planes leave free stay there")
    local_max_planes: int = Field(12, ge=3, description="local: at most this many matched planes per solve")
    local_radius_m: float = Field(6.0, gt=0, description="local: planes farther from the camera than this are never added")


Rgba = Annotated[list[Annotated[int, Field(ge=0, le=255)]], Field(min_length=3, max_length=4)]


class ViewerConfig(Section):
    """Rerun viewer (bimgraph run --rrd / --spawn, bimgraph view). Colours are [r, g, b, a], 0-255."""

    flush_seconds: float = Field(0.5, ge=0, description="send the buffered rows to Rerun at most this often (the live view lags by about this much)...")
    flush_budget: float = Field(0.05, gt=0, le=1, description="...and so rarely that sending takes at most this fraction of the run's wall time")
    depth_images: bool = Field(True, description="log each keyframe's depth image in the camera view (when the sequence has them)")
    frustum_m: float = Field(0.3, gt=0, description="depth of the camera frustum drawn in 3-D")
    axes_length_m: float = Field(0.3, gt=0, description="length of the axes drawn at the camera and at the origin of S")
    trajectory_radius_m: float = Field(0.015, gt=0, description="half-width of the trajectory lines")
    label_radius_m: float = Field(0.03, gt=0, description="radius of the point carrying each face's id label")
    observed_angle_deg: float = Field(15.0, gt=0, description="display only: a face counts as observed when a detected plane, mapped by the current estimate, is this parallel to it...")
    observed_distance_m: float = Field(0.3, gt=0, description="...its centre this close to the face's plane...")
    observed_margin_m: float = Field(0.5, ge=0, description="...and inside the face's bounding box grown by this margin")
    colour_unobserved: Rgba = Field([170, 170, 170, 90], description="BIM face never observed")
    colour_observed: Rgba = Field([90, 150, 230, 140], description="BIM face observed but not associated")
    colour_associated: Rgba = Field([60, 190, 90, 170], description="BIM face associated with a landmark")
    colour_deviating: Rgba = Field([230, 60, 50, 200], description="BIM face whose as-built position deviates beyond tolerance")
    colour_raw: Rgba = Field([240, 140, 30, 255], description="raw front-end trajectory mapped by the initial alignment")
    colour_corrected: Rgba = Field([30, 110, 240, 255], description="corrected trajectory, as estimated at each keyframe")
    colour_final: Rgba = Field([150, 60, 220, 255], description="final trajectory (logged once at the end)")
    colour_truth: Rgba = Field([40, 40, 40, 255], description="ground-truth trajectory")
    colour_plane: Rgba = Field([250, 210, 40, 255], description="outline of a detected plane not associated with a BIM face")
    colour_plane_associated: Rgba = Field([60, 190, 90, 255], description="outline of a detected plane associated with a BIM face")
    colour_association: Rgba = Field([60, 190, 90, 255], description="line from an associated plane to its BIM face's centre")

    def colour(self, state: str) -> Rgba:
        """The colour of a face state: unobserved, observed, associated or deviating."""
        return getattr(self, f"colour_{state}")


class Config(Section):
    bim: BimImportConfig = BimImportConfig()
    sim: SimConfig = SimConfig()
    depth_noise: DepthNoiseConfig = DepthNoiseConfig()
    planes: ExtractionConfig = ExtractionConfig()
    deviations: DeviationConfig = DeviationConfig()
    backend: BackendConfig = BackendConfig()
    viewer: ViewerConfig = ViewerConfig()
    baselines: BaselineConfig = BaselineConfig()


def load_config(path: Path | None) -> Config:
    """The defaults, overridden by the YAML file at `path` if given."""
    if path is None:
        return Config()
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"{path}: no such configuration file")
    try:
        data = yaml.safe_load(path.read_text()) or {}
    except yaml.YAMLError as err:
        raise ConfigError(f"{path}: invalid YAML ({err})") from None
    try:
        return Config.model_validate(data)
    except Exception as err:  # pydantic.ValidationError
        msg = describe(err) if hasattr(err, "errors") else str(err)
        raise ConfigError(f"{path}: {msg}") from None


def default_yaml() -> str:
    """The default configuration as commented YAML."""
    lines = ["# bimgraph configuration: every threshold, with its default.",
             "# Pass an edited copy (any subset of it) with --config FILE."]

    def emit(model: BaseModel, indent: int):
        for name, field in type(model).model_fields.items():
            value = getattr(model, name)
            pad = "  " * indent
            if isinstance(value, BaseModel):
                lines.append("")
                lines.append(f"{pad}# {type(value).__doc__.strip().splitlines()[0]}")
                lines.append(f"{pad}{name}:")
                emit(value, indent + 1)
            else:
                if field.description:
                    lines.append(f"{pad}# {field.description}")
                dumped = yaml.safe_dump({name: value}, default_flow_style=True, width=1000).strip()
                lines.append(f"{pad}{dumped[1:-1]}")

    emit(Config(), 0)
    return "\n".join(lines) + "\n"
