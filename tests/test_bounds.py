"""The Cramer-Rao bounds of `scripts/extrinsic_bound.py` (how well any estimator could place
T_B_S, or measure a face's offset, on a simulated walk) behave as bounds: finite and positive,
and never tighter when the estimator is told less."""

import numpy as np
import pytest

from bimgraph.config import Config
from bimgraph.sequence.groundtruth import as_planned, load_groundtruth
from bimgraph.sim.simulate import SimOptions, simulate
from conftest import load_script

LOOSE = (np.radians(0.1), 0.002)  # the robust alignment's tolerance floor (deg, m)


@pytest.fixture(scope="module")
def bounds():
    return load_script("extrinsic_bound")


@pytest.fixture(scope="module")
def site(tmp_path_factory):
    """A short walk through the default site: faces moved and tilted off plan, some not built."""
    root = tmp_path_factory.mktemp("bound_site") / "seq"
    simulate(SimOptions(output=root, scenario="site", sensor="planes", keyframes=120, seed=3), Config())
    return root


def test_face_bounds_cover_the_built_faces_seen_and_know_which_moved(bounds, site):
    rows = bounds.face_bounds(site, (0.0, 0.0), known_drift=False, min_keyframes=3)
    truth = {f["face_id"]: f for f in load_groundtruth(site).as_built["faces"]}
    assert rows and any(r["moved"] for r in rows) and not all(r["moved"] for r in rows)
    for r in rows:
        face = truth[r["face"]]
        assert face["built"] and r["keyframes"] >= 3
        assert r["moved"] == (not as_planned(face))
        assert 1e-4 < r["sigma_m"] < 0.5  # between a tenth of a millimetre and half a metre


def test_trusting_the_sound_faces_less_never_tightens_a_bound(bounds, site):
    exact = {r["face"]: r["sigma_m"] for r in bounds.face_bounds(site, (0.0, 0.0), False, 3)}
    loose = {r["face"]: r["sigma_m"] for r in bounds.face_bounds(site, LOOSE, False, 3)}
    assert exact.keys() == loose.keys()
    assert all(loose[f] >= exact[f] * (1 - 1e-6) for f in exact)
    assert any(loose[f] > 1.2 * exact[f] for f in exact)  # and the tolerance matters somewhere
    placed = bounds.bound(site, (0.0, 0.0), known_drift=False)
    placed_loose = bounds.bound(site, LOOSE, known_drift=False)
    assert np.trace(placed_loose["cov_xy"]) >= np.trace(placed["cov_xy"]) * (1 - 1e-6)
    known_drift = bounds.bound(site, (0.0, 0.0), known_drift=True)
    assert np.trace(known_drift["cov_xy"]) <= np.trace(placed["cov_xy"]) * (1 + 1e-6)
    # the plan moved to where the walls were built tells the estimator more, never less (here,
    # where walls built off plan hold the walk, far more)
    twin = bounds.bound(site, (0.0, 0.0), known_drift=False, twin=True)
    assert np.trace(twin["cov_xy"]) < 0.8 * np.trace(placed["cov_xy"])
    assert twin["yaw_deg"] <= placed["yaw_deg"] * (1 + 1e-6)
