#!/usr/bin/env python
"""How bimgraph scales with the building: generated offices of N rooms a side of a corridor
on S storeys (`bimgraph.sim.scenarios.office` stacked, written with ifcopenshell.api), each
imported, walked by the simulator on a middle storey, run online and offline against the
plane map, and shown (the recording saved, as `bimgraph view OUT --rrd`).

Prints per model: walls, faces, import seconds, the simulator's seconds (the model imported
again, the storey furnished, the walk planned and observed), the online run's seconds (of them the
deviation report's) and median milliseconds per keyframe, the offline run's seconds, and the
view's. The walk is the same length on every model: what grows is the map around it.

    .venv/bin/python scripts/bench_scale.py --models 8x1 32x4 64x8 --keyframes 600 --out /tmp/bench_scale
"""

from __future__ import annotations

import os

# one BLAS thread, as `bimgraph` runs (see scripts/bench_backend.py); before numpy loads
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse
import dataclasses
import json
import shutil
import time
from pathlib import Path

from rich.console import Console
from rich.table import Table

from bimgraph.backend.pipeline import run
from bimgraph.bim.building import Building, Storey
from bimgraph.bim.ifc_import import import_ifc
from bimgraph.bim.ifc_write import write_ifc
from bimgraph.bim.planemap import save_plane_map
from bimgraph.config import Config
from bimgraph.sim.scenarios import office
from bimgraph.sim.simulate import SimOptions, simulate
from bimgraph.viewer.session import view_outputs


def stacked_office(rooms_per_side: int, storeys: int) -> Building:
    one = office(rooms_per_side=rooms_per_side)
    height = one.storeys[0].height
    return Building(f"office {rooms_per_side}x{storeys}", [Storey(f"Level {i}", i * height, height) for i in range(storeys)],
                    [dataclasses.replace(w, storey=i) for i in range(storeys) for w in one.walls],
                    [dataclasses.replace(s, storey=i) for i in range(storeys) for s in one.spaces])


def timed(job):
    started = time.perf_counter()
    out = job()
    return out, time.perf_counter() - started


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--models", nargs="+", default=["8x1", "32x4", "64x8"],
                        help="rooms a side x storeys, e.g. 64x8 (1056 walls)")
    parser.add_argument("--keyframes", type=int, default=600)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--out", type=Path, default=Path("/tmp/bench_scale"))
    args = parser.parse_args()

    table = Table(title=f"bimgraph on generated offices, a {args.keyframes}-keyframe walk on one storey")
    for column in ("model", "walls", "faces", "import s", "simulate s", "online s", "of it deviations s", "median ms/kf",
                   "offline s", "view s"):
        table.add_column(column, justify="left" if column == "model" else "right")
    for spec in args.models:
        rooms, storeys = (int(v) for v in spec.split("x"))
        folder = args.out / spec
        shutil.rmtree(folder, ignore_errors=True)
        folder.mkdir(parents=True)
        building = stacked_office(rooms, storeys)
        ifc, planes = folder / "model.ifc", folder / "planes.json"
        write_ifc(building, ifc)
        cfg = Config()
        plane_map, import_s = timed(lambda: import_ifc(ifc, cfg.bim)[0])
        save_plane_map(plane_map, planes)
        walk = cfg.model_copy(update={"sim": cfg.sim.model_copy(update={"storey": f"Level {storeys // 2}"})})
        _, simulate_s = timed(lambda: simulate(SimOptions(output=folder / "seq", ifc=ifc, keyframes=args.keyframes,
                                                          seed=args.seed), walk))
        summaries = {}
        for mode in ("online", "offline"):
            run(folder / "seq", folder / mode, mode=mode, bim=planes, config=cfg)
            summaries[mode] = json.loads((folder / mode / "summary.json").read_text())
        _, view_s = timed(lambda: view_outputs(folder / "online", None, cfg, rrd=folder / "view.rrd"))
        online = summaries["online"]
        table.add_row(spec, str(len(building.walls)), str(len(plane_map.faces)), f"{import_s:.2f}", f"{simulate_s:.1f}",
                      f"{online['timings_s']['total_s']:.1f}", f"{online['timings_s']['deviation_report_s']:.1f}",
                      f"{online['latency_ms']['median']:.2f}", f"{summaries['offline']['timings_s']['total_s']:.1f}",
                      f"{view_s:.1f}")
        Console().print(f"{spec}: done")
    Console(width=160).print(table)


if __name__ == "__main__":
    main()
