"""Geometry read straight from IFC entities, without the geometry kernel: placements (cached),
polylines, the bodies of openings and rooms when they are extruded polygons or faceted breps
(exact, and far cheaper than the kernel), and space boundary surfaces. In the file's units."""

from __future__ import annotations

import functools
import math

import ifcopenshell.util.placement
import numpy as np
import shapely



def clear_cache() -> None:
    """Forget the placements read so far (one model at a time: each import starts cold)."""
    _a2p.cache_clear()


def axis2placement(placement) -> np.ndarray:
    """ifcopenshell's get_axis2placement (read-only), computed once per distinct value: the
    items of a model repeat most of them (Duplex: 79 values in 242 placements), and the
    matrix costs ten times its key."""
    location = placement.Location
    if not placement.is_a("IfcAxis2Placement3D") or not location.is_a("IfcCartesianPoint"):
        return ifcopenshell.util.placement.get_axis2placement(placement)
    axis, ref = placement.Axis, placement.RefDirection
    values = (location.Coordinates, axis.DirectionRatios if axis else None, ref.DirectionRatios if ref else None)
    return _a2p(repr(values), *values)


@functools.lru_cache(maxsize=4096)
def _a2p(spelling: str, location: tuple, axis: tuple | None, ref: tuple | None) -> np.ndarray:
    """`spelling`, the values' repr, keeps -0.0 and 0.0 apart, which tuple equality does not."""
    z = np.array(axis or (0, 0, 1), dtype=float)
    if not np.linalg.norm(z) > 0:
        raise ValueError(f"placement axis {axis} has no direction")
    z /= np.linalg.norm(z)
    # IFC allows a RefDirection that is not perpendicular to the Axis: its projection onto the
    # plane across the axis is the x axis (as geometry kernels take it), so the frame is rigid.
    # An Axis without one breaks IFC's rule that both or neither be given: x is then what
    # ifcopenshell's kernel takes (mapping/IfcAxis2Placement3D.cpp), so that a body read here
    # and one the kernel reads in the same file agree: (1, 0, 0) projected, unless
    # acos(Axis . (1, 0, 0)) is within 1e-5 of 0 or undefined, on the Axis as written (not
    # normalised), then (0, 0, 1); its matrix for an Axis along -x is degenerate
    along_x = axis is not None and ref is None and not (-1.0 <= float(axis[0]) < math.cos(1e-5))
    x = np.array(ref if ref else (0.0, 0.0, 1.0) if along_x else (1.0, 0.0, 0.0), dtype=float)
    x = x - (x @ z) * z
    if not np.linalg.norm(x) > 1e-12:
        raise ValueError(f"placement RefDirection {ref} is along its axis {axis}")
    M = ifcopenshell.util.placement.a2p(location, z, x / np.linalg.norm(x))
    M.flags.writeable = False
    return M


def body_items(element) -> list:
    """The items of an element's body if all are extrusions or faceted breps, else []."""
    representation = element.Representation
    if representation is None:
        return []
    bodies = [r for r in representation.Representations if r.RepresentationIdentifier == "Body"]
    if len(bodies) != 1:
        return []
    items = list(bodies[0].Items)
    return items if all(i.is_a("IfcExtrudedAreaSolid") or i.is_a("IfcFacetedBrep") for i in items) else []


def _profile_points(profile) -> np.ndarray | None:
    """The outline of a rectangle or polyline profile, in its own 2-D coordinates."""
    if profile.is_a("IfcRectangleProfileDef"):
        x, y = profile.XDim / 2, profile.YDim / 2
        points = np.array([[-x, -y], [x, -y], [x, y], [-x, y]], dtype=float)
    elif profile.is_a() == "IfcArbitraryClosedProfileDef":
        points = curve_points(profile.OuterCurve)
        if points is None:
            return None
        points = points[:, :2]
    else:
        return None
    position = getattr(profile, "Position", None)
    if position is not None:
        x = np.asarray(position.RefDirection.DirectionRatios[:2], dtype=float) if position.RefDirection else np.array([1.0, 0.0])
        if not np.linalg.norm(x) > 0:
            return None  # (left to the geometry kernel, which warns)
        x /= np.linalg.norm(x)
        R = np.column_stack([x, [-x[1], x[0]]])
        points = points @ R.T + np.asarray(position.Location.Coordinates[:2], dtype=float)
    return points


def curve_points(curve) -> np.ndarray | None:
    """The vertices of a polyline-like curve (polyline, indexed poly curve of straight
    segments, composite of those), without the closing repeat; None for curved ones."""
    if curve.is_a("IfcPolyline"):
        points = _coordinates(curve.Points)
    elif curve.is_a("IfcIndexedPolyCurve"):
        if curve.Segments and any(not s.is_a("IfcLineIndex") for s in curve.Segments):
            return None
        points = np.array(curve.Points.CoordList, dtype=float)
        if curve.Segments:
            order = [i - 1 for s in curve.Segments for i in s.wrappedValue]
            points = points[order]
    elif curve.is_a("IfcCompositeCurve"):
        parts = []
        for segment in curve.Segments:
            part = curve_points(segment.ParentCurve)
            if part is None:
                return None
            parts.append(part if segment.SameSense else part[::-1])
        points = np.concatenate(parts)
    else:
        return None
    if points.shape[1] == 2:
        points = np.column_stack([points, np.zeros(len(points))])
    keep = np.ones(len(points), dtype=bool)
    keep[1:] = np.linalg.norm(np.diff(points, axis=0), axis=1) > 1e-9  # repeated vertices
    points = points[keep]
    # np.allclose's test with its default tolerances, written out: allclose costs 50 us.
    if len(points) > 1 and (np.abs(points[0] - points[-1]) <= 1e-8 + 1e-5 * np.abs(points[-1])).all():
        points = points[:-1]
    return points


def _coordinates(points) -> np.ndarray:
    """The coordinates of IfcCartesianPoints (N x 2 or 3): their only attribute, read by
    index at a third of the cost of by name."""
    return np.array([p[0] for p in points], dtype=float)


def prism(solid) -> tuple[np.ndarray, np.ndarray] | None:
    """A closed triangle mesh (vertices in the item's parent frame, file units) of an
    extrusion of a polygon profile; None for other profiles."""
    profile = _profile_points(solid.SweptArea)
    if profile is None or len(profile) < 3:
        return None
    polygon = shapely.Polygon(profile)
    if not polygon.is_valid or polygon.area <= 0:
        return None
    n = len(profile)
    direction = np.asarray(solid.ExtrudedDirection.DirectionRatios, dtype=float)
    length = float(np.linalg.norm(direction))
    if not (length > 0 and solid.Depth > 0 and np.isfinite(direction).all()):
        return None  # degenerate: left to the geometry kernel, which warns and skips it
    direction = direction / length * solid.Depth
    bottom = np.column_stack([profile, np.zeros(n)])
    V = np.vstack([bottom, bottom + direction])
    caps = _corner_ids(shapely.constrained_delaunay_triangles(polygon), profile, np.arange(n))
    i = np.arange(n)
    j = (i + 1) % n
    T = np.vstack([caps, caps + n, np.column_stack([i, j, j + n]), np.column_stack([i, j + n, i + n])])
    if solid.Position is not None:
        M = axis2placement(solid.Position)
        V = V @ M[:3, :3].T + M[:3, 3]
    return V, T


def brep(brep) -> tuple[np.ndarray, np.ndarray] | None:
    """A closed triangle mesh (file units, the item's frame) of a faceted brep whose faces
    are polygons without holes; None otherwise."""
    loops = []
    for face in brep.Outer.CfsFaces:
        bounds = face.Bounds
        if len(bounds) != 1 or not (bound := bounds[0].Bound).is_a("IfcPolyLoop"):
            return None
        loop = _coordinates(bound.Polygon)
        loops.append(loop if bounds[0].Orientation else loop[::-1])
    # Shared corners get one index, so that the faces' common edges are cut at one point.
    V, index = np.unique(np.concatenate(loops), axis=0, return_inverse=True)
    ids = np.split(index.reshape(-1), np.cumsum([len(loop) for loop in loops])[:-1])
    triangles = [i[None, :] for i in ids]  # the triangles' own; the others' below
    # Each polygon is laid flat in its own plane and triangulated there, those with as many
    # corners together: numpy's and shapely's calls cost more than their work on one.
    for n in {len(loop) for loop in loops} - {3}:
        which = [i for i, loop in enumerate(loops) if len(loop) == n]
        stack = np.array([loops[i] for i in which])
        axes = np.linalg.svd(stack - stack.mean(axis=1, keepdims=True))[2][:, :2]  # the loops' planes
        flat = stack @ axes.transpose(0, 2, 1)
        polygons = shapely.polygons(flat)
        if not shapely.is_valid(polygons).all() or (shapely.area(polygons) <= 0).any():
            return None
        for i, points, cdt in zip(which, flat, shapely.constrained_delaunay_triangles(polygons)):
            triangles[i] = _corner_ids(cdt, points, ids[i])
    return V, np.concatenate(triangles)


def _corner_ids(triangles, points: np.ndarray, ids: np.ndarray) -> np.ndarray:
    """The corners of `triangles` (a constrained Delaunay triangulation of a polygon of
    vertices `points`, N x 2) as the `ids` of those vertices."""
    lookup = {p: i for p, i in zip(map(tuple, points.tolist()), ids.tolist())}
    corners = shapely.get_coordinates(triangles).reshape(-1, 4, 2)[:, :3]
    return np.array([[lookup[tuple(c)] for c in triangle] for triangle in corners.tolist()], dtype=int)


def surface_points(surface) -> np.ndarray | None:
    """The outer loop of a boundary surface in its space's coordinates (file units)."""
    if surface.is_a("IfcCurveBoundedPlane"):
        loop = curve_points(surface.OuterBoundary)
        if loop is None:
            return None
        M = axis2placement(surface.BasisSurface.Position)
        return loop @ M[:3, :3].T + M[:3, 3]
    if surface.is_a("IfcSurfaceOfLinearExtrusion") and surface.SweptCurve.is_a("IfcArbitraryOpenProfileDef"):
        line = curve_points(surface.SweptCurve.Curve)
        if line is None:
            return None
        direction = np.asarray(surface.ExtrudedDirection.DirectionRatios, dtype=float)
        if not np.linalg.norm(direction) > 0:
            return None
        direction = direction / np.linalg.norm(direction) * surface.Depth
        loop = np.vstack([line, line[::-1] + direction])
        M = axis2placement(surface.Position)
        return loop @ M[:3, :3].T + M[:3, 3]
    return None
