"""Simulator benchmark: long sequences of every building in both sensor modes, and the
calibration of the planes sensor's noise against planes extracted from simulated depth.

`sequences` simulates each building (the generated office and site, and shared IFC models)
with --sensor planes and --sensor depth, validates what it wrote, and prints keyframes,
detections, distance walked, measured drift and times (wall clock and CPU of the process).

`calibrate` extracts planes (bimgraph's extractor) from the noisy depth of a simulated depth
sequence, matches each to the as-built element under most of its pixels (ground-truth
labels), and compares the distribution of their errors (median and 90th percentile of the
normal angle and of the offset, by range) with that of the planes sensor's detections drawn
for the same views: ratios near 1 mean the planes sensor is calibrated.

    .venv/bin/python scripts/bench_sim.py sequences --keyframes 500 --out /tmp/bench_sim
    .venv/bin/python scripts/bench_sim.py calibrate /tmp/bench_sim/office-depth
"""

from __future__ import annotations

import argparse
import shutil
import time
from pathlib import Path

import cv2
import numpy as np

from bimgraph.config import Config
from bimgraph.planes.extractor import PlaneExtractor
from bimgraph.planes.sequence import load_depth
from bimgraph.sequence.format import load_sequence
from bimgraph.sequence.groundtruth import LABELS_FOLDER, load_groundtruth
from bimgraph.sim.calibration import compare, match_errors
from bimgraph.sim.simulate import SimOptions, simulate

SAMPLES = Path(__file__).resolve().parents[2] / "shared" / "data" / "ifc"
DEFAULT_MODELS = ["AC20-FZK-Haus.ifc", "Duplex_A_20110907.ifc", "2Storey_AC22_IFC2X3.ifc"]
# An extracted plane is matched to the element under at least this share of its pixels.
PURITY = 0.8


def sequences(args) -> None:
    from rich.console import Console
    from rich.table import Table

    buildings = [("office", None), ("site", None)] + [(Path(m).stem, SAMPLES / m) for m in args.models]
    table = Table("building", "sensor", "keyframes", "planes/kf", "walked m", "drift %", "yaw deg/m",
                  "wall s", "cpu s", "stages s", title=f"bimgraph simulate, {args.keyframes} keyframes")
    for name, ifc in buildings:
        for sensor in args.sensors:
            out = args.out / f"{name}-{sensor}"
            shutil.rmtree(out, ignore_errors=True)
            opts = SimOptions(output=out, scenario=None if ifc else name, ifc=ifc, sensor=sensor,
                              keyframes=args.keyframes, seed=args.seed)
            wall, cpu = time.perf_counter(), time.process_time()
            summary = simulate(opts, Config())
            wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
            seq = load_sequence(out)  # validates every line
            assert len(seq.keyframes) == args.keyframes
            d = summary["drift"]
            table.add_row(name, sensor, str(len(seq.keyframes)), f"{summary['planes'] / len(seq.keyframes):.2f}",
                          f"{summary['distance_m']:.0f}", f"{d['final_drift_percent']:.2f}", f"{d['yaw_drift_deg_per_m']:.3f}",
                          f"{wall:.1f}", f"{cpu:.1f}", " ".join(f"{k} {v:.1f}" for k, v in summary["timings_s"].items()))
            Console().print(f"{name} {sensor}: done in {wall:.1f} s")
            if sensor == "depth" and not args.keep_depth:
                for folder in ("depth", "rgb", f"groundtruth/{LABELS_FOLDER}"):
                    shutil.rmtree(out / folder, ignore_errors=True)
    Console(width=200).print(table)


def calibrate(args) -> None:
    cfg = Config()
    seq, gt = load_sequence(args.seqdir), load_groundtruth(args.seqdir)
    planes_B = np.array([e["plane"] for e in gt.as_built["elements"]])
    extractor = PlaneExtractor(seq.meta.camera, cfg.planes, cfg.depth_noise)
    extractions, truths, poses = [], [], []
    for kf, T_B_C in list(zip(seq.keyframes, gt.T_B_C))[::args.every]:
        extractions.append(extractor.extract(load_depth(seq, kf, seq.meta.camera)))
        truth = cv2.imread(str(args.seqdir / "groundtruth" / LABELS_FOLDER / Path(kf.depth).name), cv2.IMREAD_UNCHANGED)
        truths.append(truth.astype(int) - 1)
        poses.append(T_B_C)
    errors = match_errors(extractions, truths, poses, planes_B, PURITY)
    stats = compare(errors, cfg.sim.observe, np.random.default_rng(args.seed), args.draws)
    noise = seq.meta.simulated.get("depth_noise") or {}
    print(f"{len(errors.range_m)} extracted planes matched to as-built surfaces (purity >= {PURITY}); depth noise: "
          f"scale {noise.get('scale_sigma')}, tilt {noise.get('tilt_sigma_per_m')}, curvature {noise.get('curvature_sigma_per_m')} /m; planes sensor: "
          f"{cfg.sim.observe.noise.normal_sigma_deg:g} deg, {100 * cfg.sim.observe.noise.offset_sigma_m:g} cm at 1 m")
    print("range m | n | normal deg median, p90: depth / planes (ratio) | offset cm median, p90: depth / planes (ratio)")
    for b in stats:
        r = b.ratios()
        cells = [f"{b.depth[k][0]:.2f}, {b.depth[k][1]:.2f} / {b.planes[k][0]:.2f}, {b.planes[k][1]:.2f} "
                 f"({r[k][0]:.2f}, {r[k][1]:.2f})" for k in ("normal_deg", "offset_cm")]
        print(f"{b.lo_m:g}-{b.hi_m:g} | {b.count} | {cells[0]} | {cells[1]}")


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)
    s = sub.add_parser("sequences")
    s.add_argument("--keyframes", type=int, default=500)
    s.add_argument("--seed", type=int, default=0)
    s.add_argument("--out", type=Path, default=Path("/tmp/bench_sim"))
    s.add_argument("--models", nargs="*", default=DEFAULT_MODELS)
    s.add_argument("--sensors", nargs="*", default=["planes", "depth"])
    s.add_argument("--keep-depth", action="store_true", help="keep the images (about 0.5 MB a keyframe)")
    c = sub.add_parser("calibrate")
    c.add_argument("seqdir", type=Path)
    c.add_argument("--every", type=int, default=5, help="use every n-th keyframe")
    c.add_argument("--draws", type=int, default=20, help="planes-sensor detections drawn per extracted plane")
    c.add_argument("--seed", type=int, default=0, help="seed of the planes sensor's draws")
    args = parser.parse_args()
    {"sequences": sequences, "calibrate": calibrate}[args.command](args)


if __name__ == "__main__":
    main()
