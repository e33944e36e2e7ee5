"""A top-down plot of a run: the BIM wall faces (coloured as in the viewer: associated,
deviating, other), the raw front-end trajectory mapped by the initial alignment, the
corrected one and, for simulated sequences, the ground truth. For READMEs and reports where
the Rerun viewer (which needs a graphics adapter) cannot be used.

    python scripts/plot_run.py OUTDIR --sequence SEQDIR -o run.png

Needs matplotlib (pip install 'bimgraph[plot]').
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bimgraph.backend.pipeline import initial_alignment, load_model, model_path  # noqa: E402
from bimgraph.backend.results import ASSOCIATIONS, TRAJECTORY_BIM, load_associations  # noqa: E402
from bimgraph.config import Config, load_config  # noqa: E402
from bimgraph.evaluation.metrics import T_MAX_DIFF_S  # noqa: E402
from bimgraph.sequence.format import load_sequence  # noqa: E402
from bimgraph.sequence.tum import read_tum  # noqa: E402
from bimgraph.viewer.session import ground_truth  # noqa: E402


def _rgb(colour) -> tuple[float, float, float]:
    return tuple(c / 255.0 for c in colour[:3])


def plot_run(out_dir: Path, seq_dir: Path, png: Path, cfg: Config, bim: Path | None = None) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from bimgraph.deviations.report import JSON_FILE, load_deviations

    seq = load_sequence(seq_dir)
    plane_map = load_model(model_path(seq.root, seq.meta, bim), cfg)
    stamps, T_B_C = read_tum(Path(out_dir) / TRAJECTORY_BIM)
    T_B_S0 = initial_alignment(seq.meta, cfg).T_B_S
    raw = np.array([(T_B_S0 @ kf.pose)[:3, 3] for kf in seq.keyframes[:len(T_B_C)]])
    associated = {a.face for a in load_associations(Path(out_dir) / ASSOCIATIONS).associations}
    deviations = Path(out_dir) / JSON_FILE
    deviating = {f.face_id for f in load_deviations(deviations).faces if f.status == "deviating"} if deviations.is_file() else set()
    truth, _ = ground_truth(seq.root)

    colours = cfg.viewer
    fig, ax = plt.subplots(figsize=(10, 7), dpi=120)
    for face in plane_map.walls():
        n = np.asarray(face.normal)
        axis_u = np.cross([0.0, 0.0, 1.0], n)
        xy = np.asarray(face.polygon)[:, :2]
        u = xy @ axis_u[:2]
        ends = xy[[np.argmin(u), np.argmax(u)]]
        state = "deviating" if face.id in deviating else "associated" if face.id in associated else "unobserved"
        ax.plot(ends[:, 0], ends[:, 1], color=_rgb(colours.colour(state)), linewidth=2.5 if state != "unobserved" else 1.2,
                solid_capstyle="butt")
    if truth is not None:  # (up to the run's last keyframe: a run stopped early covers a prefix)
        truth_stamps, truth_poses = truth
        gt = truth_poses[np.argsort(truth_stamps)][np.sort(truth_stamps) <= stamps[-1] + T_MAX_DIFF_S, :3, 3]
        ax.plot(gt[:, 0], gt[:, 1], color=_rgb(colours.colour_truth), linewidth=1.0, linestyle="--", label="ground truth")
    ax.plot(raw[:, 0], raw[:, 1], color=_rgb(colours.colour_raw), linewidth=1.2, label="front-end, initial alignment")
    ax.plot(T_B_C[:, 0, 3], T_B_C[:, 1, 3], color=_rgb(colours.colour_corrected), linewidth=1.5, label="bimgraph")
    for state, label in (("associated", "wall associated"), ("deviating", "wall deviating"), ("unobserved", "wall not associated")):
        ax.plot([], [], color=_rgb(colours.colour(state)), linewidth=2.5, label=label)
    ax.set_aspect("equal")
    ax.set_xlabel("x in B (m)")
    ax.set_ylabel("y in B (m)")
    ax.set_title(f"{seq.meta.name or seq.root.name}: {len(T_B_C)} keyframes")
    ax.legend(loc="best", fontsize=8)
    fig.tight_layout()
    png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(png)
    plt.close(fig)


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("outdir", type=Path, help="output folder of bimgraph run")
    parser.add_argument("--sequence", "-s", type=Path, required=True)
    parser.add_argument("--bim", type=Path, help="IFC model or plane map (default: the sequence's)")
    parser.add_argument("--output", "-o", type=Path, default=Path("run.png"))
    parser.add_argument("--config", type=Path)
    args = parser.parse_args()
    plot_run(args.outdir, args.sequence, args.output, load_config(args.config), args.bim)
    print(f"{args.output}: written")


if __name__ == "__main__":
    main()
