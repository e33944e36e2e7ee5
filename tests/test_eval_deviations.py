"""`scripts/eval_deviations.py`'s twin: the plan moved to where the walls were built, so that a
run on the same observations is the same scenario without deviations."""

import numpy as np
import pytest

from bimgraph.backend.pipeline import load_model, model_path
from bimgraph.config import Config
from bimgraph.sequence.format import load_sequence
from bimgraph.sequence.groundtruth import load_groundtruth
from bimgraph.sim.simulate import SimOptions, simulate
from conftest import load_script


@pytest.fixture(scope="module")
def script():
    return load_script("eval_deviations")


def test_twin_moves_exactly_the_faces_built_off_plan(script, tmp_path):
    root = tmp_path / "seq"
    simulate(SimOptions(output=root, scenario="site", sensor="planes", keyframes=20, seed=3), Config())
    plan = load_model(model_path(root, load_sequence(root).meta, None), Config())
    records = {r["face_id"]: r for r in load_groundtruth(root).as_built["faces"]}
    twin = script.plan_as_built(plan, load_groundtruth(root).as_built)
    assert [f.id for f in twin.faces] == [f.id for f in plan.faces]
    moved = 0
    for planned, built in zip(plan.faces, twin.faces):
        record = records.get(planned.id)
        if record is None or not record["built"] or np.allclose(record["plane_as_built"], record["plane_planned"]):
            assert built == planned  # sound, not built, or not in the walk's storey: as planned
            continue
        moved += 1
        assert np.allclose(built.plane, record["plane_as_built"], atol=1e-9)
        assert abs(np.asarray(built.polygon) @ built.plane[:3] + built.plane[3]).max() < 1e-9
        assert built.area == pytest.approx(planned.area, rel=1e-3)  # moved and tilted, not reshaped
    assert moved > 0  # the default site builds some faces off plan
