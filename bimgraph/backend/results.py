"""The files of a run (schema in docs/formats.md, "Run outputs").

Online runs write as they go: each keyframe appends one complete line to the two TUM files
and flushes; the JSON files are rewritten atomically every few keyframes and at the end, so a
run that dies leaves every file valid and consistent up to some keyframe.
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path
from typing import Annotated, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator

from bimgraph.backend.landmarks import DIRECTION, KEPT, OUT, Landmark
from bimgraph.backend.records import KeyframeResult, Results
from bimgraph.errors import InputError
from bimgraph.files import ensure_folder, read_json, uninterrupted, write_json
from bimgraph.geometry import plane_from_frame, pose_to_tum, sigmas_in_B
from bimgraph.sequence.format import Vec3
from bimgraph.sequence.tum import format_tum, read_tum, write_tum
from bimgraph.validation import Pose7, parse_model

TRAJECTORY_BIM = "trajectory_bim.tum"
TRAJECTORY_SLAM = "trajectory_slam.tum"
EXTRINSIC = "extrinsic.json"
ASSOCIATIONS = "associations.json"
LANDMARKS = "landmarks.json"
SUMMARY = "summary.json"
METRICS = "metrics.json"  # (written by `bimgraph eval` into a run's folder)


def _pose7(T: np.ndarray) -> list[float]:
    return [round(float(v), 9) for v in pose_to_tum(T)]


def _plane(p: np.ndarray) -> list[float]:
    return [round(float(v), 9) for v in p]


def _finite(x: float):
    return None if x is None or not math.isfinite(x) else round(float(x), 6)


class _File(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)


# Numbers that a graph gone singular mid-run leaves non-finite are written as null.
Sigma3 = tuple[float | None, float | None, float | None]
Row6 = Annotated[list[float | None], Field(min_length=6, max_length=6)]
Index = Annotated[int, Field(ge=0)]


class Unobservable(_File):
    kind: Literal["rotation", "translation"]
    axis_B: Vec3


class ExtrinsicFile(_File):
    """extrinsic.json, as `extrinsic_record` writes it."""

    T_B_S: Pose7
    covariance: Annotated[list[Row6], Field(min_length=6, max_length=6)]
    covariance_tangent: str = ""
    sigma_rot_deg: Sigma3
    sigma_trans_m: Sigma3
    sigma_rot_B_deg: Sigma3 | None = None  # (absent in files written before)
    sigma_trans_B_m: Sigma3 | None = None
    unobservable: list[Unobservable]
    keyframe: Index | None

    @field_validator("covariance")
    @classmethod
    def _a_covariance(cls, rows):
        """Symmetric and positive semi-definite (where it has every number)."""
        if any(v is None for row in rows for v in row):
            return rows
        m = np.asarray(rows, dtype=float)
        scale = max(1.0, float(np.abs(m).max()))
        if not np.allclose(m, m.T, atol=1e-9 * scale):
            raise ValueError("covariance is not symmetric")
        if np.linalg.eigvalsh(m).min() < -1e-9 * scale:
            raise ValueError("covariance is not positive semi-definite")
        return rows


class AssociationRecord(_File):
    landmark: Index
    face: str
    landmark_face: str
    score: float | None
    alignment: Literal[KEPT, DIRECTION, OUT]
    keyframes: list[Index]
    observations: list[tuple[Index, Index]]


class AssociationsFile(_File):
    """associations.json, as `associations_record` writes it."""

    associations: list[AssociationRecord]

    def face_of_observation(self) -> dict[tuple[int, int], str]:
        """(keyframe index, plane index) -> the face that observation was associated with."""
        return {(k, i): a.face for a in self.associations for k, i in a.observations}


class Latency(_File):
    median: float
    p95: float
    max: float


class Tolerance(_File):
    normal_deg: float
    offset_m: float


class SigmaScale(_File):
    rotation: float
    translation: float


class FrontendDrift(_File):
    rotation_deg_per_m: Vec3
    translation_percent: Vec3
    scale_percent: float = 0.0  # (absent before the scale was fitted)
    odometry_sigma_scale: SigmaScale


class Challenge(_File):
    complement_taken: bool
    margin: float
    contested_faces: list[str]
    rival_probability: float | None = Field(default=None, ge=0, le=1)


class SummaryFile(_File):
    """summary.json, as `summary_record` writes it (docs/formats.md, "Run outputs")."""

    mode: Literal["online", "offline"]
    finished: bool
    sequence: str | None = None  # (absent when the Python API wrote the run)
    model: str | None = None
    recording: str | None = None  # (`bimgraph run --rrd`)
    keyframes: Index
    landmarks: Index
    matched_landmarks: Index
    matched_faces: Index
    off_plan_landmarks: Index
    timings_s: dict[str, float]
    latency_ms: Latency | None = None
    rounds: Index | None = None
    bim_tolerance: Tolerance | None = None
    frontend_drift: FrontendDrift | None = None
    alignment_challenge: Challenge | None = None
    depth_tilt_sigma_per_m: float | None = Field(default=None, ge=0)


def load_summary(path: Path) -> SummaryFile:
    return parse_model(SummaryFile, read_json(path), str(path))


def run_trajectory(out_dir: Path, name: str) -> tuple[list, list]:
    """A run's trajectory file `name` (stamps, 4x4 poses); of an unfinished run, up to the
    keyframe its summary counts: one killed outright (SIGKILL, power) between two saves of its
    JSON files wrote trajectory lines past the last, which its associations and extrinsic do
    not cover."""
    stamps, poses = read_tum(Path(out_dir) / name)
    if (path := Path(out_dir) / SUMMARY).is_file() and not (summary := load_summary(path)).finished:
        stamps, poses = stamps[:summary.keyframes], poses[:summary.keyframes]
    return stamps, poses


def load_extrinsic(path: Path) -> ExtrinsicFile:
    return parse_model(ExtrinsicFile, read_json(path), str(path))


def load_associations(path: Path) -> AssociationsFile:
    return parse_model(AssociationsFile, read_json(path), str(path))


def extrinsic_record(T_B_S: np.ndarray, cov: np.ndarray, unobservable: list[dict], keyframe: int | None) -> dict:
    sigma_rot_B, sigma_trans_B = sigmas_in_B(T_B_S, cov)
    return {"T_B_S": _pose7(T_B_S), "covariance": [[float(v) for v in row] for row in cov],
            "covariance_tangent": "gtsam Pose3: rotation (rad), then translation (m), right perturbation",
            "sigma_rot_deg": [float(np.degrees(np.sqrt(v))) for v in np.diag(cov)[:3]],
            "sigma_trans_m": [float(np.sqrt(v)) for v in np.diag(cov)[3:]],
            "sigma_rot_B_deg": [float(np.degrees(v)) for v in sigma_rot_B],
            "sigma_trans_B_m": [float(v) for v in sigma_trans_B],
            "unobservable": unobservable, "keyframe": keyframe}


def associations_record(landmarks: list[Landmark]) -> dict:
    """One record per (landmark, face): a landmark matched to a group of coplanar faces is
    listed once for each face its observations lie on."""
    records = []
    for lm in landmarks:
        if lm.face is None:
            continue
        by_face: dict[str, list] = {}
        for obs, face in zip(lm.observations, lm.observation_faces or [lm.face] * len(lm.observations)):
            by_face.setdefault(face, []).append(obs)
        for face, observations in by_face.items():
            records.append({"landmark": lm.id, "face": face, "landmark_face": lm.face, "score": _finite(lm.score),
                            "alignment": lm.alignment,
                            "keyframes": sorted({k for k, _ in observations}),
                            "observations": [list(o) for o in observations]})
    return {"associations": records}


def landmarks_record(landmarks: list[Landmark], T_B_S: np.ndarray) -> dict:
    out = []
    for lm in landmarks:
        plane_S = lm.plane_S
        out.append({"id": lm.id, "anchor": lm.anchor, "plane_A": _plane(lm.plane_A), "plane_S": _plane(plane_S),
                    "plane_B": _plane(plane_from_frame(plane_S, T_B_S)),
                    "covariance_A": [[float(v) for v in row] for row in lm.cov_A],
                    "extent_S": [[round(float(v), 4) for v in p] for p in lm.extent_in(np.eye(4))],
                    "area": round(float(lm.area), 4), "face": lm.face, "rejected_faces": sorted(lm.rejected),
                    "observations": len(lm.observations)})
    return {"frame": "plane_S in S, plane_B in B with the final T_B_S, plane_A in the anchor keyframe", "landmarks": out}


def _seconds(timings: dict) -> dict:
    return {k: round(v, 6) for k, v in timings.items()}


def summary_record(mode: str, timings: dict, latencies_s: list[float], n_keyframes: int, landmarks: list[Landmark],
                   finished: bool, rounds: int = 0, inputs: dict | None = None,
                   bim_tolerance: tuple[float, float] | None = None, frontend_drift: dict | None = None,
                   alignment_challenge: dict | None = None, depth_tilt_sigma_per_m: float | None = None) -> dict:
    summary = {"mode": mode, "finished": finished, **(inputs or {}), "keyframes": n_keyframes, "landmarks": len(landmarks),
               "matched_landmarks": sum(lm.face is not None for lm in landmarks),
               "matched_faces": len({lm.face for lm in landmarks if lm.face is not None}),
               # matches the alignment does not keep whole: walls found off plan (offline GNC)
               "off_plan_landmarks": sum(lm.face is not None and lm.alignment != KEPT for lm in landmarks),
               "timings_s": _seconds(timings)}
    if latencies_s:
        ms = np.asarray(latencies_s) * 1e3
        summary["latency_ms"] = {"median": float(np.median(ms)), "p95": float(np.percentile(ms, 95)), "max": float(ms.max())}
    if rounds:
        summary["rounds"] = rounds
    if bim_tolerance is not None:
        summary["bim_tolerance"] = {"normal_deg": round(float(np.degrees(bim_tolerance[0])), 4),
                                    "offset_m": round(float(bim_tolerance[1]), 5)}
    if frontend_drift is not None:
        summary["frontend_drift"] = frontend_drift
    if alignment_challenge is not None:
        summary["alignment_challenge"] = alignment_challenge
    if depth_tilt_sigma_per_m is not None:
        summary["depth_tilt_sigma_per_m"] = depth_tilt_sigma_per_m
    return summary


class TumAppender:
    """A TUM file written one complete, flushed line at a time."""

    def __init__(self, path: Path):
        self._fh = open(path, "w")
        self._fh.write(format_tum([], []))
        self._fh.flush()

    def append(self, stamp: float, T: np.ndarray) -> None:
        self._fh.write(format_tum([stamp], [T]).split("\n", 1)[1])
        self._fh.flush()

    def close(self) -> None:
        self._fh.close()


def _as_of(landmarks: list[Landmark], last: int) -> list[Landmark]:
    """The landmarks as keyframe `last` left them, in their observations: a keyframe stopped
    half-way (Ctrl-C) may have added its own, and landmarks of its own, which the
    trajectories, ending at `last`, do not hold."""
    out = []
    for lm in landmarks:
        kept = [n for n, (k, _) in enumerate(lm.observations) if k <= last]
        if not kept:
            continue
        if len(kept) < len(lm.observations):
            faces = lm.observation_faces
            lm = replace(lm, observations=[lm.observations[n] for n in kept], centres_A=[lm.centres_A[n] for n in kept],
                         observation_faces=None if faces is None else [faces[n] for n in kept])
        out.append(lm)
    return out


class OnlineWriter:
    """Writes an online run's outputs incrementally (see the module docstring)."""

    def __init__(self, out_dir: Path, write_every: int, inputs: dict | None = None):
        self.inputs = inputs
        self.out = Path(out_dir)
        ensure_folder(self.out)
        self.write_every = write_every
        self.bim = TumAppender(self.out / TRAJECTORY_BIM)
        self.slam = TumAppender(self.out / TRAJECTORY_SLAM)
        self.latencies: list[float] = []
        self.T_B_C: list[np.ndarray] = []
        self.last: KeyframeResult | None = None
        self._summary: dict | None = None  # as the last snapshot wrote it

    def keyframe(self, result: KeyframeResult, backend) -> None:
        with uninterrupted():  # (a snapshot after a stop counts the lines the trajectories hold)
            self.bim.append(result.stamp, result.T_B_C)
            self.slam.append(result.stamp, result.T_S_C)
            self.latencies.append(result.latency_s)
            self.T_B_C.append(result.T_B_C)
            self.last = result
        if len(self.latencies) % self.write_every == 0:
            self.snapshot(backend, finished=False)

    def snapshot(self, backend, finished: bool, timings: dict | None = None) -> None:
        if self.last is None:  # (stopped at its first keyframe: a summary that says so, and nothing else)
            write_json(self.out / SUMMARY, summary_record("online", timings or {}, [], 0, [], finished, inputs=self.inputs))
            return
        backend.resolve_faces(self.last.T_B_S)
        landmarks = _as_of(backend.landmarks.current(), self.last.index)
        write_json(self.out / EXTRINSIC, extrinsic_record(self.last.T_B_S, self._covariance(backend), backend.unobservable(),
                                                          self.last.index))
        write_json(self.out / ASSOCIATIONS, associations_record(landmarks))
        write_json(self.out / LANDMARKS, landmarks_record(landmarks, self.last.T_B_S))
        self._summary = summary_record("online", timings or {}, self.latencies, len(self.latencies), landmarks, finished,
                                       inputs=self.inputs, bim_tolerance=backend.bim_tolerance,
                                       frontend_drift=backend.odometry.summary() if backend.drift_fitted else None,
                                       depth_tilt_sigma_per_m=backend.tilt.sigma_per_m if backend.tilt is not None else None)
        write_json(self.out / SUMMARY, self._summary)

    def finish(self, timings: dict, alignment_challenge: dict | None = None) -> None:
        """Mark the run, as its last snapshot wrote it, finished, with these timings added, and
        the deviation step's robust alignment challenge, if it judged."""
        if self._summary is None:
            return
        challenge = {} if alignment_challenge is None else {"alignment_challenge": alignment_challenge}
        self._summary = {**self._summary, "finished": True,
                         "timings_s": {**self._summary["timings_s"], **_seconds(timings)}, **challenge}
        write_json(self.out / SUMMARY, self._summary)

    def _covariance(self, backend) -> np.ndarray:
        """The last keyframe's extrinsic covariance: its result's or, where the backend skipped
        it, the graph's now (the same state, unless a keyframe stopped half-way: then the
        graph's if it can give one, else NaN, so that what was written stays written)."""
        if np.isfinite(self.last.cov_T_B_S).all():
            return self.last.cov_T_B_S
        try:
            return backend.extrinsic_covariance()
        except Exception:  # a graph left inconsistent by the failure
            return np.full((6, 6), np.nan)

    def close(self) -> None:
        self.bim.close()
        self.slam.close()


# (stamps are written with six decimals)
_STAMP_TOL = 1e-5


def check_stamps(run: str, stamps: np.ndarray, keyframes, seq_root) -> None:
    """A run's trajectory `stamps` must be those of the first of a sequence's `keyframes` (an
    unfinished online run covers a prefix): else it is another sequence's run, an InputError."""
    if len(stamps) > len(keyframes) or \
            np.abs(np.array([kf.stamp for kf in keyframes[:len(stamps)]]) - np.asarray(stamps)).max(initial=0.0) > _STAMP_TOL:
        raise InputError(f"{run}: its trajectory's stamps are not those of {seq_root}'s keyframes")


def write_results(out_dir: Path, results: Results, inputs: dict | None = None, finished: bool = True) -> None:
    """All outputs of a run at once (offline runs) but the deviation report."""
    out = Path(out_dir)
    ensure_folder(out)
    write_tum(out / TRAJECTORY_BIM, results.stamps, results.T_B_C)
    write_tum(out / TRAJECTORY_SLAM, results.stamps, results.T_S_C)
    write_json(out / EXTRINSIC, extrinsic_record(results.T_B_S, results.cov_T_B_S, results.unobservable, None))
    write_json(out / ASSOCIATIONS, associations_record(results.landmarks))
    write_json(out / LANDMARKS, landmarks_record(results.landmarks, results.T_B_S))
    write_summary(out, results, inputs, finished)


def write_summary(out_dir: Path, results: Results, inputs: dict | None = None, finished: bool = True) -> None:
    """`summary.json` of a run written by `write_results`."""
    write_json(Path(out_dir) / SUMMARY, summary_record(
        results.mode, results.timings, [], len(results.stamps), results.landmarks, finished, results.rounds, inputs,
        results.bim_tolerance, results.frontend_drift, results.alignment_challenge, results.depth_tilt_sigma_per_m))
