"""The one call `bimgraph run` makes at the end of a run: deviations measured, listed and
written (deviations.json, deviations.csv, deviations.bcf) into the output folder; and the
same report without files, for the Python API."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from bimgraph.bim.planemap import PlaneMap
from bimgraph.config import DeviationConfig
from bimgraph.deviations.assess import assess
from bimgraph.deviations.bcf import BCF_FILE, write_bcf
from bimgraph.deviations.estimate import DeviationReport, ObservedPlane, RivalAlignment
from bimgraph.deviations.report import CSV_FILE, JSON_FILE, DeviationsFile, write_deviations
from bimgraph.deviations.visibility import expected_view_counts
from bimgraph.sequence.format import Camera

DEVIATION_FILES = (JSON_FILE, CSV_FILE, BCF_FILE)


def deviation_report(plane_map: PlaneMap, planes: Sequence[ObservedPlane], T_B_S: np.ndarray, T_B_C: Sequence[np.ndarray],
                     camera: Camera | None, cfg: DeviationConfig, rival: RivalAlignment | None = None) -> DeviationReport:
    """The deviation report, without files (`to_file` gives it as deviations.json holds it):
    of offline `Results`, `deviation_report(plane_map, results.observed_planes, results.T_B_S,
    results.T_B_C, camera, cfg.deviations, results.rival_alignment)`. Without a camera (a
    sequence that names none) no face can be said to have been in view, so none is listed as
    possibly not built. `rival`: see `assess`."""
    expected = None
    if camera is not None:
        expected = expected_view_counts(plane_map, np.asarray(T_B_C), camera.K, camera.width, camera.height, cfg)
    return assess(plane_map, planes, np.linalg.inv(T_B_S), cfg, expected, rival)


def write_deviation_outputs(out_dir: Path, plane_map: PlaneMap, planes: Sequence[ObservedPlane], T_B_S: np.ndarray,
                            T_B_C: Sequence[np.ndarray], camera: Camera | None, cfg: DeviationConfig,
                            project_name: str = "bimgraph as-built deviations",
                            rival: RivalAlignment | None = None) -> DeviationsFile:
    """`deviation_report`, written."""
    data = write_deviations(deviation_report(plane_map, planes, T_B_S, T_B_C, camera, cfg, rival), Path(out_dir))
    write_bcf(data, plane_map, Path(out_dir) / BCF_FILE, cfg, project_name)
    return data
