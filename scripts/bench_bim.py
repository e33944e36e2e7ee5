#!/usr/bin/env python
"""Time the BIM import against a bare ifcopenshell geometry iteration over the same walls.

For each model: walls, side-face sections, our seconds (`import_ifc`, end to end), and the
seconds of opening the file and iterating the walls' geometry with ifcopenshell's default
settings (openings subtracted, the geometry whose faces we report) with the same thread
count; the ratio ours / bare is the issue's goal (<= 1.2). The bare iteration without opening
subtraction (the settings our import iterates with) is shown for reference. Median of
`--repeat` rounds, the three taking turns, after one warm-up run that loads the libraries.

Usage: scripts/bench_bim.py [--repeat N] [--threads N] [--cpu] [MODEL.ifc ...]
(default: every model in the IFC samples folder, all cores on both sides)
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from pathlib import Path

import ifcopenshell
import ifcopenshell.geom
from rich.console import Console
from rich.table import Table

from bimgraph.bim.ifc_import import import_ifc
from bimgraph.bim.ifc_read import available_cores
from bimgraph.config import BimImportConfig

ROOT = Path(__file__).resolve().parents[1]


def bare_iteration(path: Path, subtract_openings: bool, threads: int) -> int:
    model = ifcopenshell.open(str(path))
    settings = ifcopenshell.geom.settings()
    settings.set("disable-opening-subtractions", not subtract_openings)
    iterator = ifcopenshell.geom.iterator(settings, model, threads, include=model.by_type("IfcWall"))
    count = 0
    if iterator.initialize():
        while True:
            iterator.get()
            count += 1
            if not iterator.next():
                break
    return count


def median_of(repeat: int, clock, **jobs) -> dict[str, float]:
    """Median seconds of each job by `clock` over `repeat` rounds; the jobs take turns within
    a round, so that a machine shared with others loads them alike."""
    seconds = {name: [] for name in jobs}
    for _ in range(repeat):
        for name, job in jobs.items():
            started = clock()
            job()
            seconds[name].append(clock() - started)
    return {name: statistics.median(values) for name, values in seconds.items()}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("models", nargs="*", type=Path)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--threads", type=int, default=0, help="geometry threads on both sides (0: all cores)")
    parser.add_argument("--cpu", action="store_true", help="time by the process's CPU time, steadier than "
                        "the wall clock on a shared machine (with --threads 1: it adds up all threads)")
    args = parser.parse_args()
    clock = time.process_time if args.cpu else time.perf_counter
    folder = Path(os.environ.get("BIMGRAPH_IFC_SAMPLES", ROOT.parent / "shared" / "data" / "ifc"))
    models = args.models or sorted(folder.glob("*.ifc"))
    cfg = BimImportConfig(threads=args.threads)
    threads = cfg.threads or available_cores()

    kind = "CPU" if args.cpu else "wall-clock"
    table = Table(title=f"BIM import against a bare geometry iteration "
                        f"({threads} threads, median {kind} seconds of {args.repeat})")
    for column in ("model", "walls", "faces", "ours s", "bare s", "ratio", "bare s, no subtraction"):
        table.add_column(column, justify="left" if column == "model" else "right")
    for path in models:
        plane_map, _ = import_ifc(path, cfg)  # warm-up
        walls = bare_iteration(path, True, threads)
        seconds = median_of(args.repeat, clock, ours=lambda: import_ifc(path, cfg),
                          bare=lambda: bare_iteration(path, True, threads),
                          bare_fast=lambda: bare_iteration(path, False, threads))
        ours, bare, bare_fast = seconds["ours"], seconds["bare"], seconds["bare_fast"]
        table.add_row(path.name, str(walls), str(len(plane_map.faces)), f"{ours:.3f}", f"{bare:.3f}",
                      f"{ours / bare:.2f}", f"{bare_fast:.3f}")
    Console().print(table)


if __name__ == "__main__":
    main()
