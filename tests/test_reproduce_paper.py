"""scripts/reproduce_paper.py: the summary table over runs."""

from conftest import load_script


def test_the_table_leaves_a_metric_a_method_lacks_empty():
    """The baselines have no covariance, so no NEES: their cell is "-", and the table is still
    written (it raised KeyError after the NEES column came)."""
    script = load_script("reproduce_paper")
    bimgraph = {key: 1.0 for key, _, _ in script.METRICS} | {"association_precision": 1.0, "association_recall": 0.99}
    baseline = {key: 2.0 for key, _, _ in script.METRICS if key != "extrinsic_nees"}
    metrics = {m: (dict(bimgraph) if m.startswith("bimgraph") else dict(baseline)) for m in script.METHODS}
    runs = [{"scenario": "office", "sensor": "planes", "seed": seed, "metrics": metrics} for seed in (1, 2)]
    rows = {line.split("|")[1].strip(): line for line in script.markdown(runs).splitlines() if line.startswith("| ")}
    nees = [title for _, title, _ in script.METRICS].index("E NEES") + 2
    assert rows["global"].split("|")[nees].strip() == "-"
    assert rows["bimgraph offline"].split("|")[nees].strip() == "1.0 ± 0.0"
