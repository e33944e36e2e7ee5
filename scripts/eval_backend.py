"""Accuracy of the backend on simulated sequences (those with a `groundtruth/` folder).

For each sequence: association precision and recall against the true face of every
observation, extrinsic error (deg, cm), ATE of `T_B_C` without re-alignment, for online (at
the last keyframe / causal trajectory), offline, and offline given the true associations
(oracle); plus the ATE of the raw front-end placed with the initial alignment, and how honest
the extrinsic's covariance is (NEES of its heading and horizontal position, 3 dof: mean 3 and
above the chi-square 95 % quantile, 7.8, one time in twenty where it is). Over several
sequences, a summary per mode: the spread of one walk's error is about the size of the
differences between settings, so compare settings over many seeds.

    python scripts/eval_backend.py SEQDIR [SEQDIR ...] [--config FILE] [--mode offline ...] [--jobs 2]
"""

from __future__ import annotations

import os

# one BLAS thread, as `bimgraph` runs (bimgraph/cli.py: on a busy machine OpenBLAS's threads spin
# against each other); set before numpy loads, the environment overrides
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse
import functools
import math
import statistics
import time
from pathlib import Path

from scipy.stats import chi2

from bimgraph.backend import run_offline, run_online
from bimgraph.backend.pipeline import depth_tilt, initial_alignment, load_model, model_path, oracle_of
from bimgraph.config import load_config
from bimgraph.evaluation.jobs import run_all
from bimgraph.evaluation.metrics import association_scores, ate, extrinsic_error, extrinsic_nees
from bimgraph.sequence.format import load_sequence
from bimgraph.sequence.groundtruth import load_groundtruth


MODES = ("online", "offline", "oracle")
NEES_95 = chi2.ppf(0.95, 3)


def evaluate(root: Path, cfg, modes=MODES) -> list[dict]:
    sequence = load_sequence(root)
    plane_map = load_model(model_path(root, sequence.meta, None), cfg)
    initial = initial_alignment(sequence.meta, cfg)
    gt = load_groundtruth(root)
    truth = oracle_of(root)
    frontend = ate([initial.T_B_S @ kf.pose for kf in sequence.keyframes], gt.T_B_C)
    rows = []
    tilt = depth_tilt(sequence.meta, cfg)
    for mode in modes:
        start = time.perf_counter()
        if mode == "online":
            results = run_online(sequence.keyframes, plane_map, cfg.backend, initial, tilt=tilt)
        else:
            results = run_offline(sequence.keyframes, plane_map, cfg.backend, initial,
                                  oracle=truth if mode == "oracle" else None, tilt=tilt)
        seconds = time.perf_counter() - start
        precision, recall = association_scores(results.associations(), truth)
        rot_deg, trans_cm = extrinsic_error(results.T_B_S, gt.T_B_S)
        nees = extrinsic_nees(results.T_B_S, results.cov_T_B_S, gt.T_B_S)
        rows.append({"sequence": root.name, "mode": mode, "precision": precision, "recall": recall, "rot_deg": rot_deg,
                     "trans_cm": trans_cm, "nees": nees, "ate_cm": 100 * ate(results.T_B_C, gt.T_B_C), "frontend_ate_cm": 100 * frontend,
                     "seconds": seconds, "tolerance": results.bim_tolerance, "unobservable": [u["kind"][0] + str([round(a, 2) for a in u["axis_B"]]) for u in results.unobservable]})
    return rows


def summary(rows: list[dict]) -> dict:
    """Over the rows of one mode: RMS and median extrinsic position error (cm), how many within
    1 and 2 cm, RMS angle error (deg), RMS ATE (cm), mean NEES and how many beyond its 95 %
    quantile."""
    cm, deg, ate_cm, nees = ([r[k] for r in rows] for k in ("trans_cm", "rot_deg", "ate_cm", "nees"))
    return {"n": len(rows), "rms_cm": _rms(cm), "median_cm": statistics.median(cm),
            "within_1cm": sum(v <= 1.0 for v in cm), "within_2cm": sum(v <= 2.0 for v in cm),
            "rms_deg": _rms(deg), "rms_ate_cm": _rms(ate_cm), "mean_nees": statistics.fmean(nees),
            "nees_beyond_95": sum(v > NEES_95 for v in nees)}


def _rms(values: list[float]) -> float:
    return math.sqrt(sum(v * v for v in values) / len(values))


def tolerance(value) -> str:
    return "" if value is None else f"{math.degrees(value[0]):.2f}, {1000 * value[1]:.1f}"


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("sequences", type=Path, nargs="+")
    parser.add_argument("--config", type=Path, default=None)
    parser.add_argument("--mode", action="append", choices=MODES, dest="modes",
                        help="run only this mode (repeat for several; default: all three)")
    parser.add_argument("--jobs", type=int, default=1,
                        help="sequences evaluated at once, each in a process of its own (the seconds column then "
                             "counts a machine they share)")
    args = parser.parse_args()
    args.modes = args.modes or list(MODES)
    cfg = load_config(args.config)
    print("| sequence | mode | precision | recall | T_B_S error deg | cm | NEES | ATE cm | front-end ATE cm | s | wall tolerance deg, mm | unobservable |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    rows = []
    for sequence_rows in run_all(functools.partial(evaluate, cfg=cfg, modes=args.modes), args.sequences, args.jobs):
        for r in sequence_rows:
            rows.append(r)
            print(f"| {r['sequence']} | {r['mode']} | {r['precision']:.4f} | {r['recall']:.4f} | {r['rot_deg']:.3f} | {r['trans_cm']:.2f} | {r['nees']:.1f} "
                  f"| {r['ate_cm']:.2f} | {r['frontend_ate_cm']:.1f} | {r['seconds']:.1f} | {tolerance(r['tolerance'])} | {' '.join(r['unobservable'])} |", flush=True)
    if len(args.sequences) > 1:
        print("\n| mode | sequences | T_B_S error RMS cm | median cm | within 1 cm | within 2 cm | RMS deg | ATE RMS cm | mean NEES | NEES beyond 95 % |")
        print("|---|---|---|---|---|---|---|---|---|---|")
        for mode in args.modes:
            m = summary([r for r in rows if r["mode"] == mode])
            print(f"| {mode} | {m['n']} | {m['rms_cm']:.2f} | {m['median_cm']:.2f} | {m['within_1cm']} | {m['within_2cm']} "
                  f"| {m['rms_deg']:.3f} | {m['rms_ate_cm']:.2f} | {m['mean_nees']:.2f} | {m['nees_beyond_95']} |")


if __name__ == "__main__":
    main()
