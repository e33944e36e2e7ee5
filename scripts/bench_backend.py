"""Backend speed on the synthetic world of `bimgraph.backend.synthetic`, in one run.

For 500 and 2000 keyframes: online per-keyframe latency (median, p95, max, association
included), the iSAM2 updates alone within it (the same graph without association), and the
offline total, and the online run's time with the Rerun viewer logging against without.
Goals: online median <= 2 ms and p95 <= 10 ms at 2000 keyframes, at most 3x the
bare iSAM2 update; offline <= 1 s at 2000 keyframes.

    python scripts/bench_backend.py [--sizes 500 2000] [--profile]
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

import numpy as np

from bimgraph.backend.offline import run_offline
from bimgraph.backend.online import Backend
from bimgraph.backend.synthetic import make_scene
from bimgraph.config import BackendConfig
from bimgraph.viewer.follow import RerunListener
from bimgraph.viewer.rerun_viewer import RerunViewer, open_recording

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


def bench(n: int, cfg: BackendConfig) -> dict:
    scene = make_scene(n, rooms=(5, 4), seed=1)
    online_with_viewer_s(make_scene(20, rooms=(2, 2), seed=1), cfg)  # rerun's one-off start-up, not per run
    backend = Backend(scene.plane_map, cfg, scene.initial)
    start = time.perf_counter()
    results = [backend.process(kf) for kf in scene.keyframes]
    online = time.perf_counter() - start
    viewer = online_with_viewer_s(scene, cfg) / online
    latency = np.array([r.latency_s for r in results]) * 1e3
    isam2 = np.array([r.isam2_s for r in results]) * 1e3
    start = time.perf_counter()
    run_offline(scene.keyframes, scene.plane_map, cfg, scene.initial)
    offline = time.perf_counter() - start
    return {"keyframes": n, "observations": sum(len(kf.planes) for kf in scene.keyframes),
            "landmarks": len(backend.landmarks), "median": np.median(latency), "p95": np.percentile(latency, 95),
            "max": latency.max(), "isam2_median": np.median(isam2), "isam2_p95": np.percentile(isam2, 95),
            "ratio": np.median(latency) / np.median(isam2), "offline_s": offline, "viewer": viewer}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[500, 2000])
    parser.add_argument("--profile", action="store_true", help="profile the largest size and print the top entries")
    args = parser.parse_args()
    cfg = BackendConfig()
    if args.profile:
        import cProfile
        import pstats

        cProfile.runctx("bench(max(args.sizes), cfg)", globals(), {"args": args, "cfg": cfg}, "/tmp/bench_backend.prof")
        pstats.Stats("/tmp/bench_backend.prof").sort_stats("tottime").print_stats(30)
        return
    print("| keyframes | observations | landmarks | online median ms | p95 ms | max ms | bare iSAM2 median ms | p95 ms | median / iSAM2 | offline s | online with viewer |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for n in args.sizes:
        r = bench(n, cfg)
        print(f"| {r['keyframes']} | {r['observations']} | {r['landmarks']} | {r['median']:.2f} | {r['p95']:.2f} | {r['max']:.1f} "
              f"| {r['isam2_median']:.2f} | {r['isam2_p95']:.2f} | {r['ratio']:.1f}x | {r['offline_s']:.2f} | {r['viewer']:.2f}x |")


if __name__ == "__main__":
    main()
