"""Robust alignment by data snooping: which plane-to-BIM factors should leave the alignment.

The robust kernel of the plane-to-BIM factors already bounds what a deviating wall can do to
the extrinsic, but a Cauchy kernel still pulls with `r / (1 + r^2)` (0.3 sigma at r = 3), and
five such walls pull as much as one good one. Here each associated face is measured against
the alignment the rest of the graph decides (its own factor taken out, `estimate`), and a
face that deviates beyond the construction tolerance by more than k sigma is flagged; the
estimator removes its factor (and keeps it from re-associating to the same face), then
re-solves, so that the consistent walls alone decide the extrinsic and the deviating ones are
measured against it (Baarda's iterated data snooping). Pure computation, no I/O.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from bimgraph.bim.planemap import PlaneMap
from bimgraph.config import DeviationConfig
from bimgraph.deviations.estimate import Deviation, ObservedPlane, excess_sigma, face_deviation


@dataclass(frozen=True)
class Outlier:
    landmark: int
    face_id: str
    excess: float  # how many sigma the deviation lies beyond the tolerance (offset or tilt)
    deviation: Deviation


def snoop(planes: Sequence[ObservedPlane], plane_map: PlaneMap, T_S_B: np.ndarray, cfg: DeviationConfig) -> list[Outlier]:
    """The associated landmarks (those with a plane-to-BIM factor) whose face deviates
    significantly, the most significant first. Removing only the first per re-solve is the
    cautious schedule; removing all at once is fine while most faces are as planned."""
    index = plane_map.index
    out = []
    for plane in planes:
        if plane.bim_factor is None or plane.face_id not in index:
            continue
        dev = face_deviation(plane_map.faces[index[plane.face_id]], plane, T_S_B)
        if not dev.measurable or plane.n_keyframes < cfg.min_keyframes:
            continue
        excess = excess_sigma(dev, cfg)
        if excess > cfg.k_sigma:
            out.append(Outlier(plane.landmark, plane.face_id, excess, dev))
    return sorted(out, key=lambda o: -o.excess)
