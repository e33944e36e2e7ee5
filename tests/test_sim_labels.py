"""Planes extracted from a simulated depth sequence get ground truth from the label images."""

from pathlib import Path

import numpy as np
import pytest

from bimgraph.config import Config
from bimgraph.errors import InputError
from bimgraph.geometry import normal_angle_deg, plane_from_frame, point_plane_distance
from bimgraph.planes.sequence import extract_into
from bimgraph.sequence.format import load_sequence
from bimgraph.sequence.groundtruth import load_groundtruth
from bimgraph.sim.simulate import SimOptions, simulate


def test_extracted_planes_are_labelled_with_their_as_built_element(tmp_path):
    root = tmp_path / "depth"
    # Per-pixel depth noise only, so that a right label is told from a wrong one by tight
    # bounds: with the sensor's systematic error, a far plane's normal errs by up to some
    # degrees (tests/test_sim_calibration.py).
    cfg = Config()
    cfg = cfg.model_copy(update={"depth_noise": cfg.depth_noise.without_systematic()})
    simulate(SimOptions(output=root, scenario="office", keyframes=12, seed=3, sensor="depth"), cfg)
    seq = load_sequence(root)
    extract_into(seq, seq.meta.camera, cfg)
    seq, gt = load_sequence(root), load_groundtruth(root)
    elements = gt.as_built["elements"]
    by_name = {e["name"]: e for e in elements}
    labelled = 0
    for kf, truth, T_B_C in zip(seq.keyframes, gt.observations, gt.T_B_C):
        assert len(truth) == len(kf.planes)
        for obs, record in zip(kf.planes, truth):
            if record["element"] is None:
                continue
            labelled += 1
            element_B = np.asarray(by_name[record["element"]]["plane"])
            plane_B = plane_from_frame(obs.plane, T_B_C)
            # The label is right: the detected plane lies on that as-built element, same side.
            assert normal_angle_deg(plane_B[:3], element_B[:3]) < 2.0
            centre_B = T_B_C[:3, :3] @ np.asarray(obs.centre) + T_B_C[:3, 3]
            assert abs(point_plane_distance(centre_B, element_B)) < 0.05
    assert labelled >= 12
    # A label image gone: one line before anything is written (it was an AttributeError).
    before = (root / "keyframes.jsonl").read_bytes()
    label = root / "groundtruth" / "labels" / Path(seq.keyframes[5].depth).name
    label.unlink()
    with pytest.raises(InputError, match=f"{label}: no such label image"):
        extract_into(load_sequence(root), seq.meta.camera, cfg)
    assert (root / "keyframes.jsonl").read_bytes() == before
