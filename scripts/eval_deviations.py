"""Issue 8's acceptance, as far as the pieces allow: run the offline backend on a world with
as-built deviations, missing walls and clutter, report the deviations, and score them against
the ground truth; and compare extrinsic error and ATE with the same world without deviations.

    python scripts/eval_deviations.py --sequences SEQ... [--clean NODEVSEQ...] [--oracle] [--[no-]gnc]
    python scripts/eval_deviations.py --synthetic [--seeds 0 1 2] [--[no-]gnc] [-c CONFIG]

`--sequences` are simulator sequences (`bimgraph simulate`, with `groundtruth/as_built.json`).
Each is also run against its twin without deviations: the same observations, the plan moved to
where the walls were built (`twin_*`, and the `twin_*_ratio` columns): the comparison that the
deviations alone change, as the synthetic world's. `--clean` adds the same scenarios and seeds
simulated without deviations (`clean_*` and the other ratios): a comparison that the two runs'
independent sensor noise also changes (the simulator draws it anew where the world differs).
`--synthetic` uses the backend's synthetic rooms (`bimgraph.backend.synthetic`), with a share
of faces moved 5-10 cm and a share not built (their observations removed); there `clean_*` is
the world as planned and `nodev_*` the same missing walls without deviations, and the ratios
(extrinsic cm and deg, ATE) are against the latter. `--oracle` gives the backend the true
associations, to measure the deviation step apart from the association. `--gnc` / `--no-gnc` override
`backend.offline.gnc` (the robust alignment: graduated non-convexity judges which plane-to-BIM
factors the alignment keeps) in every run. `not_kept` counts the faces whose factor GNC did not
keep whole, `not_kept_true` those of them truly off plan beyond the tolerance.
"""

from __future__ import annotations

import argparse
import functools
import tempfile
import time
from collections import Counter
from pathlib import Path

import numpy as np

from bimgraph.backend.landmarks import KEPT
from bimgraph.backend.offline import OfflineEstimator
from bimgraph.backend.pipeline import depth_tilt, load_inputs
from bimgraph.backend.synthetic import make_scene
from bimgraph.bim.planemap import PlaneMap
from bimgraph.config import BackendConfig, Config, DeviationConfig, load_config
from bimgraph.deviations.outputs import write_deviation_outputs
from bimgraph.evaluation.jobs import run_all
from bimgraph.evaluation.metrics import ate, extrinsic_error
from bimgraph.evaluation.walls import WallTruth, face_scores
from bimgraph.sequence.format import Camera, load_sequence
from bimgraph.sequence.groundtruth import as_planned, load_groundtruth


def deviate_synthetic(scene, rng, deviating_fraction: float, missing_fraction: float):
    """Move a share of the plan's faces by 5-10 cm (so that the world as observed deviates from
    the plan by the opposite amount) and drop the observations of a share of faces."""
    faces = scene.plane_map.faces
    truth = {}
    planned = []
    order = rng.permutation(len(faces))
    n_dev = int(round(deviating_fraction * len(faces)))
    n_missing = int(round(missing_fraction * len(faces)))
    deviating = set(order[:n_dev].tolist())
    missing = set(order[n_dev:n_dev + n_missing].tolist())
    for i, f in enumerate(faces):
        offset = rng.uniform(0.05, 0.10) * rng.choice([-1.0, 1.0]) if i in deviating else 0.0
        planned.append(f.moved_to([*f.normal, f.offset + offset]))
        truth[f.id] = (offset, 0.0, i not in missing)
    missing_ids = {faces[i].id for i in missing}
    keyframes = []
    for kf in scene.keyframes:
        keep = [p for i, p in enumerate(kf.planes) if scene.truth.get((kf.index, i)) not in missing_ids]
        keyframes.append(kf.model_copy(update={"planes": keep}))
    return PlaneMap(faces=planned), keyframes, truth


def score(data, truth, cfg: DeviationConfig) -> dict:
    """`walls.face_scores` (detection, offsets, not built) and the contest's, widths' and
    thicknesses' scores. `truth[face] = (offset at centre, tilt deg, built)`; a face it lacks
    (of a storey the simulator did not walk) stands as built as planned."""
    n_faces = len(truth)
    truth = {f.face_id: WallTruth(0.0, 0.0, True) for f in data.faces} | {k: WallTruth(*v) for k, v in truth.items()}

    def gt_deviating(face_id):
        off, tilt, built = truth[face_id]
        return built and (abs(off) > cfg.tolerance_m or abs(tilt) > cfg.tilt_tolerance_deg)

    return {
        "faces": n_faces, "observed": sum(f.status != "possibly_not_built" for f in data.faces),
        **face_scores(data.faces, truth, cfg.tolerance_m, cfg.tilt_tolerance_deg),
        "unplanned": len(data.unplanned),
        **contest_score(data, gt_deviating),
        **distance_score(getattr(data, "widths", []), truth, cfg, -1.0, "width", "widths"),
        **distance_score(getattr(data, "thicknesses", []), truth, cfg, 1.0, "thickness", "thicknesses"),
    }


def distance_score(records, truth, cfg: DeviationConfig, sign: float, name: str, names: str) -> dict:
    """The report's room widths (`sign` -1) or wall thicknesses (+1) against the truth (the
    change from plan: both faces' true offsets at their centres, times `sign`; one on a wall not
    built is left out): how many, the RMS of their errors (m) and of the errors over their
    sigmas, those flagged deviating and how many truly are; keys `names`, `name`_err_rms_mm, ..."""
    rows = []
    for r in records:
        (off_a, _, built_a), (off_b, _, built_b) = (truth.get(face, (0.0, 0.0, True)) for face in r.faces)
        if built_a and built_b:
            rows.append((r.built_m - r.planned_m - sign * (off_a + off_b), r.sigma_m, r.status, abs(off_a + off_b) > cfg.tolerance_m))
    if not rows:
        return {names: 0}
    errors = np.array([r[0] for r in rows])
    z = errors / np.maximum([r[1] for r in rows], 1e-12)
    flagged = [r for r in rows if r[2] == "deviating"]
    return {names: len(rows), f"{name}_err_rms_mm": float(np.sqrt(np.mean(errors**2)) * 1e3),
            f"{name}_z_rms": float(np.sqrt(np.mean(z**2))), f"{names}_flagged": len(flagged),
            f"{names}_flagged_true": sum(r[3] for r in flagged)}


def contest_score(data, gt_deviating) -> dict:
    """The report's contest (`deviations.json`'s `contested`), if any: `contest` 1; `contest_true`,
    the rank (1: the likelier) of the explanation that names exactly the contested faces that
    truly deviate, 0 if neither does."""
    if not data.contested:
        return {"contest": 0, "contest_true": 0}
    contested = {f.face_id for e in data.contested for f in e.deviating}
    truly = {face for face in contested if gt_deviating(face)}
    rank = next((i + 1 for i, e in enumerate(data.contested) if {f.face_id for f in e.deviating} == truly), 0)
    return {"contest": 1, "contest_true": rank}


def evaluate(plane_map: PlaneMap, keyframes, initial, truth, T_B_C_true, T_B_S_true, camera, args,
             backend_cfg: BackendConfig, dev_cfg: DeviationConfig, out_dir: Path, oracle=None,
             kinds: dict | None = None, tilt=None) -> dict:
    """Run the offline backend with the deviation step and score it. `kinds` maps (keyframe,
    observation) to the true kind of surface observed (wall, clutter, ...), if known; `tilt` as
    `bimgraph run` models a depth sequence's (`pipeline.depth_tilt`)."""
    est = OfflineEstimator(plane_map, backend_cfg, initial, oracle=oracle, tilt=tilt)
    start = time.perf_counter()
    res = est.run(keyframes)
    t_backend = time.perf_counter() - start
    data = write_deviation_outputs(out_dir, plane_map, res.observed_planes, res.T_B_S, res.T_B_C, camera, dev_cfg,
                                   rival=res.rival_alignment)
    t_report = time.perf_counter() - start - t_backend
    out = score(data, truth, dev_cfg)
    if kinds is not None:
        # An unplanned plane is right if most of its observations are of no planned wall.
        landmarks = {lm.id: lm for lm in est.landmarks.items}
        out["unplanned_not_wall"] = sum(
            Counter(kinds[o] for o in landmarks[u.landmark].observations).most_common(1)[0][0] != "wall"
            for u in data.unplanned)
    rot, trans = extrinsic_error(res.T_B_S, T_B_S_true)
    not_kept = [pair for pair, verdict in est.judge.verdicts.items() if verdict != KEPT]
    sigma = np.sqrt(np.diag(res.cov_T_B_S))
    out.update(ext_deg=rot, ext_cm=trans, ext_sigma_deg=float(np.degrees(sigma[:3].max())), ext_sigma_cm=float(sigma[3:5].max() * 100),
               ate_m=ate(res.T_B_C, T_B_C_true), not_kept=len(not_kept),
               not_kept_true=sum(abs(truth[face][0]) > dev_cfg.tolerance_m for _, face in not_kept),
               backend_s=t_backend, marginals_s=res.timings["deviation_covariances_s"], report_s=t_report)
    return out


def run_clean(plane_map, keyframes, initial, T_B_C_true, T_B_S_true, backend_cfg, oracle=None, tilt=None) -> dict:
    res = OfflineEstimator(plane_map, backend_cfg, initial, oracle=oracle, tilt=tilt).run(keyframes)
    rot, trans = extrinsic_error(res.T_B_S, T_B_S_true)
    return {"ext_deg": rot, "ext_cm": trans, "ate_m": ate(res.T_B_C, T_B_C_true)}


def load_simulated(root: Path, cfg: Config):
    seq = load_sequence(root)
    gt = load_groundtruth(root)
    inputs = load_inputs(root, None, cfg)
    plane_map, initial = inputs.plane_map, inputs.initial
    truth = {}
    for rec in gt.as_built["faces"]:
        face = plane_map.faces[plane_map.index[rec["face_id"]]]
        plane = np.asarray(rec["plane_as_built"])
        truth[rec["face_id"]] = (float(-(plane[:3] @ np.asarray(face.centre) + plane[3])), abs(rec["tilt_deg"]), rec["built"])
    return seq, gt, plane_map, initial, truth


def plan_as_built(plane_map: PlaneMap, as_built: dict) -> PlaneMap:
    """The plan with every face built off plan replaced by the face as built (its plane and
    outline from the simulator's elements): the same scenario without deviations, seen through
    the very same observations (so the same sensor noise, clutter and missing walls), which an
    independently simulated clean world (`--clean`) is not."""
    elements = {e["face_id"]: e for e in as_built["elements"] if e["face_id"] is not None}
    moved = {rec["face_id"]: rec for rec in as_built["faces"] if rec["built"] and not as_planned(rec)}

    def built(face):
        element = elements[face.id]
        return face.moved_to(moved[face.id]["plane_as_built"], element["polygon"], element["holes"])

    faces = [built(f) if f.id in moved else f for f in plane_map.faces]
    return PlaneMap(**{**plane_map.model_dump(exclude={"faces"}), "faces": faces})


def ratios(run: dict, reference: dict, prefix: str = "") -> dict:
    """Issue 8's ratios of a run's extrinsic errors and ATE to those of a reference run."""
    names = {"ext_cm": "ext_cm_ratio", "ext_deg": "ext_deg_ratio", "ate_m": "ate_ratio"}
    return {prefix + name: run[k] / max(reference[k], 1e-9) for k, name in names.items()}


def oracle_of(gt) -> dict:
    """(keyframe, observation) -> true face id (None for clutter, floors, ceilings)."""
    return {(k, i): p["face_id"] for k, planes in enumerate(gt.observations) for i, p in enumerate(planes)}


def run_simulated(root: Path, clean_root: Path | None, args, cfg) -> dict:
    seq, gt, plane_map, initial, truth = load_simulated(root, cfg)
    tilt = depth_tilt(seq.meta, cfg)
    out = evaluate(plane_map, seq.keyframes, initial, truth, gt.T_B_C, gt.T_B_S, seq.meta.camera, args,
                   cfg.backend, cfg.deviations, out_dir=root / "deviations_eval", oracle=oracle_of(gt) if args.oracle else None,
                   kinds={(k, i): p["kind"] for k, planes in enumerate(gt.observations) for i, p in enumerate(planes)}, tilt=tilt)
    kinds = [p["kind"] for planes in gt.observations for p in planes]
    out["clutter_share"] = sum(k not in ("wall", "floor", "ceiling") for k in kinds) / max(len(kinds), 1)
    twin = run_clean(plan_as_built(plane_map, gt.as_built), seq.keyframes, initial, gt.T_B_C, gt.T_B_S, cfg.backend,
                     oracle_of(gt) if args.oracle else None, tilt)
    out.update({f"twin_{k}": v for k, v in twin.items()})
    out.update(ratios(out, twin, "twin_"))
    if clean_root is not None:
        seq_c, gt_c, plane_map_c, initial_c, _ = load_simulated(clean_root, cfg)
        clean = run_clean(plane_map_c, seq_c.keyframes, initial_c, gt_c.T_B_C, gt_c.T_B_S, cfg.backend,
                          oracle_of(gt_c) if args.oracle else None, depth_tilt(seq_c.meta, cfg))
        out.update({f"clean_{k}": v for k, v in clean.items()})
        out.update(ratios(out, clean))
    return out


def run_synthetic(seed: int, args, cfg) -> dict:
    scene = make_scene(args.keyframes, rooms=(3, 2), seed=seed, drift_rot_deg=0.05 * args.drift_scale,
                       drift_trans_m=0.003 * args.drift_scale)
    T_B_C_true = np.asarray(scene.T_B_C)
    clean = run_clean(scene.plane_map, scene.keyframes, scene.initial, T_B_C_true, scene.T_B_S, cfg.backend)
    rng = np.random.default_rng(1000 + seed)
    plane_map, keyframes, truth = deviate_synthetic(scene, rng, args.deviating, args.missing)
    camera = Camera(width=640, height=480, fx=525.0, fy=525.0, cx=319.5, cy=239.5)
    out = evaluate(plane_map, keyframes, scene.initial, truth, T_B_C_true, scene.T_B_S, camera, args, cfg.backend,
                   cfg.deviations, out_dir=Path(tempfile.mkdtemp(prefix="bimgraph_deviations_")))
    out.update({f"clean_{k}": v for k, v in clean.items()})
    # The same walls missing, none deviating: the plan as built, the same observations.
    missing_only = run_clean(scene.plane_map, keyframes, scene.initial, T_B_C_true, scene.T_B_S, cfg.backend)
    out.update({f"nodev_{k}": v for k, v in missing_only.items()})
    out.update(ratios(out, missing_only))
    return out


def print_table(names, rows):
    keys = list(rows[0])
    print("| run | " + " | ".join(keys) + " |")
    print("|---" * (len(keys) + 1) + "|")
    for name, r in zip(names, rows):
        print(f"| {name} | " + " | ".join(f"{r.get(k, float('nan')):.4g}" if isinstance(r.get(k), float) else str(r.get(k)) for k in keys) + " |")


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sequences", type=Path, nargs="*", default=[])
    parser.add_argument("--clean", type=Path, nargs="*", default=[])
    parser.add_argument("--synthetic", action="store_true")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--keyframes", type=int, default=600)
    parser.add_argument("--deviating", type=float, default=0.2)
    parser.add_argument("--missing", type=float, default=0.3)
    parser.add_argument("--drift-scale", type=float, default=1.0, help="scales the synthetic front-end's drift per keyframe")
    parser.add_argument("--gnc", action=argparse.BooleanOptionalAction, default=None,
                        help="override backend.offline.gnc")
    parser.add_argument("--oracle", action="store_true", help="give the backend the true associations (simulator only)")
    parser.add_argument("--config", "-c", type=Path, default=None)
    parser.add_argument("--jobs", type=int, default=1,
                        help="worlds evaluated at once, each in a process of its own (the timing columns then count a "
                             "machine they share)")
    args = parser.parse_args()
    cfg = load_config(args.config)
    if args.gnc is not None:
        cfg.backend.offline.gnc = args.gnc
    if args.synthetic:
        print_table(args.seeds, list(run_all(functools.partial(run_synthetic, args=args, cfg=cfg), args.seeds, args.jobs)))
    if args.sequences:
        cleans = args.clean or [None] * len(args.sequences)
        print_table([p.name for p in args.sequences],
                    list(run_all(functools.partial(_run_simulated, args=args, cfg=cfg), zip(args.sequences, cleans), args.jobs)))


def _run_simulated(pair: tuple[Path, Path | None], args, cfg) -> dict:
    return run_simulated(*pair, args, cfg)


if __name__ == "__main__":
    main()
