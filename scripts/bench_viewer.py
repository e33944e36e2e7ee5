"""What Rerun logging costs an online run.

Runs the online backend over a sequence twice, without a viewer and with `RerunViewer`
saving to an .rrd, and prints both times and their ratio (goal: at most 1.20). With no
sequence given, simulates one (`bimgraph simulate`, planes mode) in a temporary folder.

    python scripts/bench_viewer.py                       # 500 simulated keyframes, office
    python scripts/bench_viewer.py --keyframes 2000 --scenario site
    python scripts/bench_viewer.py --sequence SEQDIR     # an existing sequence

`measure(sequence_root, plane_map, rrd)` is the same measurement as a function, for the
backend benchmark to call.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("RERUN_ANALYTICS", "0")
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bimgraph.backend.online import Backend  # noqa: E402
from bimgraph.backend.pipeline import initial_alignment, load_inputs  # noqa: E402
from bimgraph.bim.planemap import PlaneMap  # noqa: E402
from bimgraph.config import Config, load_config  # noqa: E402
from bimgraph.sequence.format import Sequence, load_sequence  # noqa: E402
from bimgraph.viewer.follow import RerunListener  # noqa: E402
from bimgraph.viewer.recording import open_recording  # noqa: E402
from bimgraph.viewer.rerun_viewer import RerunViewer  # noqa: E402
from bimgraph.viewer.rrd import component_counts, verify  # noqa: E402


class _TimedListener(RerunListener):
    """Adds up the wall and CPU time the main thread spends in the viewer's hooks."""

    wall = cpu = 0.0

    def on_keyframe(self, result):
        wall, cpu = time.perf_counter(), time.thread_time()
        super().on_keyframe(result)
        self.wall += time.perf_counter() - wall
        self.cpu += time.thread_time() - cpu


def _run(seq: Sequence, plane_map: PlaneMap, cfg: Config, rrd: Path | None) -> dict:
    """One online run over every keyframe: wall time, CPU time of the whole process
    (including rerun's background threads) and of the main thread; with `rrd`, also the
    wall and main-thread CPU time spent in the viewer itself (its set-up, every hook, the
    final flush to disk), set-up apart."""
    initial = initial_alignment(seq.meta, cfg)
    wall, cpu, thread = time.perf_counter(), time.process_time(), time.thread_time()
    inside = {"viewer_wall_s": 0.0, "viewer_cpu_s": 0.0, "setup_wall_s": 0.0}
    if rrd is None:
        backend = Backend(plane_map, cfg.backend, initial)
        for kf in seq.keyframes:
            backend.process(kf)
    else:
        viewer = RerunViewer(open_recording(rrd), plane_map, initial.T_B_S, camera=seq.meta.camera, config=cfg.viewer)
        listener = _TimedListener(viewer, seq.root)
        setup_wall, setup_cpu = time.perf_counter() - wall, time.thread_time() - thread
        backend = Backend(plane_map, cfg.backend, initial, listener=listener)
        for kf in seq.keyframes:
            backend.process(kf)
        close_wall, close_cpu = time.perf_counter(), time.thread_time()
        viewer.close()
        inside = {"viewer_wall_s": setup_wall + listener.wall + time.perf_counter() - close_wall,
                  "viewer_cpu_s": setup_cpu + listener.cpu + time.thread_time() - close_cpu,
                  "setup_wall_s": setup_wall}
    return {"wall_s": time.perf_counter() - wall, "cpu_s": time.process_time() - cpu,
            "thread_cpu_s": time.thread_time() - thread, **inside}


def measure(seq: Sequence, plane_map: PlaneMap, rrd: Path, cfg: Config | None = None, repeats: int = 1) -> dict:
    """Online runs without and with the viewer, alternated, best of `repeats` each. The
    overhead is given three ways: wall time ratio, process CPU time ratio (rerun's threads
    included), and the main thread's CPU time inside the viewer over the rest of the run
    (the least sensitive to other load on the machine)."""
    cfg = cfg or Config()
    bare, logged = [], []
    for _ in range(repeats):
        bare.append(_run(seq, plane_map, cfg, None))
        logged.append(_run(seq, plane_map, cfg, rrd))
    best_bare = min(bare, key=lambda r: r["wall_s"])
    best = min(logged, key=lambda r: r["viewer_cpu_s"])
    return {"keyframes": len(seq.keyframes), "bare": best_bare, "viewer": best,
            "wall_ratio": min(r["wall_s"] for r in logged) / best_bare["wall_s"],
            "cpu_ratio": min(r["cpu_s"] for r in logged) / min(r["cpu_s"] for r in bare),
            "inside_ratio": 1.0 + best["viewer_cpu_s"] / (best["thread_cpu_s"] - best["viewer_cpu_s"])}


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sequence", type=Path, help="an existing sequence folder (default: simulate one)")
    parser.add_argument("--keyframes", type=int, default=500)
    parser.add_argument("--scenario", default="office")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--repeats", type=int, default=2, help="best of this many runs each")
    parser.add_argument("--config", type=Path)
    args = parser.parse_args()
    cfg = load_config(args.config)

    with tempfile.TemporaryDirectory() as tmp:
        root = args.sequence
        if root is None:
            from bimgraph.sim.simulate import SimOptions, simulate

            root = Path(tmp) / "seq"
            opts = SimOptions(output=root, scenario=args.scenario, ifc=None, sensor="planes",
                              keyframes=args.keyframes, seed=args.seed)
            opts.check()
            simulate(opts, cfg)
        seq = load_sequence(root)
        plane_map = load_inputs(root, None, cfg).plane_map
        rrd = Path(tmp) / "bench.rrd"
        r = measure(seq, plane_map, rrd, cfg, args.repeats)
        verify(rrd)
        counts = component_counts(rrd)
        print(f"{r['keyframes']} keyframes, {len(plane_map.faces)} faces, {len(counts)} entities, "
              f"{rrd.stat().st_size / 1e6:.1f} MB recording")
        n, bare, logged = r["keyframes"], r["bare"], r["viewer"]
        print(f"online without viewer: {bare['wall_s']:.3f} s wall ({1e3 * bare['wall_s'] / n:.2f} ms/keyframe), "
              f"{bare['cpu_s']:.3f} s CPU")
        print(f"online with viewer:    {logged['wall_s']:.3f} s wall ({1e3 * logged['wall_s'] / n:.2f} ms/keyframe), "
              f"{logged['cpu_s']:.3f} s CPU; inside the viewer {logged['viewer_cpu_s']:.3f} s main-thread CPU "
              f"({1e3 * logged['viewer_cpu_s'] / n:.3f} ms/keyframe), {logged['viewer_wall_s']:.3f} s wall "
              f"of which set-up {logged['setup_wall_s']:.3f} s")
        print(f"ratio with/without viewer (goal <= 1.20): wall {r['wall_ratio']:.3f}, process CPU {r['cpu_ratio']:.3f}, "
              f"main-thread CPU {r['inside_ratio']:.3f}")

if __name__ == "__main__":
    main()
