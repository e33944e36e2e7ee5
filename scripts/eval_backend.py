"""Accuracy of the backend on simulated sequences (those with a `groundtruth/` folder).

For each sequence: association precision and recall against the true face of every
observation, extrinsic error (deg, cm), ATE of `T_B_C` without re-alignment, for online (at
the last keyframe / causal trajectory), offline, and offline given the true associations
(oracle); plus the ATE of the raw front-end placed with the initial alignment.

    python scripts/eval_backend.py SEQDIR [SEQDIR ...] [--config FILE]
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

from bimgraph.backend import run_offline, run_online
from bimgraph.backend.pipeline import initial_alignment, load_model, model_path, oracle_of
from bimgraph.config import load_config
from bimgraph.evaluation.metrics import association_scores, ate, extrinsic_error
from bimgraph.sequence.format import load_sequence
from bimgraph.sequence.groundtruth import load_groundtruth


def evaluate(root: Path, cfg) -> list[dict]:
    sequence = load_sequence(root)
    plane_map = load_model(model_path(root, sequence.meta, None), cfg)
    initial = initial_alignment(sequence.meta, cfg)
    gt = load_groundtruth(root)
    truth = oracle_of(root)
    frontend = ate([initial.T_B_S @ kf.pose for kf in sequence.keyframes], gt.T_B_C)
    rows = []
    for mode in ("online", "offline", "oracle"):
        start = time.perf_counter()
        if mode == "online":
            results = run_online(sequence.keyframes, plane_map, cfg.backend, initial)
        else:
            results = run_offline(sequence.keyframes, plane_map, cfg.backend, initial,
                                  oracle=truth if mode == "oracle" else None)
        seconds = time.perf_counter() - start
        precision, recall = association_scores(results.associations(), truth)
        rot_deg, trans_cm = extrinsic_error(results.T_B_S, gt.T_B_S)
        rows.append({"sequence": root.name, "mode": mode, "precision": precision, "recall": recall, "rot_deg": rot_deg,
                     "trans_cm": trans_cm, "ate_cm": 100 * ate(results.T_B_C, gt.T_B_C), "frontend_ate_cm": 100 * frontend,
                     "seconds": seconds, "tolerance": results.bim_tolerance, "unobservable": [u["kind"][0] + str([round(a, 2) for a in u["axis_B"]]) for u in results.unobservable]})
    return rows


def tolerance(value) -> str:
    return "" if value is None else f"{math.degrees(value[0]):.2f}, {1000 * value[1]:.1f}"


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("sequences", type=Path, nargs="+")
    parser.add_argument("--config", type=Path, default=None)
    args = parser.parse_args()
    cfg = load_config(args.config)
    print("| sequence | mode | precision | recall | T_B_S error deg | cm | ATE cm | front-end ATE cm | s | wall tolerance deg, mm | unobservable |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for root in args.sequences:
        for r in evaluate(root, cfg):
            print(f"| {r['sequence']} | {r['mode']} | {r['precision']:.4f} | {r['recall']:.4f} | {r['rot_deg']:.3f} | {r['trans_cm']:.2f} "
                  f"| {r['ate_cm']:.2f} | {r['frontend_ate_cm']:.1f} | {r['seconds']:.1f} | {tolerance(r['tolerance'])} | {' '.join(r['unobservable'])} |", flush=True)


if __name__ == "__main__":
    main()
