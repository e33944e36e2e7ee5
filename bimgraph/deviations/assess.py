"""From the graph's landmarks to the site team's list: every observed face with its deviation
and status, faces that should have been seen but never were, big planes the model lacks.
Pure computation, no I/O.

The graph associates a landmark with a face only when it fits the plan within its gates, so a
wall built 10 cm off may stay unassociated there, and one landmark stands for a whole wall
plane that the plan splits into faces per room; for the report, the faces left unmeasured are
matched to landmarks by proximity (parallel, close, overlapping), and measured the same way.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import replace

import numpy as np
import shapely

from bimgraph.bim.planemap import BimFace, PlaneMap
from bimgraph.config import DeviationConfig
from bimgraph.deviations.estimate import (
    Deviation,
    DeviationReport,
    Explanation,
    FaceReport,
    ObservedPlane,
    RivalAlignment,
    UnplannedPlane,
    classify,
    face_deviation,
    mixed,
)
from bimgraph.deviations.visibility import face_shape
from bimgraph.deviations.widths import room_widths, wall_thicknesses
from bimgraph.geometry import inverse, normal_angle_deg, plane_frame, plane_to_frame, point_plane_distance


def _overlap(face_2d, points_B: np.ndarray, cfg: DeviationConfig) -> bool:
    """The landmark's extent covers at least `match_min_overlap_m2` of the face (given by
    `face_shape`); with fewer than three extent points, its centre lies within
    `match_margin_m` of the face."""
    shape, origin, basis = face_2d
    xy = (points_B - origin) @ basis
    if len(xy) >= 3:
        hull = shapely.MultiPoint(xy).convex_hull
        return hull.intersection(shape).area >= cfg.match_min_overlap_m2
    return len(xy) > 0 and shape.distance(shapely.Point(xy.mean(axis=0))) <= cfg.match_margin_m


def _coplanar_in_plan(a: BimFace, b: BimFace, cfg: DeviationConfig) -> bool:
    """Whether the plan puts face `b` on face `a`'s plane: every corner of `b` within
    `plan_coplanar_m` of it (one wall's faces in neighbouring rooms). The faces it is asked
    about face the way `a` does already (both pass a plane's tilt test, or `a` is the face the
    graph matched that plane to)."""
    return bool((np.abs(point_plane_distance(np.asarray(b.polygon, dtype=float), a.plane)) <= cfg.plan_coplanar_m).all())


def proximity_candidates(faces: Sequence[BimFace], planes: Sequence[ObservedPlane], T_S_B: np.ndarray,
                         cfg: DeviationConfig) -> dict[str, list[ObservedPlane]]:
    """For each face, every plane that is tilted less than `match_max_tilt_deg` from it, passes
    within `match_max_offset_m` of its centre and overlaps it (`_overlap`), and lies on it
    rather than on another face: a plane serves the faces the plan puts on one plane with its
    own face (the one the graph matched it to, else the nearest of those it passes), one wall's
    sections in neighbouring rooms, not a face a few centimetres behind (a party wall behind its
    furring is hidden by it; walks through the Duplex sample model flagged four sound faces
    5.6-16.8 cm off so). A face the plan sets more than `plan_coplanar_m` off its neighbour's
    plane is then not measured by that neighbour's landmark: in view, it is listed as possibly
    not built rather than measured by the step."""
    T_B_S = inverse(T_S_B)
    normals = np.array([face.normal for face in faces], dtype=float).reshape(-1, 3)
    centres = np.array([face.centre for face in faces], dtype=float).reshape(-1, 3)
    shapes: dict[int, tuple] = {}  # (made for the faces a plane passes: a building's map has thousands)
    by_id = {face.id: face for face in faces}
    candidates: dict[str, list[ObservedPlane]] = {}
    for plane in planes:
        extent_B = plane.extent_in(T_B_S)
        if len(extent_B) == 0:
            continue
        plane_B = plane_to_frame(plane.plane_S(), T_S_B)
        distance = np.abs(point_plane_distance(centres, plane_B))
        near = []
        passing = (normal_angle_deg(normals, plane_B[:3]) <= cfg.match_max_tilt_deg) & (distance <= cfg.match_max_offset_m)
        for i in np.flatnonzero(passing):
            if i not in shapes:
                shapes[i] = face_shape(faces[i])
            if _overlap(shapes[i], extent_B, cfg):
                near.append(i)
        own = by_id.get(plane.face_id) or (faces[min(near, key=lambda i: distance[i])] if near else None)
        for face in (faces[i] for i in near):
            if _coplanar_in_plan(own, face, cfg):
                candidates.setdefault(face.id, []).append(plane)
    return candidates


def _one_plane(a: UnplannedPlane, extent_a: np.ndarray, b: UnplannedPlane, extent_b: np.ndarray,
               cfg: DeviationConfig) -> bool:
    """Whether two unplanned planes are one (two landmarks of one partition, seen on two
    visits): parallel, close and overlapping by the tests a face's candidates pass."""
    if normal_angle_deg(a.plane_B[:3], b.plane_B[:3]) > cfg.match_max_tilt_deg or b.centre_B is None:
        return False
    if abs(float(point_plane_distance(b.centre_B, a.plane_B))) > cfg.match_max_offset_m:
        return False
    origin, basis = plane_frame(a.plane_B)
    return len(extent_a) >= 3 and _overlap((shapely.MultiPoint((extent_a - origin) @ basis).convex_hull, origin, basis),
                                           extent_b, cfg)


def _is_vertical(plane_B: np.ndarray, cfg: DeviationConfig) -> bool:
    return abs(90.0 - normal_angle_deg(plane_B[:3], np.array([0.0, 0.0, 1.0]))) <= cfg.vertical_tolerance_deg


def contest(faces: Sequence[tuple[FaceReport, Deviation, Deviation | None]], probability: float,
            cfg: DeviationConfig) -> list[Explanation]:
    """The two ways the data explain the faces the two alignments judge otherwise, as
    `Explanation`s, the likelier first: `faces` are the measured faces with their deviations
    under the estimate's alignment and under the rival's (None where the rival has none), which
    has `probability`. A face is contested where it deviates under one and not under the
    other; none contested, none listed. (Their report's status, over both, is mostly not enough
    evidence: what the data do say, "one of these walls is off by about this much", is here.)"""
    under: tuple[list[FaceReport], list[FaceReport]] = ([], [])
    for entry, own, under_rival in faces:
        if under_rival is None:
            continue
        statuses = [classify(dev, entry.n_keyframes, cfg) for dev in (own, under_rival)]
        if statuses[0] == statuses[1] or "deviating" not in statuses:
            continue
        for side, status, dev in zip(under, statuses, (own, under_rival)):
            if status == "deviating":
                side.append(replace(entry, status="deviating", deviation=dev))
    if not any(under):
        return []
    explanations = [Explanation(1.0 - probability, tuple(under[0])), Explanation(probability, tuple(under[1]))]
    return sorted(explanations, key=lambda e: -e.probability)


def assess(plane_map: PlaneMap, planes: Sequence[ObservedPlane], T_S_B: np.ndarray, cfg: DeviationConfig,
           expected_views: Mapping[str, int] | None = None, rival: RivalAlignment | None = None) -> DeviationReport:
    """The deviation report. `planes` are all the graph's landmarks; `expected_views` counts,
    per face id, the keyframes at which the face should have been in view (see
    `visibility.expected_view_counts`); without it no face is listed as possibly not built.
    With the robust alignment's `rival`, each face's sigmas cover both alignments (`mixed`), and
    the faces they judge otherwise are listed by the report's `contested` (`contest`)."""
    report = DeviationReport(cfg.tolerance_m, cfg.tilt_tolerance_deg, cfg.k_sigma)
    faces = {f.id: f for f in plane_map.faces}
    expected = expected_views or {}

    # face id -> (its report, the rank of its evidence, its deviations under the estimate's
    # alignment and under the rival's, unmixed)
    measured: dict[str, tuple[FaceReport, tuple, tuple[Deviation, Deviation | None]]] = {}

    def measure(face: BimFace, plane: ObservedPlane, how: str):
        dev = own = face_deviation(face, plane, T_S_B)
        under_rival = None
        if rival is not None and plane.landmark in rival.planes:
            under_rival = face_deviation(face, rival.planes[plane.landmark], rival.T_S_B)
            dev = mixed(own, under_rival, rival.probability)
        entry = FaceReport(face.id, face.wall_guid, face.wall_name, face.storey, classify(dev, plane.n_keyframes, cfg),
                           plane.n_keyframes, dev, plane.landmark, how, expected.get(face.id, 0), face.centre, face.area)
        # Two landmarks on one face (two visits, or a glimpse beside the wall's landmark): the
        # better evidence measures it, seen in enough keyframes first, then the smaller sigma
        sigma = dev.offset_sigma_m if dev.measurable and np.isfinite(dev.offset_sigma_m) else np.inf
        rank = (plane.n_keyframes >= cfg.min_keyframes, -sigma)
        if face.id not in measured or rank > measured[face.id][1]:
            measured[face.id] = (entry, rank, (own, under_rival))

    for plane in planes:
        if plane.face_id is not None and plane.face_id in faces:
            measure(faces[plane.face_id], plane, "graph")
    candidates = proximity_candidates(plane_map.faces, planes, T_S_B, cfg)
    for face_id, near in candidates.items():
        if face_id in measured and measured[face_id][0].matched_by == "graph":
            continue
        for plane in near:
            measure(faces[face_id], plane, "proximity")
    report.faces = [measured[f.id][0] for f in plane_map.faces if f.id in measured]
    by_landmark = {p.landmark: p for p in planes}
    report.widths = room_widths(plane_map.faces, report.faces, by_landmark, T_S_B, cfg)
    report.thicknesses = wall_thicknesses(plane_map.faces, report.faces, by_landmark, T_S_B, cfg)
    if rival is not None and rival.probability >= cfg.contest_min_probability:
        report.contested = contest([(measured[f.id][0], *measured[f.id][2]) for f in plane_map.faces if f.id in measured],
                                   rival.probability, cfg)

    for face in plane_map.faces:
        seen_from = expected.get(face.id, 0)
        if face.id not in measured and seen_from >= cfg.min_expected_keyframes:
            report.faces.append(FaceReport(face.id, face.wall_guid, face.wall_name, face.storey, "possibly_not_built",
                                           expected_keyframes=seen_from, centre=face.centre, area_m2=face.area))

    # a plane that passes some face's tests is that face's (measuring it or not), not unplanned
    near_a_face = {p.landmark for near in candidates.values() for p in near}
    T_B_S = inverse(T_S_B)
    unplanned = []
    for plane in planes:
        if (plane.face_id in faces or plane.landmark in near_a_face or plane.area_m2 < cfg.unplanned_min_area_m2
                or plane.n_keyframes < cfg.min_keyframes):
            continue
        plane_B = plane_to_frame(plane.plane_S(), T_S_B)
        if cfg.unplanned_vertical_only and not _is_vertical(plane_B, cfg):
            continue
        extent_B = plane.extent_in(T_B_S)
        unplanned.append((UnplannedPlane(plane.landmark, plane_B, extent_B.mean(axis=0) if len(extent_B) else None,
                                         plane.area_m2, plane.n_keyframes), extent_B))
    # landmarks of one unplanned plane (seen on two visits, which the SLAM association did not
    # join) are listed once: the best-seen one, with the keyframes of all
    listed: list[tuple[UnplannedPlane, np.ndarray]] = []
    for entry, extent in sorted(unplanned, key=lambda e: -e[0].n_keyframes):
        same = next((i for i, (kept, kept_extent) in enumerate(listed) if _one_plane(kept, kept_extent, entry, extent, cfg)), None)
        if same is None:
            listed.append((entry, extent))
        else:
            kept, kept_extent = listed[same]
            listed[same] = (replace(kept, n_keyframes=kept.n_keyframes + entry.n_keyframes), kept_extent)
    report.unplanned = [entry for entry, _ in listed]
    return report
