"""What a sequence's keyframes may hold that the format accepts but the backend cannot use as
the writer likely meant: warnings, in words, for `bimgraph run` to print. No I/O."""

from __future__ import annotations

import numpy as np

from bimgraph.geometry import pose_from_tum
from bimgraph.sequence.format import Keyframe, SequenceMeta

# covariances at least this many times larger at the end of the walk than at its start, growing
# on most steps, are a pose's, not a step's
_GROWTH = 10.0
_GROWING_STEPS = 0.9
# most plane detections without a polygon: a front-end that gives none (a floor's may lack one)
_BARE_FRACTION = 0.9
# keyframes farther than this from S's origin: T_B_S turns about that origin, so its rotation
# couples with its translation by this lever (1 km: 2 deg there is 35 m at the walk; at 10 km
# and more, the graph's linear systems are singular to double precision)
_FAR_M = 1000.0
# with S gravity-aligned, the image's down axis (C's y) of a camera carried upright points
# down (a z-component in S below `_NOT_DOWN`) but where it looks nearly straight up or down:
# in more keyframes than `_NOT_DOWN_SHARE`, a frame convention has gone wrong
_NOT_DOWN, _NOT_DOWN_SHARE = -0.2, 0.2
# a gravity-aligned initial alignment tilting S's z more than this is written wrong
_ALIGNMENT_TILT_DEG = 10.0
_CONVENTIONS = ("a y-up world (ARKit, ARCore), a camera of OpenGL's axes (y up, z backward) or a quaternion written "
                "w x y z instead of x y z w reads like this (docs/formats.md, from an AR tracker)")
# a step's given sigmas below these (rad, m) trust the walk beyond what any front-end measures
_TINY_ROT_RAD, _TINY_TRANS_M = 1e-5, 1e-5
# keyframes further apart than this (median) are stamped in units smaller than seconds
_SLOW_STEP_S = 60.0
# planes farther than this from the camera (median) are not a depth sensor's or a tracker's
# (the sensors see a few metres): millimetres read as metres
_FAR_PLANE_M = 50.0


def sequence_warnings(keyframes: list[Keyframe], meta: SequenceMeta | None = None) -> list[str]:
    """One line per thing the writer of `keyframes` (and of `meta`, sequence.json) likely
    got wrong."""
    out = []
    if meta is not None and meta.gravity_aligned and keyframes:
        down_z = np.array([kf.pose[2, 1] for kf in keyframes])  # (C's y axis in S, its z-component)
        if (share := float(np.mean(down_z > _NOT_DOWN))) > _NOT_DOWN_SHARE:
            out.append(f"gravity_aligned is true, yet in {share:.0%} of the keyframes the image's down axis (C's y) "
                       "does not point down in S: S must have z up, and C OpenCV's axes (x right, y down, z "
                       f"forward); {_CONVENTIONS}")
    if meta is not None and meta.gravity_aligned and meta.initial_alignment is not None:
        tilt = np.degrees(np.arccos(np.clip(pose_from_tum(meta.initial_alignment.T_B_S)[2, 2], -1.0, 1.0)))
        if tilt > _ALIGNMENT_TILT_DEG:
            out.append(f"gravity_aligned is true, yet initial_alignment's T_B_S tilts S's z {tilt:.0f} deg from B's: "
                       f"only its turn about z is kept; {_CONVENTIONS}")
    if (sigmas := _median_step_sigmas(keyframes)) is not None and (sigmas[0] < _TINY_ROT_RAD or sigmas[1] < _TINY_TRANS_M):
        out.append(f"the keyframes' cov gives a step's sigmas of {np.degrees(sigmas[0]):.2g} deg and {1000 * sigmas[1]:.2g} mm "
                   "(median): bimgraph trusts the walk to that, and walls the walk cannot bend to are judged off "
                   "plan; a front-end's steps are good to millimetres and hundredths of a degree at best")
    if len(keyframes) > 2 and (step := float(np.median(np.diff([kf.stamp for kf in keyframes])))) > _SLOW_STEP_S:
        out.append(f"keyframes lie {step:.3g} s apart (median): stamps are seconds; divide milliseconds by 1e3, "
                   "microseconds by 1e6, nanoseconds by 1e9")
    traces = np.array([np.trace(kf.cov) for kf in keyframes[1:] if kf.cov is not None])
    if len(traces) >= 10 and traces[-1] > _GROWTH * traces[0] and np.mean(np.diff(traces) > 0) >= _GROWING_STEPS:
        out.append(f"the keyframes' cov grows along the walk ({traces[-1] / traces[0]:.0f}x from the second keyframe to "
                   "the last), as the front-end's pose covariance does; bimgraph reads it as the covariance of the "
                   "step from the previous keyframe, and so would trust the walk less and less (docs/formats.md)")
    planes = [p for kf in keyframes for p in kf.planes]
    if (bare := sum(not p.polygon for p in planes)) >= _BARE_FRACTION * len(planes) > 0:
        out.append(f"{bare} of {len(planes)} plane detections have no polygon: without their extents the views of one "
                   "wall are seldom joined into one landmark, and few or none are matched to BIM faces (the "
                   "associations' extent gates and geometric filters need them; docs/formats.md)")
    if planes and (median_d := float(np.median([p.d for p in planes]))) > _FAR_PLANE_M:
        out.append(f"the planes lie a median {median_d:.3g} m from the camera: d is in metres (millimetres read as "
                   "metres put every wall kilometres away, and none is matched to a BIM face)")
    distances = [float(np.linalg.norm(kf.T_S_C[:3])) for kf in keyframes]
    if keyframes and (far := max(distances)) > _FAR_M:
        first = next(kf for kf, distance in zip(keyframes, distances) if distance > _FAR_M)
        out.append(f"keyframes lie up to {far / 1000:.3g} km from the origin of S, from keyframe {first.index} on "
                   f"(stamp {first.stamp}): T_B_S turns about that origin, so "
                   "its rotation's uncertainty moves the walk by that lever, and the graph loses precision (beyond "
                   "about 10 km it is singular); give poses in a frame near the walk (e.g. subtract the first "
                   "keyframe's position, and move the initial alignment with it)")
    return out


def _median_step_sigmas(keyframes: list[Keyframe]) -> tuple[float, float] | None:
    """The median over the given step covariances of their rotation and translation sigmas
    (the mean of each block's diagonal), or None if no keyframe after the first gives one."""
    covs = [np.asarray(kf.cov) for kf in keyframes[1:] if kf.cov is not None]
    if not covs:
        return None
    diag = np.array([c.diagonal() for c in covs])
    return float(np.sqrt(np.median(diag[:, :3].mean(axis=1)))), float(np.sqrt(np.median(diag[:, 3:].mean(axis=1))))
