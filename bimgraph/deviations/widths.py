"""A room's clear width between two of its walls facing each other, and a wall's thickness
between its two sides, as built against plan, with their uncertainty. Pure maths, no I/O.

Each wall's offset is measured against the alignment (`estimate.face_deviation`); the width
between two facing walls is the planned one less both offsets (each positive into the room),
and its uncertainty comes from the joint marginal of both landmarks, their anchors and the
extrinsic, both faces' own plane-to-BIM factors taken out. The extrinsic's position along the
walls' normal moves one offset up and the other down by as much: it cancels, and so does most
of its uncertainty. Where the alignment itself is in doubt (two parallel walls alone place the
walk, one of them built off plan: a contest), the walls' verdicts are too, but the width
between them is measured as surely as anywhere: "the room is 6 cm narrower than planned".
A wall's thickness is the planned one plus both offsets, alike; its two sides are seen from
two rooms, so its sigma carries how well the walk places one room against the other.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from bimgraph.bim.planemap import BimFace
from bimgraph.config import DeviationConfig
from bimgraph.deviations.estimate import (
    Deviation,
    FaceReport,
    ObservedPlane,
    Status,
    classify,
    deviation_terms,
    plane_to_bim_residual,
    without_own_factor,
)
from bimgraph.geometry import normal_angle_deg, point_plane_distance

# tangent widths of a plane's keys (E, X_anchor, L), and where each starts in its 15 columns
_KEY_DIMS = (6, 6, 3)
_KEY_STARTS = np.concatenate([[0], np.cumsum(_KEY_DIMS)])


@dataclass(frozen=True, kw_only=True)
class Distance:
    """The distance between two opposite faces (`faces`), as planned and as built (m), with one
    sigma, the fewer keyframes of the two faces, and a status against the offset tolerance."""

    faces: tuple[str, str]
    planned_m: float
    built_m: float
    sigma_m: float
    n_keyframes: int
    status: Status


@dataclass(frozen=True, kw_only=True)
class Width(Distance):
    """The clear width of room `space` (its IfcSpace GlobalId and name) between two of its
    walls' faces."""

    space_guid: str
    space_name: str


@dataclass(frozen=True, kw_only=True)
class Thickness(Distance):
    """A wall's thickness (its IfcWall GlobalId and name) between two faces on its two sides."""

    wall_guid: str
    wall_name: str


def _opposite(a: BimFace, b: BimFace, cfg: DeviationConfig) -> bool:
    """Whether faces `a` and `b` are parallel with opposite normals within
    `width_max_angle_deg`, both near vertical, and their extents along them overlap by
    `width_min_overlap_m`."""
    n_a, n_b = np.asarray(a.normal, dtype=float), np.asarray(b.normal, dtype=float)
    if normal_angle_deg(n_a, -n_b) > cfg.width_max_angle_deg:
        return False
    along = np.cross([0.0, 0.0, 1.0], n_a)
    if np.linalg.norm(along) < 0.9:  # (a sloping face, more than 25 degrees off vertical)
        return False
    along /= np.linalg.norm(along)
    span_a, span_b = np.asarray(a.polygon) @ along, np.asarray(b.polygon) @ along
    return min(span_a.max(), span_b.max()) - max(span_a.min(), span_b.min()) >= cfg.width_min_overlap_m


def _arrangement(a: BimFace, b: BimFace) -> int:
    """+1 where each face's centre lies in front of the other face (where its normal points:
    two walls of a room facing each other), -1 where each lies behind the other (the two sides
    of a wall), else 0."""
    between = np.asarray(b.centre) - np.asarray(a.centre)
    in_front_of_a, in_front_of_b = between @ np.asarray(a.normal) > 0, between @ np.asarray(b.normal) < 0
    return 0 if in_front_of_a != in_front_of_b else (1 if in_front_of_a else -1)


def _facing(a: BimFace, b: BimFace, cfg: DeviationConfig) -> bool:
    """Whether `b` faces `a` across the room: opposite (`_opposite`) and each in front of the
    other (not the two sides of a stub wall standing in the room, nor the arms of a U-shaped
    one across its notch)."""
    return _arrangement(a, b) == 1 and _opposite(a, b, cfg)


def _two_sides(a: BimFace, b: BimFace, cfg: DeviationConfig) -> bool:
    """Whether `a` and `b` are the two sides of one wall: its faces, opposite (`_opposite`),
    each behind the other."""
    return a.wall_guid == b.wall_guid and _arrangement(a, b) == -1 and _opposite(a, b, cfg)


def _scatter(block: np.ndarray, keys: tuple[int, int, int], columns: Mapping[int, slice], dim: int) -> np.ndarray:
    """A matrix over one plane's (E, X_anchor, L) as one over the pair's joint variables."""
    out = np.zeros((len(block), dim))
    for key, a, b in zip(keys, _KEY_STARTS, _KEY_STARTS[1:]):
        out[:, columns[key]] += block[:, a:b]
    return out


def distance_between(a: BimFace, b: BimFace, plane_a: ObservedPlane, plane_b: ObservedPlane,
                     T_S_B: np.ndarray) -> tuple[float, float, float] | None:
    """(planned, built, sigma) of the distance between opposite faces `a` and `b` (a room's
    width where they face each other, a wall's thickness where they are its two sides),
    measured by their landmarks; None where taking their own factors out leaves it
    unmeasured."""
    side = _arrangement(a, b)
    keys = list(dict.fromkeys(plane_a.keys + plane_b.keys))
    dims = {key: d for plane in (plane_a, plane_b) for key, d in zip(plane.keys, _KEY_DIMS)}
    starts = np.concatenate([[0], np.cumsum([dims[key] for key in keys])])
    columns = {key: slice(int(s), int(e)) for key, s, e in zip(keys, starts, starts[1:])}
    dim = int(starts[-1])
    cov = plane_a.joint(keys)
    rows, errors = [], []
    for plane in (plane_a, plane_b):
        if plane.bim_factor is not None:
            A, e_w = plane.bim_factor
            rows.append(_scatter(A, plane.keys, columns, dim))
            errors.append(e_w)
    shift = np.zeros(dim)
    if rows:
        loo = without_own_factor(cov, (np.vstack(rows), np.concatenate(errors)))
        if loo is None:
            return None
        shift, cov = loo
    change, gradient = 0.0, np.zeros(dim)
    for face, plane in ((a, plane_a), (b, plane_b)):
        e, J = plane_to_bim_residual(face, plane, T_S_B)
        J = _scatter(J, plane.keys, columns, dim)
        y, H = deviation_terms(e + J @ shift, face)
        # (an offset out of the wall, into the room, narrows the room and thickens the wall)
        change -= side * y[0]
        gradient -= side * H[0] @ J
    variance = float(gradient @ cov @ gradient)
    if not variance > 0:  # (the two factors were all that placed it: rounding left nothing)
        return None
    planned = side * 0.5 * (float(point_plane_distance(np.asarray(b.centre), a.plane))
                            + float(point_plane_distance(np.asarray(a.centre), b.plane)))
    return planned, planned + float(change), float(np.sqrt(variance))


def _measured_pairs(faces: Sequence[BimFace], measured: Sequence[FaceReport], planes: Mapping[int, ObservedPlane],
                    T_S_B: np.ndarray, pair: Callable[[BimFace, BimFace], bool], cfg: DeviationConfig):
    """Every pair of measured wall faces that `pair` accepts, each by a landmark of its own
    from one solve: the two faces and their `Distance` (`distance_between`)."""
    by_id = {face.id: face for face in faces}
    reports = [r for r in measured if r.landmark is not None and by_id[r.face_id].kind == "wall"]
    for i, ra in enumerate(reports):
        for rb in reports[i + 1:]:
            a, b = by_id[ra.face_id], by_id[rb.face_id]
            pa, pb = planes[ra.landmark], planes[rb.landmark]
            if ra.landmark == rb.landmark or pa.joint is None or pa.joint is not pb.joint or not pair(a, b):
                continue
            if (measured_distance := distance_between(a, b, pa, pb, T_S_B)) is None:
                continue
            planned, built, sigma = measured_distance
            n_keyframes = min(ra.n_keyframes, rb.n_keyframes)
            # (an offset without a tilt: the faces' rule, its tilt term left out)
            status = classify(Deviation(built - planned, sigma, 0.0, 0.0), n_keyframes, cfg)
            yield a, b, Distance(faces=(a.id, b.id), planned_m=planned, built_m=built, sigma_m=sigma,
                                 n_keyframes=n_keyframes, status=status)


def room_widths(faces: Sequence[BimFace], measured: Sequence[FaceReport], planes: Mapping[int, ObservedPlane],
                T_S_B: np.ndarray, cfg: DeviationConfig) -> list[Width]:
    """Every pair of measured wall faces of one room that face each other (`_facing`) as a `Width`."""
    def pair(a: BimFace, b: BimFace) -> bool:
        return a.space is not None and b.space is not None and a.space.guid == b.space.guid and _facing(a, b, cfg)

    return [Width(**vars(d), space_guid=a.space.guid, space_name=a.space.name)
            for a, _, d in _measured_pairs(faces, measured, planes, T_S_B, pair, cfg)]


def wall_thicknesses(faces: Sequence[BimFace], measured: Sequence[FaceReport], planes: Mapping[int, ObservedPlane],
                     T_S_B: np.ndarray, cfg: DeviationConfig) -> list[Thickness]:
    """Every pair of measured faces on the two sides of one wall (`_two_sides`) as a `Thickness`."""
    return [Thickness(**vars(d), wall_guid=a.wall_guid, wall_name=a.wall_name)
            for a, _, d in _measured_pairs(faces, measured, planes, T_S_B, lambda a, b: _two_sides(a, b, cfg), cfg)]
