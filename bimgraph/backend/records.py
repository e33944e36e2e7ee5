"""What the estimators hand out: a result per keyframe, the results of a run, and the listener
hook through which a viewer (or anything else) follows a run without the algorithm doing I/O."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from bimgraph.backend.landmarks import Landmark
from bimgraph.deviations.estimate import RivalAlignment
from bimgraph.sequence.format import Keyframe


@dataclass
class Association:
    """Observation `observation` of the keyframe went to landmark `landmark`, matched (so far)
    to BIM face `face`, or None."""

    observation: int
    landmark: int
    face: str | None


@dataclass
class KeyframeResult:
    index: int
    stamp: float
    T_S_C: np.ndarray
    T_B_C: np.ndarray
    T_B_S: np.ndarray
    cov_T_B_S: np.ndarray  # 6x6, gtsam Pose3 tangent (rotation, translation)
    associations: list[Association]
    latency_s: float
    isam2_s: float = 0.0  # of the latency, the part spent in iSAM2 updates
    keyframe: Keyframe | None = None  # the input, so that a listener sees planes and images too


@dataclass
class Results:
    """A whole run. Trajectories are index-aligned with `indices`/`stamps`; online runs hold
    the causal estimates (as emitted), offline runs the smoothed ones."""

    mode: str
    indices: list[int]
    stamps: list[float]
    T_S_C: list[np.ndarray]
    T_B_C: list[np.ndarray]
    T_B_S: np.ndarray
    cov_T_B_S: np.ndarray
    unobservable: list[dict]
    landmarks: list[Landmark]
    timings: dict = field(default_factory=dict)
    rounds: int = 0
    # the plane-to-BIM tolerance (normal rad, offset m) the final graph's factors were given,
    # if estimated (under the robust kernel, whose width is in units of it)
    bim_tolerance: tuple[float, float] | None = None
    # the front-end's drift rates and odometry noise scale as the offline estimate measured
    # them (`bimgraph.backend.drift`), if it did
    frontend_drift: dict | None = None
    # offline: the robust alignment's consensus against its complement
    # (`OfflineEstimator._challenge`), if it ran
    alignment_challenge: dict | None = None
    # offline: the consensus the challenge turned down, where it is not negligible; `cov_T_B_S`
    # covers it too
    rival_alignment: RivalAlignment | None = None
    # the depth tilt's prior sigma, where each keyframe's was a variable (`bimgraph.backend.depth_tilt`)
    depth_tilt_sigma_per_m: float | None = None
    # Every landmark with its joint covariance with E and its anchor, for the deviation step
    # (`bimgraph.deviations.estimate.ObservedPlane`).
    observed_planes: list = field(default_factory=list)

    def associations(self) -> dict[tuple[int, int], str]:
        """(keyframe index, observation index) -> face id, for every matched landmark."""
        out = {}
        for lm in self.landmarks:
            faces = lm.observation_faces or [lm.face] * len(lm.observations)
            out.update((obs, face) for obs, face in zip(lm.observations, faces) if face is not None)
        return out


class Listener:
    """Override any of these to follow a run; the defaults do nothing."""

    def on_keyframe(self, result: KeyframeResult) -> None:
        pass

    def on_association(self, landmark_id: int, face_id: str, score: float) -> None:
        pass

    def on_association_removed(self, landmark_id: int, face_id: str, reason: str) -> None:
        pass
