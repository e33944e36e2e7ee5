"""Evaluation from files: a run's output folder and a simulated sequence in, `metrics.json`
and a table out. The I/O side of `evaluate` and `baselines`."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bimgraph.backend.pipeline import initial_alignment, load_model, model_path
from bimgraph.backend.results import ASSOCIATIONS, EXTRINSIC, SUMMARY, TRAJECTORY_BIM
from bimgraph.config import Config
from bimgraph.errors import FormatError, InputError
from bimgraph.evaluation.baselines import estimate_extrinsics, matched_planes
from bimgraph.evaluation.evaluate import Estimate, evaluate
from bimgraph.files import read_json, write_json
from bimgraph.geometry import pose_from_tum
from bimgraph.sequence.format import Sequence, load_sequence
from bimgraph.sequence.groundtruth import GroundTruth, load_groundtruth
from bimgraph.sequence.tum import read_tum

METRICS_FILE = "metrics.json"


def load_estimate(out_dir: Path) -> Estimate:
    """A bimgraph run's outputs as an Estimate."""
    out_dir = Path(out_dir)
    if not out_dir.is_dir():
        raise InputError(f"{out_dir}: no such output folder")
    _, T_B_C = read_tum(out_dir / TRAJECTORY_BIM)
    extrinsic = read_json(out_dir / EXTRINSIC)
    try:
        T_B_S = pose_from_tum(extrinsic["T_B_S"])
    except (KeyError, TypeError, ValueError):
        raise FormatError(f"{out_dir / EXTRINSIC}: T_B_S must be 7 numbers") from None
    associations = {}
    for record in read_json(out_dir / ASSOCIATIONS).get("associations", []):
        for k, i in record["observations"]:
            associations[(int(k), int(i))] = record["face"]
    return Estimate(list(T_B_C), T_B_S, associations)


class Evaluation:
    """A simulated sequence loaded once, against which any number of methods are measured."""

    def __init__(self, seq_dir: Path, cfg: Config):
        self.cfg = cfg
        self.sequence: Sequence = load_sequence(seq_dir)
        self.gt: GroundTruth = load_groundtruth(seq_dir)
        if len(self.gt.T_B_C) != len(self.sequence.keyframes):
            raise FormatError(f"{seq_dir}: ground truth has {len(self.gt.T_B_C)} poses for {len(self.sequence.keyframes)} keyframes")
        self.plane_map = load_model(model_path(seq_dir, self.sequence.meta, None), cfg)
        self.manual = initial_alignment(self.sequence.meta, cfg)

    def metrics(self, estimate: Estimate) -> dict:
        if len(estimate.T_B_C) != len(self.sequence.keyframes):
            raise FormatError(f"the run has {len(estimate.T_B_C)} poses for {len(self.sequence.keyframes)} keyframes "
                              "(an unfinished online run?)")
        return evaluate(estimate, self.sequence.keyframes, self.gt, self.plane_map)

    def truth(self) -> Estimate:
        """The ground truth as if it were a method: its wall errors are the floor that the
        detections' noise and the as-built deviations leave to every method."""
        return Estimate(list(self.gt.T_B_C), self.gt.T_B_S, None)

    def baseline(self, method: str, associations) -> Estimate:
        """The paper's `method` on this sequence, with the given associations."""
        keyframes = self.sequence.keyframes
        matches = matched_planes(keyframes, associations, self.plane_map)
        T_B_S = estimate_extrinsics(method, keyframes, matches, self.manual, self.cfg.backend, self.cfg.baselines)
        T_B_C = [T @ kf.pose for T, kf in zip(T_B_S, keyframes)]
        return Estimate(T_B_C, T_B_S[-1], associations)


def run_timings(out_dir: Path) -> dict:
    """The run's total seconds and median per-keyframe latency, from its summary.json."""
    summary = read_json(Path(out_dir) / SUMMARY)
    out = {"run_s": summary.get("timings_s", {}).get("total_s")}
    if "latency_ms" in summary:
        out["latency_median_ms"] = summary["latency_ms"]["median"]
    return out


def write_metrics(out_dir: Path, metrics: dict) -> None:
    write_json(Path(out_dir) / METRICS_FILE, metrics)


def summary_row(name: str, metrics: dict) -> dict:
    """The aggregates of a metrics record, without the per-keyframe series."""
    return {"method": name, **{k: v for k, v in metrics.items() if k != "per_keyframe" and np.isscalar(v)}}
