"""Backend speed on the synthetic world of `bimgraph.backend.synthetic`, and on sequences.

For 500 and 2000 keyframes of the synthetic world: online per-keyframe latency (median, p95,
max, association included), the iSAM2 updates alone within it (the same graph without
association), and the offline total, and the online run's time with the Rerun viewer logging
against without. Goals: online median <= 2 ms and p95 <= 10 ms at 2000 keyframes, at most 3x
the bare iSAM2 update; offline <= 1 s at 2000 keyframes.

`--sequences` adds the same figures (without the viewer's) for sequence folders, e.g. the
simulator's walks: their walls are seen again and again across the walk, which the synthetic
world's rooms, each seen only while the camera is in it, do not show, and which makes iSAM2's
work per keyframe grow.

    python scripts/bench_backend.py [--sizes 500 2000] [--sequences SEQ ...] [--profile]
"""

from __future__ import annotations

import os

# one BLAS thread, as `bimgraph` runs (bimgraph/cli.py: on a busy machine OpenBLAS's threads spin
# against each other); set before numpy loads, the environment overrides
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse
import itertools
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from bimgraph.backend.offline import run_offline
from bimgraph.backend.online import Backend
from bimgraph.backend.pipeline import initial_alignment, load_model, model_path
from bimgraph.backend.synthetic import make_scene
from bimgraph.config import BackendConfig, Config
from bimgraph.errors import BimgraphError
from bimgraph.sequence.format import load_sequence
from bimgraph.viewer.follow import RerunListener
from bimgraph.viewer.recording import open_recording
from bimgraph.viewer.rerun_viewer import RerunViewer

os.environ.setdefault("RERUN_ANALYTICS", "0")


def online_with_viewer_s(scene, cfg: BackendConfig) -> float:
    """Seconds of the same online run with the Rerun viewer logging to a file (issue 7's
    budget: at most 1.2x the run without it)."""
    with tempfile.TemporaryDirectory() as tmp:
        start = time.perf_counter()
        viewer = RerunViewer(open_recording(Path(tmp) / "bench.rrd"), scene.plane_map, scene.initial.T_B_S)
        backend = Backend(scene.plane_map, cfg, scene.initial, listener=RerunListener(viewer))
        for kf in scene.keyframes:
            backend.process(kf)
        viewer.close()
        return time.perf_counter() - start


def bench_synthetic(n: int, cfg: BackendConfig) -> dict:
    scene = make_scene(n, rooms=(5, 4), seed=1)
    online_with_viewer_s(make_scene(20, rooms=(2, 2), seed=1), cfg)  # rerun's one-off start-up, not per run
    figures = bench(f"synthetic {n}", scene.keyframes, scene.plane_map, scene.initial, cfg)
    return {**figures, "viewer": f"{online_with_viewer_s(scene, cfg) / figures['online_s']:.2f}x"}


def load_run(root: Path, cfg: Config) -> tuple:
    """A sequence folder as `bench`'s first four arguments."""
    sequence = load_sequence(root)
    plane_map = load_model(model_path(root, sequence.meta, None), cfg)
    return root.name, sequence.keyframes, plane_map, initial_alignment(sequence.meta, cfg)


def bench(name: str, keyframes, plane_map, initial, cfg: BackendConfig) -> dict:
    backend = Backend(plane_map, cfg, initial)
    start = time.perf_counter()
    results = [backend.process(kf) for kf in keyframes]
    online = time.perf_counter() - start
    latency = np.array([r.latency_s for r in results]) * 1e3
    isam2 = np.array([r.isam2_s for r in results]) * 1e3
    start = time.perf_counter()
    run_offline(keyframes, plane_map, cfg, initial)
    offline = time.perf_counter() - start
    return {"name": name, "keyframes": len(keyframes), "observations": sum(len(kf.planes) for kf in keyframes), "online_s": online,
            "landmarks": len(backend.landmarks), "median": np.median(latency), "p95": np.percentile(latency, 95),
            "max": latency.max(), "isam2_median": np.median(isam2), "isam2_p95": np.percentile(isam2, 95),
            "ratio": np.median(latency) / np.median(isam2), "offline_s": offline}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="*", default=[500, 2000], help="keyframes of the synthetic world")
    parser.add_argument("--sequences", type=Path, nargs="*", default=[], help="sequence folders to run as well")
    parser.add_argument("--profile", action="store_true", help="profile the largest size and print the top entries")
    args = parser.parse_args()
    cfg = BackendConfig()
    try:  # (before the synthetic runs, which take minutes)
        sequences = [load_run(root, Config()) for root in args.sequences]
    except BimgraphError as err:
        sys.exit(f"bench_backend.py: {err}")
    if args.profile:
        import cProfile
        import pstats

        cProfile.runctx("bench_synthetic(max(args.sizes), cfg)", globals(), {"args": args, "cfg": cfg}, "/tmp/bench_backend.prof")
        pstats.Stats("/tmp/bench_backend.prof").sort_stats("tottime").print_stats(30)
        return
    print("| run | keyframes | observations | landmarks | online median ms | p95 ms | max ms | bare iSAM2 median ms | p95 ms | median / iSAM2 | offline s | online with viewer |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    # (generators: each row is printed as soon as it is measured)
    rows = itertools.chain((bench_synthetic(n, cfg) for n in args.sizes),
                           ({**bench(*run, cfg), "viewer": "-"} for run in sequences))
    for r in rows:
        print(f"| {r['name']} | {r['keyframes']} | {r['observations']} | {r['landmarks']} | {r['median']:.2f} | {r['p95']:.2f} | {r['max']:.1f} "
              f"| {r['isam2_median']:.2f} | {r['isam2_p95']:.2f} | {r['ratio']:.1f}x | {r['offline_s']:.2f} | {r['viewer']} |", flush=True)


if __name__ == "__main__":
    main()
