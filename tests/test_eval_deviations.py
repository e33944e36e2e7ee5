"""`scripts/eval_deviations.py`'s twin: the plan moved to where the walls were built, so that a
run on the same observations is the same scenario without deviations."""

import numpy as np
import pytest

from bimgraph.backend.pipeline import load_model, model_path
from bimgraph.config import Config
from bimgraph.sequence.format import load_sequence
from bimgraph.sequence.groundtruth import as_planned, load_groundtruth
from bimgraph.sim.simulate import SimOptions, simulate
from conftest import load_script


@pytest.fixture(scope="module")
def script():
    return load_script("eval_deviations")


def test_twin_has_exactly_the_faces_built_off_plan_as_built(script, tmp_path):
    root = tmp_path / "seq"
    simulate(SimOptions(output=root, scenario="site", sensor="planes", keyframes=20, seed=3), Config())
    plan = load_model(model_path(root, load_sequence(root).meta, None), Config())
    as_built = load_groundtruth(root).as_built
    records = {r["face_id"]: r for r in as_built["faces"]}
    elements = {e["face_id"]: e for e in as_built["elements"] if e["face_id"] is not None}
    twin = script.plan_as_built(plan, as_built)
    assert [f.id for f in twin.faces] == [f.id for f in plan.faces]
    moved = tilted = 0
    for planned, built in zip(plan.faces, twin.faces):
        record = records.get(planned.id)
        if record is None or not record["built"] or as_planned(record):
            assert built == planned  # sound, not built, or not in the walk's storey: as planned
            continue
        moved += 1
        tilted += record["tilt_deg"] != 0.0
        assert np.allclose(built.plane, record["plane_as_built"], atol=1e-9)
        # the outline as the simulator built it (tilted walls turn about their foot)
        assert np.allclose(built.polygon, elements[planned.id]["polygon"], atol=1e-6)
        assert len(built.holes) == len(elements[planned.id]["holes"])
    assert moved > 0 and tilted > 0  # the default site builds faces off plan, some tilted


def test_a_face_of_another_storey_counts_as_built(script):
    """The simulator's truth covers the walked storey's faces; a face of another storey that
    the report lists (possibly not built) is a false alarm, not a crash (a walk through the
    Duplex sample model, before floors hid other storeys, stopped the evaluation)."""
    from bimgraph.config import DeviationConfig
    from bimgraph.deviations.estimate import DeviationReport, FaceReport

    report = DeviationReport(0.02, 0.5, 3.0, faces=[
        FaceReport("gone", "g1", "", "ground", "possibly_not_built"),
        FaceReport("upstairs", "g2", "", "first", "possibly_not_built")])
    scores = script.score(report, {"gone": (0.0, 0.0, False), "kept": (0.0, 0.0, True)}, DeviationConfig())
    assert scores["faces"] == 2 and scores["not_built_flagged"] == 2
    assert scores["not_built_precision"] == 0.5 and scores["not_built_recall"] == 1.0


def test_the_contest_is_scored_by_the_explanation_that_is_the_truth(script):
    """(The twenty-sixth session counted these by hand over 56 walks.)"""
    from bimgraph.config import DeviationConfig
    from bimgraph.deviations.estimate import Deviation, DeviationReport, Explanation, FaceReport

    def deviating(face_id):
        return FaceReport(face_id, "g", "", "", "deviating", 10, Deviation(0.06, 0.01, 0.0, 0.1))

    faces = [FaceReport(face, "g", "", "", "not_enough_evidence", 10, Deviation(0.03, 0.04, 0.0, 0.1)) for face in "ew"]
    report = DeviationReport(0.02, 0.5, 3.0, faces=faces, contested=[
        Explanation(0.6, (deviating("w"),)), Explanation(0.4, (deviating("e"),))])
    east_moved = {"e": (0.06, 0.0, True), "w": (0.0, 0.0, True)}
    scores = script.score(report, east_moved, DeviationConfig())
    assert (scores["contest"], scores["contest_true"]) == (1, 2)
    scores = script.score(report, {"e": (0.0, 0.0, True), "w": (0.0, 0.0, True)}, DeviationConfig())
    assert scores["contest_true"] == 0  # neither wall is off: neither explanation is the truth
    assert script.score(DeviationReport(0.02, 0.5, 3.0, faces=faces), east_moved, DeviationConfig())["contest"] == 0


def test_widths_are_scored_against_the_truth(script):
    from bimgraph.config import DeviationConfig
    from bimgraph.deviations.estimate import DeviationReport
    from bimgraph.deviations.widths import Width

    report = DeviationReport(0.02, 0.5, 3.0, widths=[
        Width(space_guid="r", space_name="", faces=("e", "w"), planned_m=5.06, built_m=5.002, sigma_m=0.004,
              n_keyframes=20, status="deviating"),
        Width(space_guid="r", space_name="", faces=("n", "s"), planned_m=4.0, built_m=4.001, sigma_m=0.005,
              n_keyframes=20, status="within_tolerance")])
    # the east face built 6 cm into the room: 6 cm narrower; the width measured 5.8
    scores = script.score(report, {"e": (0.06, 0.0, True)}, DeviationConfig())
    assert scores["widths"] == 2 and scores["widths_flagged"] == scores["widths_flagged_true"] == 1
    assert scores["width_err_rms_mm"] == pytest.approx(np.sqrt((2.0**2 + 1.0**2) / 2), rel=1e-6)
    assert script.score(report, {"e": (0.06, 0.0, False)}, DeviationConfig())["widths"] == 1  # (on a wall not built)


def test_thicknesses_are_scored_against_the_truth(script):
    from bimgraph.config import DeviationConfig
    from bimgraph.deviations.estimate import DeviationReport
    from bimgraph.deviations.widths import Thickness

    report = DeviationReport(0.02, 0.5, 3.0, thicknesses=[Thickness(
        wall_guid="w", wall_name="", faces=("a", "b"), planned_m=0.2, built_m=0.257, sigma_m=0.005, n_keyframes=20,
        status="deviating")])
    # face a built 6 cm out of the wall: 6 cm thicker; measured 5.7
    scores = script.score(report, {"a": (0.06, 0.0, True)}, DeviationConfig())
    assert scores["thicknesses"] == 1 and scores["thicknesses_flagged"] == scores["thicknesses_flagged_true"] == 1
    assert scores["thickness_err_rms_mm"] == pytest.approx(3.0, rel=1e-6) and scores["widths"] == 0
