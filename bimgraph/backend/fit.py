"""Whether the BIM model fits the walk, judged from a run's landmarks. No I/O.

A model of another storey, in other units, or placed far from where the initial alignment
says, matches few of the walls the front-end saw, and the run still ends without an error:
its trajectory is the front-end's, its deviation report a list of walls "possibly not built".
The large planes seen long are mostly the walls of the rooms walked: more than half of them
matched a face on every walk measured (the six simulated walks, offices and sites with
clutter, boards and partitions; a deviation site; the sixth outside review's runs on FZK-Haus
and two more sites): 10 of 18 on the worst. With another storey's model 4 of 15 did (that
review's run), with the map in millimetres 1 of 19, with the map 1.5 m off 1 of 6.
"""

from __future__ import annotations

import numpy as np

from bimgraph.backend.landmarks import Landmark

# a large vertical plane seen long: within ~17 degrees of vertical in B, from 10 observations
# and 2 m2 of extent up
_MAX_VERTICAL_NZ = 0.3
_SEEN_LONG = 10
_LARGE_M2 = 2.0
# fewer than this share of them matched (and enough of them to tell): the model does not fit
_FITTING_SHARE = 0.4
_ENOUGH = 5


def unfitting_model(landmarks: list[Landmark], T_B_S: np.ndarray) -> str | None:
    """A warning where most of the large vertical planes seen long match no BIM face; None
    where they do, or where there are too few to tell."""
    R_B_S = np.asarray(T_B_S)[:3, :3]
    walls = [lm for lm in landmarks if abs(R_B_S[2] @ lm.plane_S[:3]) < _MAX_VERTICAL_NZ
             and len(lm.observations) >= _SEEN_LONG and lm.area >= _LARGE_M2]
    matched = sum(lm.face is not None for lm in walls)
    if len(walls) < _ENOUGH or matched >= _FITTING_SHARE * len(walls):
        return None
    return (f"only {matched} of the {len(walls)} large vertical planes seen in {_SEEN_LONG} keyframes or more matched a "
            f"BIM face (more than half on every simulated walk measured): is the model that of the storey walked, in its "
            f"units, and is the initial alignment within its sigmas?")
