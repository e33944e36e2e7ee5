"""Backend speed on the synthetic world of `bimgraph.backend.synthetic`, in one run.

For 500 and 2000 keyframes: online per-keyframe latency (median, p95, max, association
included), the iSAM2 updates alone within it (the same graph without association), and the
offline total. Goals: online median <= 2 ms and p95 <= 10 ms at 2000 keyframes, at most 3x the
bare iSAM2 update; offline <= 1 s at 2000 keyframes.

    python scripts/bench_backend.py [--sizes 500 2000] [--profile]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from bimgraph.backend.offline import run_offline
from bimgraph.backend.online import Backend
from bimgraph.backend.synthetic import make_scene
from bimgraph.config import BackendConfig


def bench(n: int, cfg: BackendConfig) -> dict:
    scene = make_scene(n, rooms=(5, 4), seed=1)
    backend = Backend(scene.plane_map, cfg, scene.initial)
    results = [backend.process(kf) for kf in scene.keyframes]
    latency = np.array([r.latency_s for r in results]) * 1e3
    isam2 = np.array([r.isam2_s for r in results]) * 1e3
    start = time.perf_counter()
    run_offline(scene.keyframes, scene.plane_map, cfg, scene.initial)
    offline = time.perf_counter() - start
    return {"keyframes": n, "observations": sum(len(kf.planes) for kf in scene.keyframes),
            "landmarks": len(backend.landmarks), "median": np.median(latency), "p95": np.percentile(latency, 95),
            "max": latency.max(), "isam2_median": np.median(isam2), "isam2_p95": np.percentile(isam2, 95),
            "ratio": np.median(latency) / np.median(isam2), "offline_s": offline}


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
    print("| keyframes | observations | landmarks | online median ms | p95 ms | max ms | bare iSAM2 median ms | p95 ms | median / iSAM2 | offline s |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for n in args.sizes:
        r = bench(n, cfg)
        print(f"| {r['keyframes']} | {r['observations']} | {r['landmarks']} | {r['median']:.2f} | {r['p95']:.2f} | {r['max']:.1f} "
              f"| {r['isam2_median']:.2f} | {r['isam2_p95']:.2f} | {r['ratio']:.1f}x | {r['offline_s']:.2f} |")


if __name__ == "__main__":
    main()
