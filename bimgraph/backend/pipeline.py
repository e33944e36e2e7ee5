"""A run from files to files: load the sequence and the BIM model, estimate, write the outputs.
The only part of the backend that touches the disk (with `results`)."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bimgraph.backend.alignment import Alignment, align_from_seeds, seeded_start
from bimgraph.backend.depth_tilt import DepthTilt
from bimgraph.backend.fit import unfitting_model
from bimgraph.backend.graph import BatchSolver, singular_as_error
from bimgraph.backend.offline import OfflineEstimator, run_offline
from bimgraph.backend.online import Backend
from bimgraph.backend.records import Listener, Results
from bimgraph.backend.results import (ASSOCIATIONS, EXTRINSIC, LANDMARKS, METRICS, SUMMARY, TRAJECTORY_BIM,
                                      TRAJECTORY_SLAM, OnlineWriter, load_summary, write_results, write_summary)
from bimgraph.bim.planemap import PlaneMap, load_plane_map
from bimgraph.config import Config
from bimgraph.deviations.estimate import RivalAlignment
from bimgraph.deviations.graph import observed_planes_isam2
from bimgraph.deviations.outputs import DEVIATION_FILES, write_deviation_outputs
from bimgraph.errors import BimgraphError, ConfigError, InputError
from bimgraph.files import ensure_folder
from bimgraph.geometry import inverse, normalise_plane, plane_from_frame, pose_from_tum
from bimgraph.sequence.checks import sequence_warnings
from bimgraph.sequence.format import Keyframe, SequenceMeta, load_meta, load_sequence


def load_model(path: Path, cfg: Config, progress=None) -> PlaneMap:
    """A BIM model: an IFC file goes through the importer (`progress` as `import_ifc`'s), a
    JSON file is a plane map."""
    path = Path(path)
    if path.suffix.lower() == ".ifc":
        from bimgraph.bim.ifc_import import import_ifc

        return import_ifc(path, cfg.bim, progress=progress)[0]
    if path.suffix.lower() == ".json":
        return load_plane_map(path)
    raise InputError(f"{path}: not a BIM model (expected .ifc or a .json plane map)")


def model_path(root: Path, meta: SequenceMeta, bim: Path | None) -> Path:
    if bim is not None:
        return Path(bim)
    if meta.model is None:
        raise InputError(f"{root}: sequence.json names no model; give one with --bim")
    p = Path(meta.model)
    return p if p.is_absolute() else Path(root) / p


def run_model(out_dir: Path, seq_dir: Path | None = None) -> Path | None:
    """The BIM model a finished run used (its summary.json names it), to read its outputs
    against: a run given `--bim planes.json` names faces that the sequence's own model may
    not have, and re-importing that IFC can take long. None if the run names none. A run
    moved with its sequence (to `seq_dir`) finds a model inside the sequence there."""
    summary_path = Path(out_dir) / SUMMARY
    summary = load_summary(summary_path) if summary_path.is_file() else None
    if summary is None or summary.model is None:
        return None
    named = Path(summary.model)
    if named.is_file():
        return named
    if seq_dir is not None and summary.sequence is not None and named.is_relative_to(summary.sequence):
        moved = Path(seq_dir) / named.relative_to(summary.sequence)
        if moved.is_file():
            return moved
    raise InputError(f"{out_dir}: the run's BIM model {named} is not there; give it with --bim")


def depth_tilt(meta: SequenceMeta, cfg: Config) -> DepthTilt | None:
    """The depth sensor's tilt model for a sequence whose planes were extracted from its own
    depth images (`sensor: depth`), unless the configuration leaves it out."""
    if not cfg.backend.noise.depth_tilt or meta.sensor != "depth" or meta.camera is None or cfg.depth_noise.tilt_sigma_per_m == 0:
        return None
    return DepthTilt(meta.camera, cfg.depth_noise.tilt_sigma_per_m)


def initial_alignment(meta: SequenceMeta, cfg: Config) -> Alignment:
    """The sequence's manual alignment; if none, identity with the configured uncertainty
    (`backend.noise.extrinsic_*`: 2 degrees and 20 cm, so only a front-end whose S nearly is B
    gets its walls matched; `run` warns)."""
    noise = cfg.backend.noise
    if meta.initial_alignment is None:
        alignment = Alignment.from_sigmas(np.eye(4), noise.extrinsic_rot_deg, noise.extrinsic_trans_m)
    else:
        ia = meta.initial_alignment
        alignment = Alignment.from_sigmas(pose_from_tum(ia.T_B_S), ia.sigma_rot_deg, ia.sigma_trans_m)
    alignment.gravity_aligned = meta.gravity_aligned
    return alignment


def parse_seed(text: str) -> tuple[int, int, str]:
    """`KEYFRAME:PLANE:FACE_ID` (a face id may itself contain colons)."""
    parts = text.split(":", 2)
    try:
        return int(parts[0]), int(parts[1]), parts[2]
    except (ValueError, IndexError):
        raise ConfigError(f"seed {text!r}: expected KEYFRAME:PLANE:FACE_ID") from None


def seed_alignment(keyframes: list[Keyframe], plane_map: PlaneMap, seeds: list[tuple[int, int, str]],
                   cfg: Config, prior: Alignment, prior_given: bool = False) -> Alignment:
    """The start of a graph whose seed pairs (keyframe, plane index, BIM face id) are matched
    from the outset: `T_B_S` by plane registration of the pairs (`seeded_start`); with
    `prior_given` (the user's alignment, not the default), one that turns far from it is refused."""
    by_index = {kf.index: kf for kf in keyframes}
    planes_S, planes_B, centres_B, seen = [], [], [], []
    for k, i, face in seeds:
        if k not in by_index:
            raise ConfigError(f"seed {k}:{i}:{face}: no keyframe {k} in the sequence")
        if i >= len(by_index[k].planes):
            raise ConfigError(f"seed {k}:{i}:{face}: no plane {i} in keyframe {k} (it has {len(by_index[k].planes)}, "
                              "counted from 0)")
        if face not in plane_map.index:
            raise ConfigError(f"seed {k}:{i}:{face}: no face {face!r} in the plane map")
        kf = by_index[k]
        planes_S.append(plane_from_frame(normalise_plane(kf.planes[i].plane), kf.pose))
        planes_B.append(plane_map.faces[plane_map.index[face]].plane)
        centres_B.append(plane_map.faces[plane_map.index[face]].centre)
        seen.append((kf.pose, kf.planes[i].cov))
    seeded = align_from_seeds(np.array(planes_S), np.array(planes_B), cfg.backend, prior, np.array(centres_B),
                              [f"{k}:{i}:{face}" for k, i, face in seeds], seen, prior_given)
    return seeded_start(prior, seeded, {(k, i): face for k, i, face in seeds})


def oracle_of(root: Path) -> dict[tuple[int, int], str | None]:
    """Ground-truth associations of a simulated sequence: (keyframe index, plane) -> face id."""
    from bimgraph.sequence.groundtruth import load_groundtruth

    gt = load_groundtruth(root)
    return {(k, i): p.get("face_id") for k, planes in enumerate(gt.observations) for i, p in enumerate(planes)}


@dataclass
class Inputs:
    """What a run reads before its first keyframe: the sequence's metadata, the BIM model
    (its path and plane map) and the user's initial alignment."""

    seq_dir: Path
    meta: SequenceMeta
    model: Path
    plane_map: PlaneMap
    initial: Alignment


def load_inputs(seq_dir: Path, bim: Path | None, cfg: Config, progress=None) -> Inputs:
    """Load them once, so that the pipeline and a viewer following it share them (`progress`:
    the IFC import's, see `load_model`)."""
    seq_dir = Path(seq_dir)
    meta = load_meta(seq_dir)
    model = model_path(seq_dir, meta, bim)
    plane_map = load_model(model, cfg, progress)
    if not plane_map.faces:
        raise InputError(f"{model}: the BIM model has no wall faces")
    return Inputs(seq_dir, meta, model, plane_map, initial_alignment(meta, cfg))


# every file a run writes, and `bimgraph eval`'s of it
_RUN_FILES = (TRAJECTORY_BIM, TRAJECTORY_SLAM, EXTRINSIC, ASSOCIATIONS, LANDMARKS, SUMMARY, *DEVIATION_FILES, METRICS)


def clear_previous_run(out_dir: Path, recording: Path | None = None) -> None:
    """Remove what an earlier run wrote into `out_dir`, before this run writes there: one
    that stops before it has written each of its files (its deviation report comes last; a
    graph made singular at its first keyframe writes almost nothing) would otherwise leave
    the earlier run's beside its own as if they were its own. That includes the recording
    its summary names if it lies in `out_dir` (unless it is this run's, `recording`).
    (`out_dir` is a folder: `run` made sure of it.)"""
    summary = Path(out_dir) / SUMMARY
    try:
        earlier = load_summary(summary).recording if summary.is_file() else None
    except BimgraphError:  # (a damaged summary names nothing for sure)
        earlier = None
    if earlier is not None and Path(earlier).parent.resolve() == Path(out_dir).resolve() and (
            recording is None or Path(earlier).resolve() != Path(recording).resolve()):
        Path(earlier).unlink(missing_ok=True)
    _remove(out_dir, _RUN_FILES)
    _remove(out_dir, [name + ".tmp" for name in _RUN_FILES])  # (a run killed while it wrote one)


def run_outputs_in(folder: Path) -> list[str]:
    """The names of the files a run (or `eval`) wrote that `folder` holds."""
    return [name for name in _RUN_FILES if (Path(folder) / name).is_file()]


def _remove(out_dir: Path, names) -> None:
    for name in names:
        (Path(out_dir) / name).unlink(missing_ok=True)


@singular_as_error()
def run(seq_dir: Path, out_dir: Path, mode: str = "online", bim: Path | None = None, config: Config | None = None,
        seeds: list[tuple[int, int, str]] = (), oracle: bool = False, listener: Listener | None = None,
        progress: Callable[[int, int | None], None] | None = None, inputs: Inputs | None = None,
        stage: Callable[[str], None] | None = None, log: Callable[[str], None] | None = None,
        recording: Path | None = None) -> Results | None:
    """Run the backend on a sequence folder and write the outputs to `out_dir`. The sequence
    is read and validated whole first; online runs then process it keyframe by keyframe,
    writing as they go, and return None. `inputs`, if given, are those of
    `load_inputs(seq_dir, bim, config)`; `progress(keyframes done, total)` hears each online
    keyframe, `stage(what)` the long step after the last one, and `log(line)` a warning;
    `recording`, the Rerun recording the caller makes of the run, is named in the summary."""
    cfg = config or Config()
    seq_dir = Path(seq_dir)
    if mode not in ("online", "offline"):
        raise ConfigError(f"mode {mode!r}: expected online or offline")
    inputs = inputs or load_inputs(seq_dir, bim, cfg)
    meta, plane_map, initial = inputs.meta, inputs.plane_map, inputs.initial
    # Absolute, so that `bimgraph view OUTDIR` finds them from anywhere.
    named = {"sequence": str(seq_dir.resolve()), "model": str(Path(inputs.model).resolve()),
             **({} if recording is None else {"recording": str(Path(recording).resolve())})}
    truth = oracle_of(seq_dir) if oracle else None
    # the whole sequence is read and validated before anything is written: a bad line must
    # not leave an earlier run's outputs in `out_dir` overwritten by a part of this one
    sequence = load_sequence(seq_dir)
    if not sequence.keyframes:
        raise InputError(f"{seq_dir}: the sequence has no keyframes")
    if not any(kf.planes for kf in sequence.keyframes):
        # (run anyway, it would place nothing and list every face in view as possibly not built)
        hint = (f": detect them in its depth images first, with `bimgraph planes {seq_dir}`"
                if any(kf.depth for kf in sequence.keyframes) else "")
        raise InputError(f"{seq_dir}: no keyframe has a plane detection{hint}")
    if log is not None:
        for warning in sequence_warnings(sequence.keyframes, meta):
            log(f"warning: {seq_dir}: {warning}")
        if (warning := plane_map.far_warning()) is not None:
            log(f"warning: {inputs.model}: {warning}")
    if seeds:
        initial = seed_alignment(sequence.keyframes, plane_map, list(seeds), cfg, initial, meta.initial_alignment is not None)
    elif meta.initial_alignment is None and log is not None:
        noise = cfg.backend.noise
        log(f"warning: {seq_dir / 'sequence.json'} gives no initial_alignment and no --seed pair was given: T_B_S "
            f"starts at identity, trusted to {noise.extrinsic_rot_deg:g} deg and {noise.extrinsic_trans_m:g} m "
            "(backend.noise.extrinsic_*), so walls are matched only if the front-end's frame lies there already")
    ensure_folder(out_dir)  # (before the work, not after it; after everything the input can refuse)
    clear_previous_run(out_dir, recording)
    if mode == "offline":
        start = time.perf_counter()
        results = run_offline(sequence.keyframes, plane_map, cfg.backend, initial, listener, truth, depth_tilt(meta, cfg))
        _warn_unfitting(results.landmarks, results.T_B_S, inputs.model, log)
        # as online: every other output first, `finished` once the report is written too
        write_results(out_dir, results, named, finished=False)
        report_start = time.perf_counter()
        _write_report(out_dir, plane_map, ReportBasis.of(results), meta.camera, cfg)
        results.timings.update(deviation_report_s=time.perf_counter() - report_start, total_s=time.perf_counter() - start)
        write_summary(out_dir, results, named)
        return results

    # the extrinsic's covariance per keyframe only for a listener (the viewer plots it); the
    # writer asks for it when it writes
    backend = Backend(plane_map, cfg.backend, initial, listener, truth, covariance=listener is not None,
                      tilt=depth_tilt(meta, cfg))
    writer = OnlineWriter(out_dir, cfg.backend.write_every, named)
    start = time.perf_counter()
    try:
        for n, kf in enumerate(sequence.keyframes, start=1):
            writer.keyframe(backend.process(kf), backend)
            if progress is not None:
                progress(n, None)
    except BaseException:
        writer.snapshot(backend, finished=False, timings={"total_s": time.perf_counter() - start})
        writer.close()
        raise
    # the run's outputs as the last keyframe left them, before the deviation step (which
    # changes the backend's landmarks); `finished` once the report is written too
    writer.snapshot(backend, finished=False, timings={"total_s": time.perf_counter() - start})
    writer.close()
    _warn_unfitting(backend.landmarks.current(), writer.last.T_B_S, inputs.model, log)
    if stage is not None:  # (about as long as offline rounds: seconds to a minute)
        stage("measuring the walls")
    report_start = time.perf_counter()
    basis = _online_deviations(backend, sequence.keyframes, plane_map, cfg, initial, truth, writer.T_B_C)
    _write_report(out_dir, plane_map, basis, meta.camera, cfg)
    writer.finish({"deviation_report_s": time.perf_counter() - report_start, "total_s": time.perf_counter() - start},
                  basis.challenge)
    return None


def _warn_unfitting(landmarks, T_B_S: np.ndarray, model: Path, log) -> None:
    if log is not None and (warning := unfitting_model(landmarks, T_B_S)) is not None:
        log(f"warning: {model}: {warning}")


@dataclass(frozen=True)
class ReportBasis:
    """What a deviation report is measured from: the landmarks (as `ObservedPlane`s), `T_B_S`,
    `T_B_C`, and the robust alignment's runner-up and challenge there (if it judged)."""

    planes: list
    T_B_S: np.ndarray
    T_B_C: list[np.ndarray]
    rival: RivalAlignment | None = None
    challenge: dict | None = None

    @classmethod
    def of(cls, results: Results) -> ReportBasis:
        return cls(results.observed_planes, results.T_B_S, results.T_B_C, results.rival_alignment, results.alignment_challenge)


def _write_report(out_dir: Path, plane_map: PlaneMap, basis: ReportBasis, camera, cfg: Config) -> None:
    """The deviation report, whole or not at all."""
    try:
        write_deviation_outputs(out_dir, plane_map, basis.planes, basis.T_B_S, basis.T_B_C, camera, cfg.deviations,
                                rival=basis.rival)
    except BaseException:
        _remove(out_dir, DEVIATION_FILES)  # (a report written in part is no report)
        raise


def _online_deviations(backend: Backend, keyframes: list[Keyframe], plane_map: PlaneMap, cfg: Config, initial: Alignment,
                       truth, T_B_C_causal: list[np.ndarray]) -> ReportBasis:
    """What the deviation report of an online run is measured from. With
    `deviations.online_refine`, where the offline rounds take the backend's graph (they change
    its landmarks); else at its own solution."""
    if cfg.deviations.online_refine:
        return ReportBasis.of(OfflineEstimator(plane_map, cfg.backend, initial, oracle=truth, causal=backend,
                                               tilt=backend.tilt).refine(keyframes))
    planes, T_S_B = observed_planes_isam2(backend.graph, backend.landmarks.current(),
                                          BatchSolver(cfg.backend.offline.max_iterations, cfg.backend.offline.relative_error_tol))
    return ReportBasis(planes, inverse(T_S_B), T_B_C_causal)
