"""The `bimgraph` command. Thin: parse options, call the library, map known errors to one line.

Heavy imports (gtsam, open3d, ifcopenshell, rerun) happen inside each command so that
`bimgraph --help` answers at once.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import Optional

# The dense matrices here are small (joint marginals of a few thousand rows): OpenBLAS's threads
# gain nothing on them, and on a busy machine they spin against each other (measured: a site
# walk offline 11.3 s either way idle, 13.8 against 11.5 s beside one busy process; a 1500-row
# Cholesky 1.1 s against 0.08 s beside two). Set before numpy loads; the environment overrides.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import typer

from bimgraph.terminal import Commands, console, friendly_errors, import_progress, progress_bar

app = typer.Typer(
    cls=Commands,
    name="bimgraph",
    help="BIM-aware SLAM backend: corrects a SLAM trajectory against a building's IFC model "
    "and reports how each observed wall deviates from plan.\n\n"
    "Typical use:\n\n"
    "  bimgraph bim model.ifc -o planes.json\n\n"
    "  bimgraph simulate -o seq --scenario office\n\n"
    "  bimgraph run seq -o out",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    rich_markup_mode="rich",
)

ConfigOption = typer.Option(None, "--config", "-c", help="YAML file overriding any subset of `bimgraph config --default`.")


@app.command()
@friendly_errors
def config(
    default: bool = typer.Option(False, "--default", help="Print the default configuration."),
    check: Optional[Path] = typer.Option(None, "--check", help="Validate a configuration file."),
):
    """Print the default configuration, or validate one.

    Example: bimgraph config --default > my.yaml; edit it; bimgraph run seq -o out --config my.yaml
    """
    from bimgraph.config import default_yaml, load_config

    if check is not None and default:
        raise typer.BadParameter("give --default or --check FILE, not both")
    if check is not None:
        load_config(check)
        typer.echo(f"{check}: valid")
    elif default:
        sys.stdout.write(default_yaml())
    else:
        raise typer.BadParameter("give --default or --check FILE")


@app.command()
@friendly_errors
def bim(
    model: Path = typer.Argument(..., help="The IFC model (IFC2X3 or IFC4)."),
    output: Path = typer.Option(..., "--output", "-o", help="The plane map JSON to write."),
    config_file: Optional[Path] = ConfigOption,
):
    """Import an IFC model: every wall side face, split per room, as an oriented plane in B.

    Example: bimgraph bim building.ifc -o planes.json
    """
    from bimgraph.bim.ifc_import import import_ifc
    from bimgraph.bim.planemap import save_plane_map
    from bimgraph.config import load_config
    from bimgraph.errors import InputError

    if output.resolve() == model.resolve():
        raise InputError(f"{output}: is the model itself; the plane map would replace it")
    cfg = load_config(config_file)
    out = console()
    # (a warning is one line, however long: a log may be grepped by GlobalId)
    with import_progress(out, f"bimgraph bim {model.name}") as progress:
        plane_map, report = import_ifc(model, cfg.bim, log=lambda text: out.print(text, soft_wrap=True, highlight=False, markup=False),
                                       progress=progress)
    save_plane_map(plane_map, output)
    console(stderr=False).print(report)


@app.command()
@friendly_errors
def planes(
    seqdir: Path = typer.Argument(..., help="A sequence folder with depth images, or a TUM RGB-D folder (with --trajectory)."),
    trajectory: Optional[Path] = typer.Option(None, "--trajectory", "-t", help="TUM trajectory (T_S_C) of any SLAM, to turn a plain TUM RGB-D folder into a sequence."),
    intrinsics: Optional[Path] = typer.Option(None, "--intrinsics", "-i", help="YAML/JSON file with width, height, fx, fy, cx, cy (depth_scale optional)."),
    fx: Optional[float] = typer.Option(None, "--fx", help="Focal length x in pixels (with --fy --cx --cy instead of --intrinsics)."),
    fy: Optional[float] = typer.Option(None, "--fy"),
    cx: Optional[float] = typer.Option(None, "--cx"),
    cy: Optional[float] = typer.Option(None, "--cy"),
    max_dt: float = typer.Option(0.02, "--max-dt", help="Largest stamp difference between a depth image and its trajectory pose (s)."),
    config_file: Optional[Path] = ConfigOption,
):
    """Detect planes in every keyframe's depth image and write them into the keyframes file.

    A keyframe without a depth image keeps its planes; a sequence without any is refused.

    Example (TUM fr1/desk, ORB-SLAM trajectory):
    bimgraph planes rgbd_dataset_freiburg1_desk -t CameraTrajectory.txt --fx 517.3 --fy 516.5 --cx 318.6 --cy 255.3
    """
    from bimgraph.config import load_config
    from bimgraph.planes.sequence import extract_into, open_input

    cfg = load_config(config_file)
    seq, camera = open_input(seqdir, trajectory, intrinsics, (fx, fy, cx, cy), max_dt)
    out = console()
    if trajectory is not None and seq.meta.initial_alignment is not None:
        out.print(f"note: {seqdir}/sequence.json keeps its initial_alignment and gravity_aligned: redo them if "
                  f"{trajectory.name}'s frame S is not the one they were set for", highlight=False, soft_wrap=True)
    with progress_bar(out) as progress:
        task = progress.add_task("extracting planes", total=sum(kf.depth is not None for kf in seq.keyframes))
        report = extract_into(seq, camera, cfg, on_frame=lambda kf, extraction: progress.advance(task))
    for line in report.problems:
        out.print(f"[yellow]skipped[/yellow] {line}", highlight=False, soft_wrap=True)
    console(stderr=False).print(f"{report.planes} planes in {report.frames} frames ({len(report.problems)} skipped) -> {seqdir}",
                                soft_wrap=True)


@app.command()
@friendly_errors
def simulate(
    output: Path = typer.Option(..., "--output", "-o", help="The sequence folder to write."),
    scenario: Optional[str] = typer.Option(None, "--scenario", metavar="office|site", help="Generated building: office or site (default office)."),
    ifc: Optional[Path] = typer.Option(None, "--ifc", help="Walk through this IFC model instead of a generated one."),
    storey: Optional[str] = typer.Option(None, "--storey", help="The model's storey to walk, by name (default: the one with the most wall area; sim.storey)."),
    sensor: str = typer.Option("planes", "--sensor", metavar="planes|depth", help="planes: plane detections (fast); depth: 640x480 depth images."),
    keyframes: int = typer.Option(600, "--keyframes", "-n", help="Number of keyframes."),
    seed: int = typer.Option(0, "--seed", help="Random seed; the same seed gives the same files."),
    config_file: Optional[Path] = ConfigOption,
):
    """Simulate a walk through a building with a drifting front-end, and its ground truth.

    Example: bimgraph simulate -o seq --scenario site --keyframes 800 --seed 3

    Example: bimgraph simulate -o seq --ifc model.ifc --storey "Level 2"
    """
    from bimgraph.config import load_config
    from bimgraph.sim.simulate import SimOptions, simulate as run_simulation

    cfg = load_config(config_file)
    if storey is not None:
        cfg = cfg.model_copy(update={"sim": cfg.sim.model_copy(update={"storey": storey})})
    opts = SimOptions(output=output, scenario=scenario, ifc=ifc, sensor=sensor, keyframes=keyframes, seed=seed)
    opts.check()
    out = console()
    with progress_bar(out) as bar:
        task = bar.add_task(f"simulating ({sensor})", total=keyframes)
        summary = run_simulation(opts, cfg, log=out.print, progress=lambda done, total: bar.update(task, completed=done),
                                 stage=lambda text: bar.update(task, description=f"simulating ({sensor}): {text}"))
    drift = summary["drift"]
    console(stderr=False).print(
        f"{output}: {summary['keyframes']} keyframes, {summary['planes']} plane detections, "
        f"{summary['distance_m']:.1f} m walked; front-end drift {drift['final_drift_percent']:.2f} % of distance, "
        f"heading {drift['yaw_drift_deg_per_m']:.3f} deg/m; seconds: "
        + ", ".join(f"{stage} {seconds:.2f}" for stage, seconds in summary["timings_s"].items()))


@app.command()
@friendly_errors
def run(
    sequence: Path = typer.Argument(..., help="The sequence folder (sequence.json + keyframes.jsonl)."),
    output: Path = typer.Option(..., "--output", "-o", help="Folder for the trajectories, extrinsic, associations, landmarks, summary."),
    bim_model: Optional[Path] = typer.Option(None, "--bim", help="IFC model or plane map JSON; default: the model sequence.json names."),
    mode: str = typer.Option("online", "--mode", metavar="online|offline", help="online (keyframe by keyframe, causal) or offline (whole sequence, smoothed)."),
    seed: list[str] = typer.Option([], "--seed", help="Seed pair KEYFRAME:PLANE:FACE_ID for the initial alignment: keyframe index, the plane's position in that keyframe's planes list (from 0), the BIM face's id (repeat it; two walls at an angle fix the heading; pairs that disagree, or that turn T_B_S far from sequence.json's initial alignment, are refused); default: the sequence's manual alignment."),
    oracle: bool = typer.Option(False, "--oracle", help="Use the ground-truth associations of a simulated sequence (the reference the association is measured by)."),
    rrd: Optional[Path] = typer.Option(None, "--rrd", help="Save a Rerun recording of the run to this .rrd file (open it with: rerun FILE)."),
    spawn: bool = typer.Option(False, "--spawn", help="Open the Rerun viewer and stream the run to it as it goes."),
    config_file: Optional[Path] = ConfigOption,
):
    """Estimate the trajectory in B, the extrinsic T_B_S and the wall associations of a sequence.

    Example: bimgraph run seq -o out --mode offline --bim planes.json

    Example: bimgraph run seq -o out --rrd out/run.rrd; rerun out/run.rrd
    """
    from bimgraph.backend.pipeline import load_inputs, parse_seed, run as run_backend
    from bimgraph.config import load_config

    cfg = load_config(config_file)
    if spawn:  # (before the inputs are read and the run made, not after)
        from bimgraph.viewer.recording import check_viewer_can_open

        check_viewer_can_open()
    out = console()
    seeds = [parse_seed(s) for s in seed]
    with import_progress(out, "bimgraph run: reading the BIM model") as progress:
        inputs = load_inputs(sequence, bim_model, cfg, progress)
    viewer = listener = None
    if rrd is not None or spawn:
        from bimgraph.viewer.session import follow_run

        viewer, listener = follow_run(inputs, cfg, rrd=rrd, spawn=spawn)
    try:
        with progress_bar(out) as bar:
            task = bar.add_task(f"bimgraph run ({mode})", total=None)
            run_backend(sequence, output, mode=mode, bim=bim_model, config=cfg, seeds=seeds, oracle=oracle,
                        listener=listener, progress=lambda done, total: bar.update(task, completed=done), inputs=inputs,
                        log=lambda text: out.print(text, soft_wrap=True, highlight=False, markup=False),
                        stage=lambda text: bar.update(task, description=f"bimgraph run ({mode}): {text}"), recording=rrd)
    finally:
        if viewer is not None:  # an interrupted run still leaves a complete recording of what it did
            from bimgraph.viewer.session import finish

            finish(viewer, output, rrd)
    from bimgraph.evaluation.report import summary_table
    from bimgraph.evaluation.runs import run_summary

    result = console(stderr=False)
    result.print(summary_table(f"bimgraph run: {output}", run_summary(output)))
    if rrd is not None:
        from bimgraph.viewer.rrd import open_command

        result.print(f"recording: {rrd} (open it with: {open_command(rrd)})", soft_wrap=True)


@app.command()
@friendly_errors
def view(
    outdir: Path = typer.Argument(..., help="The output folder of a finished `bimgraph run`."),
    sequence: Optional[Path] = typer.Option(None, "--sequence", "-s", help="The run's sequence folder (default: the one summary.json names)."),
    bim_model: Optional[Path] = typer.Option(None, "--bim", help="IFC model or plane map JSON; default: the one the run used (summary.json names it), else the one sequence.json names."),
    rrd: Optional[Path] = typer.Option(None, "--rrd", help="Save the recording to this .rrd file instead of opening the viewer."),
    spawn: bool = typer.Option(False, "--spawn", help="Also open the viewer when saving with --rrd."),
    config_file: Optional[Path] = ConfigOption,
):
    """Show a finished run in the Rerun viewer: trajectories, extrinsic, associations, deviations.

    Example: bimgraph view out --sequence seq

    Example: bimgraph view out --sequence seq --rrd out/run.rrd
    """
    from bimgraph.config import load_config
    from bimgraph.viewer.rrd import open_command
    from bimgraph.viewer.session import view_outputs

    cfg = load_config(config_file)
    n, total = view_outputs(outdir, sequence, cfg, bim=bim_model, rrd=rrd, spawn=spawn or rrd is None)
    stopped = f" of the sequence's {total} (the run stopped early)" if n < total else ""
    # (one line, however narrow the terminal: the command in it is to be copied)
    console(stderr=False).print(f"{outdir}: {n} keyframes{stopped} logged" + (f" to {rrd} (open it with: {open_command(rrd)})" if rrd else ""),
                                soft_wrap=True)


@app.command("eval")
@friendly_errors
def evaluate(
    outdirs: list[Path] = typer.Argument(..., help="Output folders of `bimgraph run` on the same sequence."),
    gt: Path = typer.Option(..., "--gt", help="The sequence folder, with its reference in groundtruth/: a simulated one's, or T_B_C.tum of one's own (docs/formats.md)."),
    baselines: bool = typer.Option(True, "--baselines/--no-baselines", help="Also measure the seed paper's manual, global and local alignment, with the first run's associations."),
    bim_model: Optional[Path] = typer.Option(None, "--bim", help="IFC model or plane map JSON to measure against; default: the one the runs used (their summary.json names it), else the one the sequence names."),
    t_max_diff: float = typer.Option(0.01, "--t-max-diff", min=0.0, help="Seconds a reference pose may be from a keyframe's stamp to be its truth (as evo's)."),
    walls: Optional[Path] = typer.Option(None, "--walls", help="Walls measured on site, a CSV (face_id,offset_m[,tilt_deg][,built]): score each run's deviation report against them (docs/formats.md)."),
    config_file: Optional[Path] = ConfigOption,
):
    """Measure runs against ground truth: ATE, RPE, extrinsic, wall errors, association.

    The wall errors are the seed paper's; association is precision and recall against the simulator's truth. Writes metrics.json into each output folder.

    A simulated sequence's groundtruth/ has everything. A recording of one's own needs only groundtruth/T_B_C.tum, the reference trajectory in B (a total station's, a motion-capture system's), at its own stamps: each keyframe takes the pose nearest its stamp within --t-max-diff, and keyframes without one are left out of ATE and RPE; with groundtruth/T_B_S.json the extrinsic is measured too. Without the faces behind the planes (observations.jsonl) the wall errors average over the first run's matches and association is not scored.

    With --walls, each run's deviation report is scored against walls measured on site: detection of the walls off plan beyond the report's tolerance, and the offsets' errors.

    The last row, "truth", is the ground-truth trajectory measured the same way: the floor of the wall errors that the detections' noise and the as-built deviations leave.

    Example: bimgraph eval out/online out/offline --gt seq
    """
    from bimgraph.config import load_config
    from bimgraph.evaluation.evaluate import reduction_percent
    from bimgraph.evaluation.report import metrics_table
    from bimgraph.evaluation.runs import Evaluation, check_runs_of, load_estimate, model_of_runs, run_timings, summary_row, write_metrics

    cfg = load_config(config_file)
    check_runs_of(outdirs, gt)
    # every run read, validated and measured before any metrics.json is written
    estimates = {str(d): load_estimate(d) for d in outdirs}
    timings = {str(d): run_timings(d) for d in outdirs}
    associations = next(iter(estimates.values())).associations
    evaluation = Evaluation(gt, cfg, bim_model or model_of_runs(outdirs, gt), associations, t_max_diff)
    measured_walls = None
    if walls is not None:
        from bimgraph.evaluation.walls import load_measured_walls

        measured_walls = load_measured_walls(walls, evaluation.plane_map.index)
    rows = []
    if baselines:
        for method in ["manual", "global", "local"]:
            rows.append(summary_row(method, evaluation.metrics(evaluation.baseline(method, associations))))
    measured = {out_dir: evaluation.metrics(estimate, out_dir) for out_dir, estimate in estimates.items()}
    wall_lines = []
    if measured_walls is not None:
        from bimgraph.evaluation.runs import wall_scores

        for out_dir, metrics in measured.items():
            metrics["walls_measured"], line = wall_scores(Path(out_dir), measured_walls)
            wall_lines.append(f"{Path(out_dir).name}: {line}")
    total = len(evaluation.sequence.keyframes)
    for out_dir, metrics in measured.items():
        write_metrics(out_dir, metrics)
        stopped = f" (stopped: first {metrics['keyframes']} of {total} keyframes)" if metrics["keyframes"] < total else ""
        rows.append({**summary_row(Path(out_dir).name + stopped, metrics), **timings[out_dir]})
    rows.append(summary_row("truth", evaluation.truth_metrics()))
    if baselines:
        manual = rows[0]
        for row in rows[1:]:
            row["wall_angle_reduction_pct"] = reduction_percent(row["wall_angle_deg"], manual["wall_angle_deg"])
            row["wall_distance_reduction_pct"] = reduction_percent(row["wall_distance_m"], manual["wall_distance_m"])
    from rich.console import Console

    # (a file or a pipe takes the table at its own width: rich's 80 columns there cut figures)
    terminal = Console()
    Console(width=max(terminal.width, 120) if terminal.is_terminal else 1000).print(
        metrics_table(rows, walls_on_truth=evaluation.truth.faces is not None))
    for line in wall_lines:
        terminal.print(f"walls measured on site, {line}", soft_wrap=True, highlight=False, markup=False)

def main():
    app()


if __name__ == "__main__":
    main()
