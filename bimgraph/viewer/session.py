"""The viewer around whole runs: set up for a sequence folder (plane map, camera, initial
alignment, ground truth when simulated), finish with the deviation report, and replay a
finished run's output folder (`bimgraph view`). File reading lives here, not in the viewer."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from bimgraph.bim.planemap import PlaneMap
from bimgraph.config import Config
from bimgraph.errors import FormatError, InputError
from bimgraph.geometry import inverse
from bimgraph.sequence.format import SequenceMeta, load_sequence
from bimgraph.viewer.follow import mark_deviations, read_depth
from bimgraph.viewer.recording import open_recording, prepare_target
from bimgraph.viewer.rerun_viewer import RerunViewer


def ground_truth(seq_dir: Path) -> tuple[tuple[np.ndarray, np.ndarray] | None, np.ndarray | None]:
    """The reference trajectory's stamps and `T_B_C` poses and the true `T_B_S`, of a
    sequence whose groundtruth/ has them (`load_reference`; None for what it lacks)."""
    from bimgraph.sequence.groundtruth import FOLDER, load_reference

    if not (Path(seq_dir) / FOLDER).is_dir():
        return None, None
    reference = load_reference(seq_dir)
    return (reference.stamps, reference.T_B_C), reference.T_B_S


def partial(rrd: Path) -> Path:
    """Where the recording for `rrd` is written until `finish` moves it there: a run or a view
    stopped half-way must not leave an earlier recording at `rrd` cut short."""
    return rrd.with_name(rrd.name + ".part")


def open_viewer(seq_dir: Path, meta: SequenceMeta, plane_map: PlaneMap, T_B_S_initial: np.ndarray, cfg: Config,
                rrd: Path | None = None, spawn: bool = False) -> RerunViewer:
    """A viewer for a run over the sequence in `seq_dir`, saving to `rrd` (through `partial`)
    and/or streaming to a spawned Rerun viewer."""
    if rrd is not None:
        prepare_target(Path(rrd))
    T_B_C_truth, T_B_S_truth = ground_truth(seq_dir)
    return RerunViewer(open_recording(None if rrd is None else partial(Path(rrd)), spawn, meta.camera), plane_map,
                       T_B_S_initial, camera=meta.camera, T_B_C_truth=T_B_C_truth, T_B_S_truth=T_B_S_truth, config=cfg.viewer)


def deviation_report(out_dir: Path):
    """The run's deviation report (`DeviationsFile`), None if it wrote none or its summary does
    not say it finished (`deviations.report.run_report`)."""
    from bimgraph.backend.results import SUMMARY, load_summary
    from bimgraph.deviations.report import run_report

    summary = Path(out_dir) / SUMMARY
    return run_report(out_dir, summary.is_file() and load_summary(summary).finished)


def face_statuses(report) -> dict[str, str]:
    """Each face's status in a deviation report ("contested" for a face of a contest that is
    not deviating either way)."""
    statuses = {f.face_id: f.status for f in report.faces}
    for explanation in report.contested:
        statuses.update({f.face_id: "contested" for f in explanation.deviating if statuses.get(f.face_id) != "deviating"})
    return statuses


def finish(viewer: RerunViewer, out_dir: Path, rrd: Path | None = None, report=None) -> None:
    """Colour the deviating and contested faces and draw the room widths and wall thicknesses
    if the run wrote a deviation report (`report`, if read already), close, and move the
    recording to `rrd` (the file `open_viewer` was given) if it holds a keyframe: a run whose
    input was refused must not replace an earlier recording with an empty one."""
    report = report or deviation_report(out_dir)
    if report is not None:
        mark_deviations(viewer, face_statuses(report))
        viewer.widths(report.widths)
        viewer.thicknesses(report.thicknesses)
    close(viewer, rrd, keep=viewer.logged_keyframes > 0)


def close(viewer: RerunViewer, rrd: Path | None, keep: bool) -> None:
    """Close the viewer's recording; move it to `rrd` if `keep`, else drop it (whatever was
    at `rrd` stays)."""
    viewer.close()
    if rrd is not None:
        if keep:
            os.replace(partial(Path(rrd)), rrd)
        else:
            partial(Path(rrd)).unlink(missing_ok=True)


def view_outputs(out_dir: Path, seq_dir: Path | None, cfg: Config, bim: Path | None = None,
                 rrd: Path | None = None, spawn: bool = False) -> tuple[int, int]:
    """Log a finished run's output folder (trajectory_bim.tum, trajectory_slam.tum,
    associations.json, deviations.json if any) against its sequence; returns the number
    of keyframes logged and the sequence's (fewer logged: the run stopped early). The extrinsic at each keyframe is recovered as
    `T_B_C @ inverse(T_S_C)` from the two trajectories; associations are the final ones."""
    from bimgraph.backend.pipeline import initial_alignment, load_model, model_path, run_model
    from bimgraph.backend.results import (ASSOCIATIONS, SUMMARY, TRAJECTORY_BIM, TRAJECTORY_SLAM, check_stamps,
                                          load_associations, load_summary, run_trajectory)

    out_dir = Path(out_dir)
    if not out_dir.is_dir():
        raise InputError(f"{out_dir}: no such output folder")
    if seq_dir is None:
        named = load_summary(out_dir / SUMMARY).sequence if (out_dir / SUMMARY).is_file() else None
        if named is None:
            raise InputError(f"{out_dir}: the run does not name its sequence; give it with --sequence SEQDIR")
        seq_dir = Path(named)
        if not seq_dir.is_dir():
            raise InputError(f"{seq_dir}: the run's sequence is not there (moved?); give it with --sequence SEQDIR")
    seq = load_sequence(seq_dir)
    plane_map = load_model(bim or run_model(out_dir, seq.root) or model_path(seq.root, seq.meta, None), cfg)
    stamps, T_B_C = run_trajectory(out_dir, TRAJECTORY_BIM)
    stamps_slam, T_S_C = run_trajectory(out_dir, TRAJECTORY_SLAM)
    if len(stamps) == 0:
        raise InputError(f"{out_dir}: the run has no keyframe to show (it stopped at its first)")
    if len(stamps_slam) != len(stamps):
        raise FormatError(f"{out_dir}: {TRAJECTORY_BIM} has {len(stamps)} poses, {TRAJECTORY_SLAM} {len(stamps_slam)}")
    check_stamps(str(out_dir), stamps, seq.keyframes, seq.root)
    keyframes = seq.keyframes[:len(stamps)]  # an interrupted online run covers a prefix
    faces = load_associations(out_dir / ASSOCIATIONS).face_of_observation()
    report = deviation_report(out_dir)  # (every file read before the recording is written)

    viewer = open_viewer(seq.root, seq.meta, plane_map, initial_alignment(seq.meta, cfg).T_B_S, cfg, rrd, spawn)
    try:
        for kf, T_B_C_k, T_S_C_k in zip(keyframes, T_B_C, T_S_C):
            depth = read_depth(seq.root / kf.depth) if kf.depth is not None and cfg.viewer.depth_images else None
            viewer.keyframe(kf.index, kf.stamp, T_S_C=kf.pose, T_B_C=T_B_C_k, T_B_S=T_B_C_k @ inverse(T_S_C_k),
                            planes=kf.planes, plane_faces=[faces.get((kf.index, i)) for i in range(len(kf.planes))],
                            depth=depth)
    except BaseException:  # (Ctrl-C too) a recording of part of a finished run is no replacement for one of all of it
        close(viewer, rrd, keep=False)
        raise
    finish(viewer, out_dir, rrd, report)
    return len(keyframes), len(seq.keyframes)


def follow_run(inputs, cfg: Config, rrd: Path | None = None, spawn: bool = False):
    """(viewer, listener) for `bimgraph run --rrd/--spawn` on the pipeline's `Inputs`: pass
    the listener to the pipeline, and `finish(viewer, out_dir, rrd)` after it."""
    from bimgraph.viewer.follow import RerunListener

    viewer = open_viewer(inputs.seq_dir, inputs.meta, inputs.plane_map, inputs.initial.T_B_S, cfg, rrd, spawn)
    return viewer, RerunListener(viewer, inputs.seq_dir)
