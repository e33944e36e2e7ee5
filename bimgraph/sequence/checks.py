"""What a sequence's keyframes may hold that the format accepts but the backend cannot use as
the writer likely meant: warnings, in words, for `bimgraph run` to print. No I/O."""

from __future__ import annotations

import numpy as np

from bimgraph.sequence.format import Keyframe

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


def sequence_warnings(keyframes: list[Keyframe]) -> list[str]:
    """One line per thing the writer of `keyframes` likely got wrong."""
    out = []
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
    distances = [float(np.linalg.norm(kf.T_S_C[:3])) for kf in keyframes]
    if keyframes and (far := max(distances)) > _FAR_M:
        first = next(kf for kf, distance in zip(keyframes, distances) if distance > _FAR_M)
        out.append(f"keyframes lie up to {far / 1000:.3g} km from the origin of S, from keyframe {first.index} on "
                   f"(stamp {first.stamp}): T_B_S turns about that origin, so "
                   "its rotation's uncertainty moves the walk by that lever, and the graph loses precision (beyond "
                   "about 10 km it is singular); give poses in a frame near the walk (e.g. subtract the first "
                   "keyframe's position, and move the initial alignment with it)")
    return out
