"""Tables of metrics: rich for the terminal, markdown for the README and the reproduction."""

from __future__ import annotations

import math

COLUMNS = [
    ("method", "method", "{}"),
    ("keyframes_with_reference", "ref. kf", "{}"),
    ("ate_m", "ATE m", "{:.3f}"),
    ("extrinsic_rot_deg", "E deg", "{:.2f}"),
    ("extrinsic_trans_cm", "E cm", "{:.1f}"),
    ("extrinsic_nees", "E NEES", "{:.1f}"),
    ("wall_angle_deg", "wall deg", "{:.2f}"),
    ("wall_distance_m", "wall m", "{:.3f}"),
    ("wall_angle_reduction_pct", "deg -%", "{:.1f}"),
    ("wall_distance_reduction_pct", "m -%", "{:.1f}"),
    ("association_precision", "prec.", "{:.3f}"),
    ("association_recall", "recall", "{:.3f}"),
    ("run_s", "run s", "{:.1f}"),
    ("latency_median_ms", "ms/kf", "{:.1f}"),
]


def _cell(fmt: str, value) -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "-"
    return fmt.format(value)


def metrics_table(rows: list[dict], walls_on_truth: bool = True):
    """The rows (`runs.summary_row`) as a table, its caption a legend of the columns shown.
    `walls_on_truth`: whether the wall errors average over the planes truly of a face (else
    over the first run's matches)."""
    from rich.table import Table

    # (how many keyframes had a reference pose, where some had none)
    partial = any(r.get("keyframes_with_reference", 0) != r.get("keyframes", 0) for r in rows if r["method"] != "truth")
    present = [c for c in COLUMNS if any(c[0] in r for r in rows) and (c[0] != "keyframes_with_reference" or partial)]
    shown = {key for key, _, _ in present}
    # (the legend of the columns shown: without baselines there is no reduction against manual)
    legend = ["ref. kf: the keyframes with a reference pose, over which ATE is" if partial else None,
              "E: extrinsic T_B_S error (NEES: of its heading and horizontal position against its covariance, "
              "3 on average where that is honest)" if "extrinsic_rot_deg" in shown else None,
              "wall: the paper's wall errors" + ("" if walls_on_truth else ", over the first run's matches"),
              "-%: reduction against manual" if "wall_angle_reduction_pct" in shown else None,
              "prec./recall: association against ground truth" if "association_precision" in shown else None,
              "ms/kf: median online latency per keyframe" if "latency_median_ms" in shown else None,
              "truth: the ground truth measured alike"]
    table = Table(title="bimgraph evaluation", caption="; ".join(item for item in legend if item))
    # (a figure is never cut: where the width is short, the method's name folds)
    for _, title, _ in present:
        if title == "method":
            table.add_column(title, overflow="fold")
        else:
            table.add_column(title, justify="right", no_wrap=True)
    for row in rows:
        table.add_row(*[_cell(fmt, row.get(key)) for key, _, fmt in present])
    return table


def summary_table(title: str, rows: list[tuple[str, str]]):
    """Labelled lines (`runs.run_summary`) as a two-column table."""
    from rich.table import Table

    table = Table(title=title, show_header=False)
    table.add_column(style="bold", no_wrap=True)
    table.add_column()
    for label, text in rows:
        table.add_row(label, text)
    return table
