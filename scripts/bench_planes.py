"""Plane extraction benchmark: bimgraph's extractor against Open3D's `detect_planar_patches`.

Renders noisy depth frames of the test room (walls with a step and a kink, a cabinet) from
random viewpoints, at 640x480 and 320x240, and runs both methods on the same frames on one
thread. Open3D gets the frame as a point cloud, voxel-downsampled to 5 cm, with normals
estimated (its documented use); its time includes those steps, and is also given for the
detection call alone. Times are CPU time of the process (one thread), so that other load on
the machine does not inflate them.

Recall: share of visible wall sections (>= 0.5 m^2 within 5 m, showing a 60 px square) for
which some detected plane has its normal within 2 degrees and its offset within 5 cm (the
same geometric test for both methods); "strict" uses the acceptance bounds, 0.5 degrees and
1 cm. Normal error: median over the found walls of the best plane's normal angle.

    OMP_NUM_THREADS=1 .venv/bin/python scripts/bench_planes.py --frames 40
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))  # the test scenes are the benchmark's scenes

from depth_scenes import CAMERA, room, viewpoints  # noqa: E402

from bimgraph.config import DepthNoiseConfig, ExtractionConfig  # noqa: E402
from bimgraph.geometry import plane_to_frame  # noqa: E402
from bimgraph.planes.extractor import PlaneExtractor  # noqa: E402
from bimgraph.sim.render import DepthRenderer, add_depth_noise, pixel_rays  # noqa: E402

WALLS = {2, 3, 4, 5, 6, 7, 8}


def scaled_camera(width: int):
    s = width / CAMERA.width
    return CAMERA.model_copy(update=dict(width=width, height=round(CAMERA.height * s), fx=CAMERA.fx * s,
                                         fy=CAMERA.fy * s, cx=(CAMERA.cx + 0.5) * s - 0.5, cy=(CAMERA.cy + 0.5) * s - 0.5))


def visible_walls(depth, ids, camera, planes_C):
    block = max(3, round(60 * camera.width / 640))
    out = []
    for f in WALLS & set(np.unique(ids)):
        px = (ids == f) & (depth > 0) & (depth <= 5.0)
        area = (depth[px] ** 3).sum() / (camera.fx * camera.fy * planes_C[f][3])
        square = cv2.erode(px.astype(np.uint8), np.ones((block, block), np.uint8), borderType=cv2.BORDER_CONSTANT, borderValue=0)
        if area >= 0.5 and square.any():
            out.append(f)
    return out


def open3d_planes(depth, camera, o3d):
    """Open3D's pipeline on one frame: points, 5 cm voxels, normals, planar patches."""
    t0 = time.process_time()
    points = (pixel_rays(camera) * depth[..., None])[depth > 0]
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    cloud = cloud.voxel_down_sample(0.05)
    cloud.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=0.15, max_nn=30))
    t1 = time.process_time()
    boxes = cloud.detect_planar_patches(normal_variance_threshold_deg=60, coplanarity_deg=75, outlier_ratio=0.75,
                                        min_plane_edge_length=0, min_num_points=0,
                                        search_param=o3d.geometry.KDTreeSearchParamKNN(knn=30))
    t2 = time.process_time()
    planes = []
    for box in boxes:
        n = np.asarray(box.R)[:, int(np.argmin(box.extent))]
        d = -n @ np.asarray(box.center)
        planes.append(np.r_[n, d] if d > 0 else -np.r_[n, d])
    return planes, t2 - t0, t2 - t1


def score(planes, walls, planes_C, loose=(2.0, 0.05), strict=(0.5, 0.01)):
    found = strict_found = 0
    errors = []
    for f in walls:
        truth = planes_C[f]
        cands = [(np.degrees(np.arccos(np.clip(p[:3] @ truth[:3], -1, 1))), abs(p[3] - truth[3])) for p in planes]
        ok = [c for c in cands if c[0] <= loose[0] and c[1] <= loose[1]]
        if ok:
            found += 1
            errors.append(min(ok)[0])
        strict_found += any(c[0] <= strict[0] and c[1] <= strict[1] for c in cands)
    return found, strict_found, errors


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=40)
    parser.add_argument("--seed", type=int, default=5)
    args = parser.parse_args()

    import open3d as o3d

    cv2.setNumThreads(1)
    o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)
    scene = room()
    renderer = DepthRenderer(*scene.arrays())
    noise = DepthNoiseConfig()
    poses = viewpoints(np.random.default_rng(args.seed), args.frames)
    rows = []
    for width in (640, 320):
        camera = scaled_camera(width)
        cfg = ExtractionConfig(cell_size_px=20 if width == 640 else 16)  # cells of 400 and 256 pixels
        extractor = PlaneExtractor(camera, cfg, noise)
        rng = np.random.default_rng(args.seed)
        stats = {"ours": [[], [], 0, 0, []], "open3d": [[], [], 0, 0, []]}
        n_walls = 0
        for T_B_C in poses:
            depth, ids, cos_inc = renderer.render(camera, T_B_C, with_incidence=True)
            noisy = add_depth_noise(depth, noise, rng, cos_inc)
            planes_C = {f: plane_to_frame(p, T_B_C) for f, p in scene.planes_B.items()}
            walls = visible_walls(depth, ids, camera, planes_C)
            n_walls += len(walls)
            t0 = time.process_time()
            ours = [p.plane for p in extractor.extract(noisy).planes]
            t_ours = time.process_time() - t0
            theirs, t_o3d, t_detect = open3d_planes(noisy, camera, o3d)
            for name, planes, t, t_only in [("ours", ours, t_ours, t_ours), ("open3d", theirs, t_o3d, t_detect)]:
                s = stats[name]
                found, strict, errors = score(planes, walls, planes_C)
                s[0].append(t * 1e3)
                s[1].append(t_only * 1e3)
                s[2] += found
                s[3] += strict
                s[4] += errors
        for name, (t, t_only, found, strict, errors) in stats.items():
            rows.append((f"{camera.width}x{camera.height}", name, np.median(t), np.percentile(t, 95), np.median(t_only),
                         found / max(n_walls, 1), strict / max(n_walls, 1), np.median(errors) if errors else float("nan"), n_walls))
    print(f"{args.frames} frames per size, CPU ms on one thread; recall over visible wall sections\n")
    print("| frame | method | median ms | p95 ms | detection-only median ms | recall (2 deg, 5 cm) | recall (0.5 deg, 1 cm) | median normal error deg | walls |")
    print("|---|---|---|---|---|---|---|---|---|")
    for size, name, med, p95, only, rec, rec_strict, err, walls in rows:
        print(f"| {size} | {name} | {med:.1f} | {p95:.1f} | {only:.1f} | {rec:.1%} | {rec_strict:.1%} | {err:.3f} | {walls} |")
    by = {(r[0], r[1]): r for r in rows}
    for size in dict.fromkeys(r[0] for r in rows):
        print(f"\n{size}: ours is {by[(size, 'open3d')][2] / by[(size, 'ours')][2]:.1f}x faster than Open3D (median, whole pipeline)", end="")
    print()


if __name__ == "__main__":
    main()
