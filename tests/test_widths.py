"""A room's clear width between two facing walls, as built (`bimgraph.deviations.widths`): one
room whose east wall is built 6 cm into it. East and west wall alone place the walk along x,
so which of the two is off the data cannot tell (tests/test_rival_alignment.py), but the room
being 6 cm narrower than planned they tell to millimetres: the alignment cancels."""

import numpy as np
import pytest
from synthetic_sequence import write_sequence
from test_deviations_backend import moved_plan

from bimgraph.backend.offline import OfflineEstimator
from bimgraph.backend.pipeline import run as run_pipeline
from bimgraph.backend.synthetic import make_scene
from bimgraph.bim.planemap import Space, save_plane_map
from bimgraph.config import BackendConfig, DeviationConfig
from bimgraph.deviations.assess import assess
from bimgraph.deviations.bcf import read_bcf_topics, write_bcf
from bimgraph.deviations.estimate import without_own_factor
from bimgraph.deviations.report import CSV_FILE, JSON_FILE, load_deviations, read_csv_rows, write_deviations
from bimgraph.evaluation.runs import run_summary
from bimgraph.geometry import inverse


def in_one_room(plan):
    return plan.model_copy(update={"faces": [f.model_copy(update={"space": Space(guid="room0", name="Room 0")})
                                             for f in plan.faces]})


@pytest.fixture(scope="module")
def one_room():
    scene = make_scene(120, rooms=(1, 1), seed=0, drift_rot_deg=0.01, drift_trans_m=0.001)
    plan = in_one_room(moved_plan(scene.plane_map, {"r00E": 0.06}))
    res = OfflineEstimator(plan, BackendConfig(), scene.initial).run(scene.keyframes)
    return plan, res, assess(plan, res.observed_planes, inverse(res.T_B_S), DeviationConfig(), rival=res.rival_alignment)


def test_the_room_is_measured_narrower_where_no_wall_can_be_blamed(one_room):
    _, _, report = one_room
    widths = {frozenset(w.faces): w for w in report.widths}
    assert set(widths) == {frozenset({"r00W", "r00E"}), frozenset({"r00N", "r00S"})}
    across = widths[frozenset({"r00W", "r00E"})]
    # the plan's east face lies 6 cm beyond the built wall: built 6 cm narrower than planned
    assert across.built_m - across.planned_m == pytest.approx(-0.06, abs=3 * across.sigma_m)
    assert across.sigma_m < 0.01 and across.status == "deviating"
    # (each wall's own offset is uncertain by the whole doubt about the alignment: 15-19 cm)
    sigmas = {f.face_id: f.deviation.offset_sigma_m for f in report.faces}
    assert across.sigma_m < 0.1 * min(sigmas["r00W"], sigmas["r00E"])
    along = widths[frozenset({"r00N", "r00S"})]
    assert along.built_m == pytest.approx(along.planned_m, abs=3 * along.sigma_m) and along.status != "deviating"


def test_faces_of_different_rooms_or_without_one_give_no_width(one_room):
    plan, res, _ = one_room
    apart = plan.model_copy(update={"faces": [f.model_copy(update={"space": Space(guid=f.id)}) for f in plan.faces]})
    assert not assess(apart, res.observed_planes, inverse(res.T_B_S), DeviationConfig()).widths
    nowhere = plan.model_copy(update={"faces": [f.model_copy(update={"space": None}) for f in plan.faces]})
    assert not assess(nowhere, res.observed_planes, inverse(res.T_B_S), DeviationConfig()).widths


def test_two_factors_taken_out_at_once_as_one_after_the_other():
    rng = np.random.default_rng(3)
    root = rng.normal(size=(9, 9))
    A1, A2 = rng.normal(size=(3, 9)), rng.normal(size=(3, 9))
    e1, e2 = rng.normal(size=3), rng.normal(size=3)
    # the marginal of a graph that holds both factors
    cov = np.linalg.inv(root @ root.T + np.eye(9) + A1.T @ A1 + A2.T @ A2)
    shift, both = without_own_factor(cov, (np.vstack([A1, A2]), np.concatenate([e1, e2])))
    # one after the other: the second factor's error moved by the first's shift
    shift1, cov1 = without_own_factor(cov, (A1, e1))
    shift2, cov2 = without_own_factor(cov1, (A2, e2 + A2 @ shift1))
    np.testing.assert_allclose(both, cov2, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(shift, shift1 + shift2, rtol=1e-10, atol=1e-12)


def test_widths_are_written_and_printed(one_room, tmp_path):
    _, _, report = one_room
    data = write_deviations(report, tmp_path)
    assert load_deviations(tmp_path / JSON_FILE) == data and len(data.widths) == 2
    rows = [row for row in read_csv_rows(tmp_path / CSV_FILE) if row["status"].startswith("width_")]
    assert sorted(" ".join(sorted(row["face_id"].split())) for row in rows) == ["r00E r00W", "r00N r00S"]
    assert all(float(row["built_m"]) - float(row["planned_m"]) == pytest.approx(float(row["offset_m"])) for row in rows)
    # its BCF topics: the contest's, and the deviating width's, selecting both walls
    plan, _, _ = one_room
    assert write_bcf(data, plan, tmp_path / "d.bcf", DeviationConfig()) == 2
    titles = dict(read_bcf_topics(tmp_path / "d.bcf"))
    assert sorted(titles["Room width off plan: Room 0"]) == ["w00E", "w00W"]


def test_the_run_prints_the_deviating_width(tmp_path):
    scene = write_sequence(tmp_path / "seq", 120, rooms=(1, 1), seed=2)
    save_plane_map(in_one_room(moved_plan(scene.plane_map, {"r00E": 0.06})), tmp_path / "seq" / "planes.json")
    run_pipeline(tmp_path / "seq", tmp_path / "out", mode="offline")
    rows = dict((label, text) for label, text in run_summary(tmp_path / "out") if label in ("room widths", "width"))
    assert "1 deviating" in rows["room widths"]
    assert "Room 0 between r00" in rows["width"] and "planned (-" in rows["width"]


def test_the_two_sides_of_a_stub_wall_are_no_width():
    """Both sides of a 20 cm wall standing in the room face away from each other: no room
    lies between them (nor between the arms of a U-shaped room across its notch)."""
    from bimgraph.bim.planemap import BimFace
    from bimgraph.deviations.widths import _facing

    def face(x, normal):
        return BimFace(id=f"f{x}", wall_guid="w", normal=(normal, 0.0, 0.0), offset=-normal * x, space=Space(guid="r"),
                       polygon=[(x, 0.0, 0.0), (x, 2.0, 0.0), (x, 2.0, 2.5), (x, 0.0, 2.5)])

    cfg = DeviationConfig()
    assert _facing(face(0.0, 1.0), face(4.0, -1.0), cfg)  # across the room
    assert not _facing(face(2.1, 1.0), face(1.9, -1.0), cfg)  # back to back
