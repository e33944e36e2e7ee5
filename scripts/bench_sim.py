"""Simulator benchmark: long sequences of every building in both sensor modes, and the
calibration of the planes sensor's noise against planes extracted from simulated depth.

`sequences` simulates each building (the generated office and site, and shared IFC models)
with --sensor planes and --sensor depth, validates what it wrote, and prints keyframes,
detections, distance walked, measured drift and times (wall clock and CPU of the process).

`calibrate` extracts planes (bimgraph's extractor) from the noisy depth of a simulated depth
sequence, matches each to the as-built element under most of its pixels (ground-truth
labels), and compares its error to the noise the planes sensor draws for the same view:
`z = error / sigma_model` should have an RMS near 1 if the planes sensor is calibrated.

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
from bimgraph.geometry import normal_angle_deg, plane_to_frame
from bimgraph.planes.extractor import PlaneExtractor
from bimgraph.planes.sequence import load_depth
from bimgraph.sequence.format import load_sequence
from bimgraph.sequence.groundtruth import LABELS_FOLDER, load_groundtruth
from bimgraph.sim.observe import plane_sigmas
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
    rows = []
    for kf, T_B_C in list(zip(seq.keyframes, gt.T_B_C))[::args.every]:
        extraction = extractor.extract(load_depth(seq, kf, seq.meta.camera))
        truth = cv2.imread(str(args.seqdir / "groundtruth" / LABELS_FOLDER / Path(kf.depth).name), cv2.IMREAD_UNCHANGED).astype(int) - 1
        labels = extraction.labels
        for i, plane in enumerate(extraction.planes):
            under = truth[labels == i]
            under = under[under >= 0]
            if len(under) == 0:
                continue
            element = np.bincount(under).argmax()
            if np.mean(under == element) < PURITY:
                continue
            true_C = plane_to_frame(planes_B[element], T_B_C)
            if true_C[3] <= 0:
                continue
            r = float(np.linalg.norm(plane.centre))
            cos_view = abs(float(plane.n @ plane.centre)) / r
            sigma_n, sigma_d = plane_sigmas(r, cos_view, plane.area, cfg.sim.observe)
            angle = np.radians(normal_angle_deg(plane.n, true_C[:3]))
            rows.append((r, np.degrees(angle), plane.d - true_C[3], angle / sigma_n, (plane.d - true_C[3]) / sigma_d,
                         np.degrees(np.sqrt(plane.cov[0, 0])), np.sqrt(plane.cov[2, 2])))
    a = np.array(rows)
    print(f"{len(a)} extracted planes matched to as-built surfaces (purity >= {PURITY})")
    print("range m | n | median normal err deg | median |offset err| cm | RMS z_normal/sqrt2 | RMS z_offset | extractor sigma deg, cm (median)")
    for lo, hi in [(0, 2), (2, 3), (3, 4), (4, 8)]:
        b = a[(a[:, 0] >= lo) & (a[:, 0] < hi)]
        if len(b):
            print(f"{lo}-{hi} | {len(b)} | {np.median(b[:, 1]):.2f} | {100 * np.median(np.abs(b[:, 2])):.2f} | "
                  f"{np.sqrt(np.mean(b[:, 3] ** 2) / 2):.2f} | {np.sqrt(np.mean(b[:, 4] ** 2)):.2f} | "
                  f"{np.median(b[:, 5]):.3f}, {100 * np.median(b[:, 6]):.3f}")
    print(f"all | {len(a)} | {np.median(a[:, 1]):.2f} | {100 * np.median(np.abs(a[:, 2])):.2f} | "
          f"{np.sqrt(np.mean(a[:, 3] ** 2) / 2):.2f} | {np.sqrt(np.mean(a[:, 4] ** 2)):.2f}")


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
    args = parser.parse_args()
    {"sequences": sequences, "calibrate": calibrate}[args.command](args)


if __name__ == "__main__":
    main()
