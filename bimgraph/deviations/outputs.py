"""The one call `bimgraph run` makes at the end of a run: deviations measured, listed and
written (deviations.json, deviations.csv, deviations.bcf) into the output folder."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from bimgraph.bim.planemap import PlaneMap
from bimgraph.config import DeviationConfig
from bimgraph.deviations.assess import assess
from bimgraph.deviations.bcf import BCF_FILE, write_bcf
from bimgraph.deviations.estimate import ObservedPlane, RivalAlignment
from bimgraph.deviations.report import CSV_FILE, JSON_FILE, DeviationsFile, write_deviations
from bimgraph.deviations.visibility import expected_view_counts
from bimgraph.sequence.format import Camera

DEVIATION_FILES = (JSON_FILE, CSV_FILE, BCF_FILE)


def write_deviation_outputs(out_dir: Path, plane_map: PlaneMap, planes: Sequence[ObservedPlane], T_B_S: np.ndarray,
                            T_B_C: Sequence[np.ndarray], camera: Camera | None, cfg: DeviationConfig,
                            project_name: str = "bimgraph as-built deviations",
                            rival: RivalAlignment | None = None) -> DeviationsFile:
    """Assess and write. Without a camera (a sequence that names none) no face can be said to
    have been in view, so none is listed as possibly not built. `rival`: see `assess`."""
    expected = None
    if camera is not None:
        expected = expected_view_counts(plane_map, np.asarray(T_B_C), camera.K, camera.width, camera.height, cfg)
    report = assess(plane_map, planes, np.linalg.inv(T_B_S), cfg, expected, rival)
    out_dir = Path(out_dir)
    data = write_deviations(report, out_dir)
    write_bcf(data, plane_map, out_dir / BCF_FILE, cfg, project_name)
    return data
