"""IFC model -> BIM plane map: every wall's vertical side faces, openings cut out, per room.

Walls are meshed WITHOUT opening subtraction (the boolean cuts dominate: on AC20-FZK-Haus
about 1.8 s with them, 0.14 s without), straight from the schema where their bodies are
extruded polygons or faceted breps, by ifcopenshell's geometry iterator otherwise; each
opening is instead sliced just behind each face and the slice cut out of the face polygon,
which gives the same polygon.
"""

from __future__ import annotations

import time
from collections import Counter
from pathlib import Path
from typing import NamedTuple

import numpy as np
import shapely

from bimgraph.bim import curved, faces as F
from bimgraph.bim.ifc_open import missing_references, open_model, unbalanced_statement
from bimgraph.bim.ifc_read import ModelReader
from bimgraph.bim.planemap import WALL_MAX_LEAN_RAD, BimFace, PlaneMap, Space
from bimgraph.bim.rooms import Claim, Junctions, Rooms, boundary_claims, split_at, split_face
from bimgraph.config import BimImportConfig
from bimgraph.errors import FormatError, InputError
from bimgraph.geometry import pose_to_tum

# the parser's problems with a file listed one by one; the rest counted
_PARSE_WARNINGS = 5

ORIGIN = ("the IfcBuilding's placement (its local coordinate system; the project's world "
          "coordinate system if there is no IfcBuilding), metres, z up")


def import_ifc(path, cfg: BimImportConfig, log=None, progress=None):
    """Read the IFC model at `path` into a PlaneMap in frame B (see ORIGIN); returns
    (plane_map, report) where report is a rich Table of counts and timing. A file that is no
    IFC or a damaged one raises FormatError, a sound one without walls InputError; a wall (or
    slab) whose geometry fails or gives no face is reported through `log` and skipped.
    `progress(what, done, total)` hears each wall and each face as they are done (a building
    of a thousand walls takes a minute or so)."""
    log = log or (lambda message: None)
    progress = progress or (lambda what, done, total: None)
    started = time.perf_counter()
    path = Path(path)
    model, problems = open_model(path)
    walls = model.by_type("IfcWall")
    if not walls:
        if problems:  # (lost to the damage, most likely)
            raise FormatError(f"{path}: the model has no walls (IfcWall); {_damage(path, problems)}")
        raise InputError(f"{path}: the model has no walls (IfcWall)")
    for message in problems[:_PARSE_WARNINGS]:
        log(f"warning: {path.name}: {message}")
    if len(problems) > _PARSE_WARNINGS:
        log(f"warning: {path.name}: {len(problems) - _PARSE_WARNINGS} more problems of the file's syntax")
    try:
        reader = ModelReader(model, cfg.threads, missing_references(problems))
    except (InputError, AttributeError, ValueError) as err:  # (a cycle, a reference to no entity, no axes)
        raise FormatError(f"{path}: the building's placement cannot be read ({err})") from None
    slabs = model.by_type("IfcSlab") if cfg.include_slabs else ()
    face_ids = _face_ids(walls + slabs, log)
    voids = {wall.id(): [rel.RelatedOpeningElement for rel in wall.HasOpenings if rel.RelatedOpeningElement is not None]
             for wall in walls}
    spaces = model.by_type("IfcSpace")
    meshes, solids = reader.meshes_and_solids(walls, [o for os in voids.values() for o in os] + list(spaces))
    skipped = {"walls skipped (no geometry)": _skip(log, "wall", [w for w in walls if w.id() not in meshes
                                                                  and w.id() not in reader.unreadable], "no geometry")}
    _skip(log, "room", [space for space in spaces if space.id() in reader.unreadable], "", reader.unreadable)
    if reader.kernel_fallbacks:
        log(f"warning: {len(reader.kernel_fallbacks)} bodies the schema reader could not read, left to the geometry kernel "
            f"(the first: {reader.kernel_fallbacks[0]})")
    curtain_walls = model.by_type("IfcCurtainWall")
    for wall in curtain_walls:
        log(f"warning: curtain wall {_named(wall)}: not imported")

    wall_faces = _wall_faces(reader, [w for w in walls if w.id() in meshes], meshes, voids, solids, cfg, log, progress)
    unreadable = [w for w in walls if w.id() in reader.unreadable]
    skipped["walls skipped (geometry unreadable)"] = _skip(log, "wall", unreadable, "", reader.unreadable)
    faces_per_wall = Counter()  # by face id prefix
    sections = _split_per_room(reader, wall_faces, meshes, spaces, solids, face_ids, faces_per_wall, cfg, progress)
    if reader.unread_boundaries:
        log(f"warning: {reader.unread_boundaries} space boundaries could not be read, skipped (their rooms are found by their solids)")
    # Whatever takes a wall's faces (a sliver, none vertical or along its axis, all below the
    # minimum area, or cut up by openings and rooms), it must not vanish unnoticed.
    faceless = [w for w in walls
                if w.id() in meshes and w.id() not in reader.unreadable and not faces_per_wall[face_ids[w.id()]]]
    skipped["walls skipped (no side face)"] = _skip(log, "wall", faceless, f"no side face of at least {cfg.min_face_area_m2} m2")
    if not sections:
        # (a parser lost in a wall's statement keeps its type, not its geometry, and may swallow
        # every wall after it: walls are found, and yet it is the file that is at fault)
        if problems:
            raise FormatError(f"{path}: no wall face of at least {cfg.min_face_area_m2} m2; {_damage(path, problems)}")
        raise InputError(f"{path}: no wall face of at least {cfg.min_face_area_m2} m2")
    if cfg.include_slabs:
        slab_sections, skipped["slabs skipped"] = _slab_faces(reader, slabs, face_ids, cfg, log)
        sections += slab_sections
    T_W_B = None if np.allclose(reader.T_W_B, np.eye(4)) else tuple(pose_to_tum(reader.T_W_B))
    projects = model.by_type("IfcProject")
    plane_map = PlaneMap(source=path.name, ifc_project=(projects[0].GlobalId or "") if projects else "", origin=ORIGIN, T_W_B=T_W_B,
                         faces=sections)
    seconds = time.perf_counter() - started
    return plane_map, _report(path, walls, skipped, curtain_walls, wall_faces, sections, seconds)


def _damage(path: Path, problems: list[str]) -> str:
    """What the one-line error says of a damaged file: the line to fix where its parentheses
    do not balance (one "(" too many swallows the rest of the file), the first problem else."""
    line = unbalanced_statement(path)
    where = f"the first: {problems[0]}" if line is None else f"line {line}: its parentheses do not balance"
    return f"the file is damaged ({len(problems)} problems, {where})"


def _named(element) -> str:
    """An element as warnings name it: its GlobalId and Name; its entity id where the parser,
    lost in the element's statement, filled its attributes with what came next (another entity)."""
    if isinstance(element.GlobalId, str):
        return f"{element.GlobalId} ({element.Name})"
    return f"#{element.id()} ({element.is_a()}, its attributes lost to the file's damage)"


def _face_ids(elements, log) -> dict[int, str]:
    """Element id -> what its faces' ids start with: its GlobalId. GlobalIds are unique in IFC;
    elements sharing one (an exporter's or a hand edit's slip) are warned about, and their
    faces' ids carry their entity ids too: refusing the file would be too harsh for one slip,
    and faces numbered under one id would have reports and BCF topics name one wall for two.
    (Their `wall_guid` stays the file's GlobalId: a BCF viewer looks elements up by it.)"""
    sharing = {}
    for element in elements:
        sharing.setdefault(element.GlobalId, []).append(element)
    out = {}
    for guid, alike in sharing.items():
        if len(alike) > 1:
            named = ", ".join(f"#{e.id()} {e.is_a()} ({e.Name})" for e in alike)
            log(f"warning: GlobalId {guid} is given to {len(alike)} elements, {named}: their faces' ids are "
                f"{guid}#<entity id>/<k>")
        out.update({e.id(): guid if len(alike) == 1 else f"{guid}#{e.id()}" for e in alike})
    return out


def _skip(log, kind: str, elements, reason: str, reasons: dict[int, str] | None = None) -> int:
    """Warn that each of `elements` (of `kind`) is skipped for `reason`, or for its own in
    `reasons` (by element id); returns how many."""
    for element in elements:
        why = (reasons or {}).get(element.id(), reason)
        log(f"warning: {kind} {_named(element)}: {why}, skipped")
    return len(elements)


class WallFace(NamedTuple):
    """A face of a wall (in its own frame, `faces.Face`), the depth of the wall behind it and,
    for the back of a recess, how far the recess sets it back from the wall's side (its room
    is that much further in front)."""

    wall: object
    face: F.Face
    depth: float
    recess: float = 0.0


def _wall_faces(reader: ModelReader, walls, meshes, voids, solids, cfg, log, progress) -> list[WallFace]:
    """Every side face, and every recess's back, openings cut out (`voids`: wall id -> its
    openings, `solids`: their meshes by id). A wall whose geometry cannot be read goes into
    `reader.unreadable`, with why."""
    angle_tol, axis_tol = np.radians(cfg.coplanar_angle_deg), np.radians(cfg.axis_tol_deg)
    per_wall = {}
    for done, wall in enumerate(walls, start=1):
        try:
            per_wall[wall.id()] = (wall, _sides(reader, wall, meshes[wall.id()], cfg, angle_tol, axis_tol, log))
        except Exception as err:  # a geometry this reader cannot follow: the rest goes on
            reader.unreadable[wall.id()] = (f"its geometry cannot be read "
                                            f"({type(err).__name__}: {str(err).splitlines()[0] if str(err) else ''})")
        progress("walls' side faces", done, len(walls))
    for opening in (o for wall, _ in per_wall.values() for o in voids[wall.id()] if o.id() not in solids):
        log(f"warning: opening {_named(opening)} has no geometry; its wall keeps the area")

    linings = _Linings(per_wall, meshes, axis_tol, cfg.lining_gap_m)
    out = []
    for done, (wall, sides) in enumerate(per_wall.values(), start=1):
        openings = [m for o in voids[wall.id()] for m in solids.get(o.id(), [])]
        recesses = []
        for face, depth in sides:
            holes = [F.plane_section(o.V, o.T, face, cfg.opening_slice_depth_m) for o in openings]
            # an opening that ends inside the wall (a niche, a recess for a cabinet) has a back
            # a scanner sees as a plane of its own (after the wall's sides, whose ids stay)
            for opening, hole in zip(openings, holes):
                if not hole.is_empty and (back := F.recess_back(opening, face, depth, meshes[wall.id()], openings,
                                                                cfg.opening_slice_depth_m, cfg.grid_m)) is not None:
                    recess = back.offset - face.offset
                    recesses.append(WallFace(wall, back, depth - recess, recess))
            holes += [F.plane_section(m.V, m.T, face, -cfg.lining_gap_m) for m in linings.over(face, wall)]
            holes = [h for h in holes if not h.is_empty]
            if holes:
                face.region = face.region.difference(shapely.union_all(holes, grid_size=cfg.grid_m), grid_size=cfg.grid_m)
            if face.region.area >= cfg.min_face_area_m2:
                out.append(WallFace(wall, face, depth))
        out += [back for back in recesses if back.face.region.area >= cfg.min_face_area_m2]
        progress("openings cut out", done, len(per_wall))
    return out


class _Linings:
    """Which other walls run along a face (a side of theirs parallel to it) and cross the
    plane `gap` in front of it. Where one fills that plane, the face is hidden: behind a
    lining, furring or cladding modelled as a wall of its own (Revit's way), or inside a wall
    that overlaps it. A wall across the face, butting on it at a junction, leaves it as it
    is: what is hidden there is a strip, and the rooms split the face there."""

    def __init__(self, per_wall: dict, meshes, angle_tol: float, gap: float):
        self.walls = [wall for wall, _ in per_wall.values()]
        self.meshes, self.cos_tol, self.gap = [meshes[wall.id()] for wall in self.walls], np.cos(angle_tol), gap
        self.low = np.array([mesh.V.min(axis=0) for mesh in self.meshes]).reshape(-1, 3)
        self.high = np.array([mesh.V.max(axis=0) for mesh in self.meshes]).reshape(-1, 3)
        self.normals = [np.array([side.normal for side, _ in sides]).reshape(-1, 3) for _, sides in per_wall.values()]

    def over(self, face: F.Face, wall) -> list:
        u0, v0, u1, v1 = face.region.bounds
        corners = face.to_3d(np.array([[u0, v0], [u1, v1]]))
        near = ((self.low <= corners.max(axis=0) + self.gap) & (self.high >= corners.min(axis=0) - self.gap)).all(axis=1)
        out = []
        for k in np.flatnonzero(near):
            if self.walls[k] is wall or not (np.abs(self.normals[k] @ face.normal) > self.cos_tol).any():
                continue
            distances = self.meshes[k].V @ face.normal + face.offset
            if distances.min() < self.gap < distances.max():
                out.append(self.meshes[k])
        return out


def _sides(reader: ModelReader, wall, mesh, cfg, angle_tol: float, axis_tol: float, log) -> list[tuple[F.Face, float]]:
    """A wall's side faces (before openings), each with the depth of the wall behind it; a
    side leaning out of vertical is left out, and said so through `log`."""
    axis = reader.axis(wall, mesh.T_B_E)
    steps = np.diff(axis, axis=0) if axis is not None else np.empty((0, 2))
    steps = steps[np.linalg.norm(steps, axis=1) > 1e-9]
    # A straight axis says at once which faces are sides. Along a bent or curved one that
    # depends on where a face lies, and a curved side comes as strips to be merged first.
    straight = len(steps) <= 1
    along = [np.append(steps[0] / np.linalg.norm(steps[0]), 0.0)] if len(steps) else [F.long_axis(mesh.V)]
    found = F.vertical_faces(mesh.V, mesh.T, np.radians(cfg.vertical_tol_deg), angle_tol,
                             cfg.coplanar_distance_m, cfg.grid_m, along if straight else None, axis_tol)
    if straight:
        area, slope = F.sloped_sides(mesh.V, mesh.T, np.radians(cfg.vertical_tol_deg), along, axis_tol, WALL_MAX_LEAN_RAD)
        if area >= cfg.min_face_area_m2:
            log(f"warning: wall {_named(wall)}: {area:.2f} m2 of its sides lean up to "
                f"{np.degrees(slope):.1f} deg out of vertical (more than vertical_tol_deg, {cfg.vertical_tol_deg}): not imported")
    else:
        found = curved.merge_facets(found, cfg.curved_face_tol_m, cfg.coplanar_distance_m, cfg.grid_m)
        line = shapely.LineString(axis)
        found = [face for face in found if curved.runs_along(face, line, axis_tol, cfg.grid_m)]
    return [(face, F.depth_behind(face, found, angle_tol)) for face in found]


def _split_per_room(reader: ModelReader, wall_faces, meshes, spaces, solids, face_ids, counter: Counter, cfg,
                    progress) -> list[BimFace]:
    """Sections of the wall faces per room (`spaces`, with their meshes in `solids`), their ids
    from `face_ids` (by wall id) numbered on in `counter`."""
    names = {s.GlobalId: " ".join(n for n in (s.Name, s.LongName) if n) for s in spaces}
    guids = {s.id(): s.GlobalId for s in spaces}
    rooms = Rooms({guids[i]: meshes for i, meshes in solids.items() if i in guids})
    boundaries = {}
    for b in reader.boundaries([f.wall for f in wall_faces]):
        boundaries.setdefault(b.wall_id, []).append(b)

    # (rooms without a solid or a boundary on these walls say nothing: the junctions split then)
    junctions = None if rooms.items or boundaries else Junctions({f.wall.id(): meshes[f.wall.id()] for f in wall_faces})
    angle_tol = np.radians(cfg.vertical_tol_deg)
    sections = []
    for done, (wall, face, depth, recess) in enumerate(wall_faces, start=1):
        if junctions is None:
            in_front = rooms.claims(face, cfg.probe_distance_m + recess)
            claims = boundary_claims(face, depth, boundaries.get(wall.id(), []), cfg.boundary_on_face_m,
                                     angle_tol, {c.space_guid: c.region for c in in_front})
            pieces = [(region, claim or Claim(None, "none", None))
                      for region, claim in split_face(face, claims + in_front, cfg.grid_m)]
        else:
            cuts = junctions.cuts(face, wall.id(), cfg.coplanar_distance_m, cfg.min_section_width_m)
            pieces = [(region, Claim(None, "junction" if cuts else "none", None)) for region in split_at(face, cuts)]
        for region, claim in pieces:
            space = Space(guid=claim.space_guid, name=names.get(claim.space_guid, "")) if claim.space_guid else None
            sections += _sections(reader, wall, face_ids[wall.id()], face, region, cfg, counter, space=space, split=claim.method)
        progress("faces split per room", done, len(wall_faces))
    return sections


def _slab_faces(reader: ModelReader, slabs, face_ids, cfg, log) -> tuple[list[BimFace], int]:
    """Top and bottom faces of every slab, openings (stairs, shafts) subtracted by the
    geometry iterator: slabs have few, and their faces are not split per room. Returns them
    and how many slabs were skipped (warned about through `log`)."""
    sections = []
    counter = Counter()
    meshes = reader.meshes(slabs, subtract_openings=True)
    faceless = []
    for slab in slabs:
        if slab.id() not in meshes:
            continue
        mesh = meshes[slab.id()]
        found = []
        for face in F.horizontal_faces(mesh.V, mesh.T, np.radians(cfg.vertical_tol_deg), cfg.coplanar_distance_m, cfg.grid_m):
            kind = "slab_top" if face.normal[2] > 0 else "slab_bottom"
            found += _sections(reader, slab, face_ids[slab.id()], face, face.region, cfg, counter, kind=kind)
        sections += found
        if not found:  # e.g. a sloped roof slab
            faceless.append(slab)
    skipped = _skip(log, "slab", [s for s in slabs if s.id() not in meshes], "no geometry")
    return sections, skipped + _skip(log, "slab", faceless, f"no horizontal face of at least {cfg.min_face_area_m2} m2")


def _sections(reader, element, face_id: str, face: F.Face, region, cfg, counter: Counter, **fields) -> list[BimFace]:
    """One BimFace per polygon of `region` (in `face`'s frame) of at least the minimum area,
    its id `face_id`/k, k numbering them per `face_id` in `counter`."""
    storey, elevation = reader.storey(element)
    out = []
    for polygon in F.polygons(region):
        if polygon.area < cfg.min_face_area_m2:
            continue
        polygon = polygon.simplify(cfg.grid_m)  # corners only: no vertices along straight edges
        k = counter[face_id]
        counter[face_id] += 1
        out.append(BimFace(
            id=f"{face_id}/{k}", wall_guid=element.GlobalId, wall_name=element.Name or "",
            storey=storey, elevation=elevation, normal=tuple(face.normal), offset=face.offset,
            polygon=_points_3d(face, polygon.exterior), holes=[_points_3d(face, r) for r in polygon.interiors],
            area=polygon.area, centre=tuple(face.to_3d(np.asarray(polygon.centroid.coords))[0].tolist()), **fields))
    return out


def _points_3d(face: F.Face, ring) -> list[tuple]:
    """A closed ring of the face frame as its points in B, without the closing repeat; plain
    floats, which the plane map validates faster than numpy's."""
    return [tuple(p) for p in face.to_3d(shapely.get_coordinates(ring)[:-1]).tolist()]


def _report(path, walls, skipped, curtain_walls, wall_faces, sections, seconds):
    from rich.table import Table

    table = Table(title=f"BIM import of {path.name}")
    table.add_column("item")
    table.add_column("count", justify="right")
    table.add_row("walls", str(len(walls)))
    for item, count in skipped.items():
        table.add_row(item, str(count))
    table.add_row("curtain walls skipped", str(len(curtain_walls)))
    table.add_row("wall side faces", str(len(wall_faces)))
    slabs = [s for s in sections if s.kind != "wall"]
    if slabs:
        table.add_row("slab top and bottom faces", str(len(slabs)))
    for method, n in sorted(Counter(s.split for s in sections if s.kind == "wall").items()):
        table.add_row(f"wall sections split by {method}", str(n))
    table.add_row("total face area (m2)", f"{sum(s.area for s in sections):.2f}")
    table.add_row("seconds", f"{seconds:.3f}")
    return table
