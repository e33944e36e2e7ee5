"""The two sensor modes of the simulator agree: planes extracted from simulated depth images
err as much as the planes sensor's detections drawn for the same views, and both as much as
planes fitted to real RGB-D depth (tenths of a degree, about a centimetre at 2-4 m)."""

import numpy as np
import pytest

from bimgraph.config import Config
from bimgraph.planes.extractor import PlaneExtractor
from bimgraph.sequence.format import load_sequence
from bimgraph.sequence.groundtruth import load_groundtruth
from bimgraph.sim.calibration import compare, match_errors
from bimgraph.sim.render import DepthRenderer, add_depth_noise
from bimgraph.sim.simulate import SimOptions, simulate
from bimgraph.sim.world import Element, triangulate

VIEWS, REALISATIONS = 30, 6
# The depth sensor's error is mostly drawn once per frame, so a sample's statistics carry the
# noise of its few hundred frames: measured on other seeds, up to some 15 % pooled over ranges
# and 35 % within a range bin. The calibration itself (scripts/bench_sim.py calibrate on five
# sequences, ~3700 planes) agrees within 10 % pooled and mostly within 25 % per bin.
POOLED_TOLERANCE, BIN_TOLERANCE = 0.25, 0.4


@pytest.fixture(scope="module")
def errors(tmp_path_factory):
    """Errors of planes extracted from depth images of views of a simulated site, each view
    rendered and noised several times (independent systematic errors)."""
    root = tmp_path_factory.mktemp("calibration")
    cfg = Config()
    simulate(SimOptions(output=root, scenario="site", sensor="planes", keyframes=2 * VIEWS, seed=11), cfg)
    seq, gt = load_sequence(root), load_groundtruth(root)
    elements = [Element(e["name"], e["kind"], e["face_id"], np.array(e["plane"]), np.array(e["polygon"]),
                        [np.array(h) for h in e["holes"]]) for e in gt.as_built["elements"]]
    mesh = triangulate(elements)
    renderer = DepthRenderer(mesh.vertices, mesh.triangles, mesh.element)
    extractor = PlaneExtractor(seq.meta.camera, cfg.planes, cfg.depth_noise)
    rng = np.random.default_rng(0)
    extractions, truths, poses = [], [], []
    for T_B_C in gt.T_B_C[::2]:
        depth, ids, cos_incidence = renderer.render(seq.meta.camera, T_B_C, with_incidence=True)
        for _ in range(REALISATIONS):
            extractions.append(extractor.extract(add_depth_noise(depth, cfg.depth_noise, rng, cos_incidence)))
            truths.append(ids)
            poses.append(T_B_C)
    return match_errors(extractions, truths, poses, np.array([e.plane for e in elements]), purity=0.8)


def test_planes_sensor_matches_planes_extracted_from_depth(errors):
    assert len(errors.range_m) >= 450
    stats = compare(errors, Config().sim.observe, np.random.default_rng(0), draws=20, bins=((0.0, 3.0), (3.0, 8.0)))
    assert len(stats) == 3
    for b, tolerance in zip(stats, (BIN_TOLERANCE, BIN_TOLERANCE, POOLED_TOLERANCE)):
        for name, (median, p90) in b.ratios().items():
            assert abs(median - 1) < tolerance and abs(p90 - 1) < tolerance, (b.lo_m, b.hi_m, b.count, name, median, p90)


def test_depth_sensor_errs_like_a_real_one(errors):
    """Plane fits to real RGB-D depth at 2-4 m: about 0.2-1 degree and 0.5-2 cm (median and
    90th percentile span those); white pixel noise alone would give a hundredth of that."""
    mid = (errors.range_m >= 2) & (errors.range_m < 4)
    normal, offset_cm = errors.normal_deg[mid], 100 * np.abs(errors.offset_m[mid])
    assert 0.15 < np.median(normal) < 0.6 and 0.5 < np.percentile(normal, 90) < 2.0
    assert 0.3 < np.median(offset_cm) < 1.2 and 1.0 < np.percentile(offset_cm, 90) < 4.0
