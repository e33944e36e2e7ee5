"""Evaluation from files: a run's output folder and a sequence with its reference in,
`metrics.json` and a table out. The I/O side of `evaluate` and `baselines`; and what a run's folder says
without ground truth (`run_summary`, printed by `bimgraph run`)."""

from __future__ import annotations

import filecmp
from collections import Counter
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from bimgraph.backend.pipeline import initial_alignment, load_model, model_path, run_model
from bimgraph.backend.results import (ASSOCIATIONS, EXTRINSIC, METRICS, SUMMARY, TRAJECTORY_BIM, check_stamps,
                                      load_associations, load_extrinsic, load_summary, run_trajectory)
from bimgraph.config import Config
from bimgraph.deviations.report import FACE_STATUSES, WIDTH_STATUSES, run_report
from bimgraph.errors import FormatError, InputError
from bimgraph.evaluation.baselines import estimate_extrinsics, matched_planes
from bimgraph.evaluation.evaluate import Estimate, Truth, evaluate, wall_matches
from bimgraph.evaluation.metrics import T_MAX_DIFF_S, nearest_stamps
from bimgraph.files import write_json
from bimgraph.geometry import pose_from_tum, sigmas_in_B
from bimgraph.sequence.format import KEYFRAMES_FILE, Sequence, load_sequence
from bimgraph.sequence.groundtruth import load_reference


def load_estimate(out_dir: Path) -> Estimate:
    """A bimgraph run's outputs as an Estimate."""
    out_dir = Path(out_dir)
    if not out_dir.is_dir():
        raise InputError(f"{out_dir}: " + ("a file, not an output folder" if out_dir.exists() else "no such output folder"))
    stamps, T_B_C = run_trajectory(out_dir, TRAJECTORY_BIM)
    if len(T_B_C) == 0:
        raise InputError(f"{out_dir}: the run has no keyframe to evaluate (it stopped at its first)")
    # (a finished run's files agree; a trajectory cut or copied from another run measured an
    # association precision of 0.34 against the wrong keyframes)
    if (out_dir / SUMMARY).is_file() and (summary := load_summary(out_dir / SUMMARY)).finished \
            and summary.keyframes != len(T_B_C):
        raise InputError(f"{out_dir}: {TRAJECTORY_BIM} holds {len(T_B_C)} poses, but {SUMMARY} says the run finished "
                         f"after {summary.keyframes} keyframes: the folder's files are not of one run")
    extrinsic = load_extrinsic(out_dir / EXTRINSIC)
    associations = load_associations(out_dir / ASSOCIATIONS).face_of_observation()
    return Estimate(list(T_B_C), pose_from_tum(extrinsic.T_B_S), associations, np.asarray(extrinsic.covariance), stamps)


def check_runs_of(out_dirs, seq_dir: Path) -> None:
    """InputError for a run whose summary names another sequence than `seq_dir` whose
    keyframes differ from its own: measured against the wrong ground truth, a run's figures
    came out plausible and wrong (another office walk's: association 0.91 / 0.87 for 1.00 /
    0.98). A copy of the sequence, or one that is no longer where the run found it, passes."""
    keyframes = Path(seq_dir) / KEYFRAMES_FILE
    for out_dir in out_dirs:
        summary_path = Path(out_dir) / SUMMARY
        named = load_summary(summary_path).sequence if summary_path.is_file() else None
        if named is None or not (Path(named) / KEYFRAMES_FILE).is_file() or Path(named).resolve() == Path(seq_dir).resolve():
            continue
        if keyframes.is_file() and not filecmp.cmp(Path(named) / KEYFRAMES_FILE, keyframes, shallow=False):
            raise InputError(f"{out_dir}: the run was made on {named}, whose keyframes differ from {seq_dir}'s; "
                             "measure it against its own sequence")


def model_of_runs(out_dirs, seq_dir: Path) -> Path | None:
    """The BIM model the runs of the sequence at `seq_dir` used (`pipeline.run_model`); None
    if they name none. Runs on different models are refused: their associations name faces
    of different maps."""
    used = {m for d in out_dirs if (m := run_model(d, seq_dir)) is not None}
    if len(used) > 1:
        raise InputError(f"the runs used different BIM models ({', '.join(sorted(map(str, used)))}); "
                         "give the one to measure against with --bim")
    return next(iter(used), None)


class Evaluation:
    """A sequence and its reference loaded once, against which any number of methods are
    measured."""

    def __init__(self, seq_dir: Path, cfg: Config, model: Path | None = None,
                 associations: Mapping[tuple[int, int], str] | None = None, t_max_diff_s: float = T_MAX_DIFF_S):
        """`model`: the BIM model the runs used (default: the one the sequence names).
        `associations`: where the reference names no face behind the planes, the matches the
        wall errors average over (a run's). `t_max_diff_s`: how far from a keyframe's stamp
        a reference pose may be (evo's `--t_max_diff`)."""
        self.cfg = cfg
        self.sequence: Sequence = load_sequence(seq_dir)
        keyframes = self.sequence.keyframes
        reference = load_reference(seq_dir)
        rows = nearest_stamps(np.array([kf.stamp for kf in keyframes]), reference.stamps, t_max_diff_s)
        if (rows < 0).all():
            raise InputError(f"{seq_dir}: no pose of groundtruth/T_B_C.tum within {t_max_diff_s:g} s of a keyframe's stamp "
                             f"(its stamps {_span(reference.stamps)}, the keyframes' {_span([kf.stamp for kf in keyframes])})")
        faces = None
        if reference.observations is not None:
            if len(reference.observations) != len(keyframes):
                raise FormatError(f"{seq_dir}: groundtruth/observations.jsonl has {len(reference.observations)} keyframes, "
                                  f"keyframes.jsonl {len(keyframes)}")
            for kf, truths in zip(keyframes, reference.observations):
                if len(truths) != len(kf.planes):  # (the association's precision and recall would count the wrong planes)
                    raise FormatError(f"{seq_dir}: groundtruth/observations.jsonl has {len(truths)} planes for keyframe {kf.index}, "
                                      f"keyframes.jsonl {len(kf.planes)}")
            faces = {(kf.index, i): obs.get("face_id") for kf, planes in zip(keyframes, reference.observations)
                     for i, obs in enumerate(planes)}
        self.plane_map = load_model(model or model_path(seq_dir, self.sequence.meta, None), cfg)
        self.truth = Truth({kf.index: reference.T_B_C[r] for kf, r in zip(keyframes, rows) if r >= 0}, reference.T_B_S, faces,
                           wall_matches(keyframes, faces if faces is not None else associations or {}, self.plane_map))
        self.manual = initial_alignment(self.sequence.meta, cfg)
        # every (keyframe, plane) the sequence has, which an association may name
        self._observed = {(kf.index, i) for kf in keyframes for i in range(len(kf.planes))}

    def metrics(self, estimate: Estimate, name: str = "the run") -> dict:
        """Every metric of `estimate`; one of an online run that stopped early (its stamps
        those of the sequence's first keyframes) over the keyframes it reached."""
        keyframes = self.sequence.keyframes
        n = len(estimate.T_B_C)
        if n > len(keyframes) or (n < len(keyframes) and estimate.stamps is None):
            raise FormatError(f"{name} has {n} poses for {len(keyframes)} keyframes")
        if estimate.stamps is not None:
            check_stamps(name, estimate.stamps, keyframes, self.sequence.root)
        for (k, i), face in (estimate.associations or {}).items():
            if (k, i) not in self._observed:
                raise FormatError(f"{name}: associations name plane {i} of keyframe {k}, which {self.sequence.root} does not have")
            if face is not None and face not in self.plane_map.index:
                raise FormatError(f"{name}: associations name face {face!r}, which the plane map does not have")
        return evaluate(estimate, keyframes[:n], self.truth)

    def truth_metrics(self) -> dict:
        """The reference measured as if it were a method, over the keyframes it has a pose
        for: its wall errors are the floor that the detections' noise and the as-built
        deviations leave to every method."""
        keyframes = [kf for kf in self.sequence.keyframes if kf.index in self.truth.T_B_C]
        return evaluate(Estimate([self.truth.T_B_C[kf.index] for kf in keyframes], self.truth.T_B_S), keyframes, self.truth)

    def baseline(self, method: str, associations) -> Estimate:
        """The paper's `method` on this sequence, with the given associations."""
        keyframes = self.sequence.keyframes
        matches = matched_planes(keyframes, associations, self.plane_map)
        T_B_S = estimate_extrinsics(method, keyframes, matches, self.manual, self.cfg.backend, self.cfg.baselines)
        T_B_C = [T @ kf.pose for T, kf in zip(T_B_S, keyframes)]
        return Estimate(T_B_C, T_B_S[-1], associations)


def wall_scores(out_dir: Path, walls: dict) -> tuple[dict | None, str]:
    """A finished run's deviation report scored against walls measured on site
    (`walls.face_scores`), and a line saying it; (None, why) where the run has no report."""
    from bimgraph.evaluation.walls import face_scores

    report = run_report(out_dir, load_summary(Path(out_dir) / SUMMARY).finished) if (Path(out_dir) / SUMMARY).is_file() else None
    if report is None:
        return None, "no deviation report (the run wrote none, or did not finish)"
    scores = face_scores(report.faces, walls, report.tolerance_m, report.tilt_tolerance_deg)
    within = f"{scores['offset_within_1cm']:.0%}" if scores["enough"] else "-"
    return scores, (f"{len(walls)} given, {scores['enough']} measured in the report: {scores['flagged']} flagged deviating "
                    f"(precision {scores['precision']:.2f}, recall {scores['recall']:.2f} at the report's "
                    f"{100 * report.tolerance_m:g} cm), offsets within 1 cm {within}, 95th percentile of their errors "
                    f"{scores['offset_err_p95_mm']:.1f} mm; possibly not built {scores['not_built_flagged']}, "
                    f"{scores['not_built_true']} given as not built")


def _span(stamps) -> str:
    return f"{min(stamps):.3f}-{max(stamps):.3f} s" if len(stamps) else "none"


def run_timings(out_dir: Path) -> dict:
    """The run's total seconds and median per-keyframe latency, from its summary.json."""
    summary = load_summary(Path(out_dir) / SUMMARY)
    out = {"run_s": summary.timings_s.get("total_s")}
    if summary.latency_ms is not None:
        out["latency_median_ms"] = summary.latency_ms.median
    return out


def run_summary(out_dir: Path) -> list[tuple[str, str]]:
    """What a run's files say, in a few labelled lines for the terminal (no ground truth
    needed): keyframes, landmarks and matches, `T_B_S` with its sigmas and unobservable
    directions, the front-end's drift, the walls' verdicts, time."""
    out_dir = Path(out_dir)
    summary = load_summary(out_dir / SUMMARY)
    extrinsic = load_extrinsic(out_dir / EXTRINSIC)
    T_B_S = pose_from_tum(extrinsic.T_B_S)
    yaw = np.degrees(np.arctan2(T_B_S[1, 0], T_B_S[0, 0]))
    sigma_rot_rad, sigma_trans_m = sigmas_in_B(T_B_S, extrinsic.covariance)
    sigma_cm = ", ".join("?" if np.isnan(s) else f"{100 * s:.1f}" for s in sigma_trans_m)
    sigma_deg = ", ".join("?" if np.isnan(s) else f"{np.degrees(s):.2f}" for s in sigma_rot_rad)
    unobservable = "; ".join(f"{u.kind} along {np.round(u.axis_B, 3).tolist()} (held at the initial alignment)"
                             for u in extrinsic.unobservable) or "none"
    rows = [("mode", summary.mode + ("" if summary.finished else " (stopped early: outputs up to the last keyframe written)")),
            ("keyframes", str(summary.keyframes)),
            ("landmarks", f"{summary.landmarks}, {summary.matched_landmarks} matched to {summary.matched_faces} BIM faces"
                          + ("" if summary.matched_landmarks or not summary.keyframes else
                             " (is the initial alignment, sequence.json's or the --seed pairs', within its sigmas?)")),
            ("T_B_S", f"position {np.round(T_B_S[:3, 3], 3).tolist()} m, heading {yaw:.2f} deg"),
            ("T_B_S sigma", f"position {sigma_cm} cm, rotation {sigma_deg} deg (along B's x, y, z)"),
            ("unobservable", unobservable)]
    if drift := summary.frontend_drift:
        rows.append(("front-end drift", f"correction {drift.rotation_deg_per_m[2]:+.3f} deg/m about z, "
                                        f"{np.linalg.norm(drift.translation_percent):.2f} % of the distance"
                                        + (f", each step's length {drift.scale_percent:+.2f} %" if drift.scale_percent else "")))
    if (tilt := summary.depth_tilt_sigma_per_m) is not None:
        rows.append(("depth tilt", f"a variable per keyframe, prior sigma {1000 * tilt:g} mm per m^2 of depth at the image's border"))
    if challenge := summary.alignment_challenge:
        taken = "the complement of the first consensus, ahead" if challenge.complement_taken else "consensus ahead of its complement"
        rival = "" if challenge.rival_probability is None else f", {100 * challenge.rival_probability:.2g} % likely"
        rows.append(("alignment", f"{taken} by {challenge.margin:.1f} ({len(challenge.contested_faces)} faces "
                                  f"judged otherwise there{rival})"))
    if (deviations := run_report(out_dir, summary.finished)) is not None:
        counts = deviations.counts()
        rows.append(("walls", ", ".join(f"{counts.get(k, 0)} {k.replace('_', ' ')}" for k in FACE_STATUSES)
                     + f"; {counts['unplanned']} unplanned planes (below, ± is one sigma)"))
        rows += [("deviating", f"{f.wall_name or f.wall_guid} ({f.face_id}): offset {100 * f.offset_m:+.1f} ± "
                               f"{100 * f.offset_sigma_m:.1f} cm, tilt {f.tilt_deg:.2f} ± {f.tilt_sigma_deg:.2f} deg")
                 for f in deviations.faces if f.status == "deviating"]
        rows += _distance_rows("room widths", "width", deviations.widths, lambda w: (
            f"{w.space_name or w.space_guid} between {w.faces[0]} and {w.faces[1]}: {w.built_m:.3f} ± {w.sigma_m:.3f} m built, "
            f"{w.planned_m:.3f} m planned ({100 * (w.built_m - w.planned_m):+.1f} cm)"))
        rows += _distance_rows("wall thicknesses", "thickness", deviations.thicknesses, lambda t: (
            f"{t.wall_name or t.wall_guid} between {t.faces[0]} and {t.faces[1]}: {100 * t.built_m:.1f} ± {100 * t.sigma_m:.1f} cm "
            f"built, {100 * t.planned_m:.1f} cm planned ({100 * (t.built_m - t.planned_m):+.1f} cm)"))
        for lead, explanation in zip(("either", "or"), deviations.contested):
            faces = "; ".join(f"{f.wall_name or f.wall_guid} ({f.face_id}) offset {100 * f.offset_m:+.1f} ± "
                              f"{100 * f.offset_sigma_m:.1f} cm" for f in explanation.deviating) or "no wall off beyond tolerance"
            rows.append(("contested", f"{lead} {faces}, {100 * explanation.probability:.2g} % likely (which, the data barely tell)"))
    seconds = summary.timings_s.get("total_s")
    if summary.latency_ms is not None:
        latency = summary.latency_ms
        rows.append(("time", f"{seconds:.1f} s, per keyframe median {latency.median:.1f} ms, p95 {latency.p95:.1f} ms"))
    elif seconds is not None:
        rows.append(("time", f"{seconds:.1f} s in {summary.rounds or 1} rounds"))
    return rows


def _distance_rows(title: str, label: str, records, describe) -> list[tuple[str, str]]:
    """The report's room widths or wall thicknesses: a row of counts by status, and a row for
    each off plan (`describe`d)."""
    if not records:
        return []
    counts = Counter(r.status for r in records)
    return ([(title, ", ".join(f"{counts.get(k, 0)} {k.replace('_', ' ')}" for k in WIDTH_STATUSES))]
            + [(label, describe(r)) for r in records if r.status == "deviating"])


def write_metrics(out_dir: Path, metrics: dict) -> None:
    write_json(Path(out_dir) / METRICS, metrics)


def summary_row(name: str, metrics: dict) -> dict:
    """The aggregates of a metrics record, without the per-keyframe series."""
    return {"method": name, **{k: v for k, v in metrics.items() if k != "per_keyframe" and np.isscalar(v)}}
