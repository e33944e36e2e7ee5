"""The generated buildings, mirroring the environments of the seed paper.

- `office`: two rows of rooms along a corridor, a door from each room onto the corridor,
  windows in the facades. Furnished (boxes, desks, cabinets) by the as-built world.
- `site`: a construction floor: a big shell cut by a few walls with wide openings and a
  stair core; bare, cluttered, with temporary partitions and walls not yet built.

Coordinates are metres in B. Room footprints are the room's axis rectangle minus the walls'
thickness, so that they lie exactly on the wall faces (as the IFC writer's space boundaries
need).
"""

from __future__ import annotations

from shapely.geometry import LineString, Polygon, box
from shapely.geometry.polygon import orient
from shapely.ops import unary_union

from bimgraph.bim.building import Building, Opening, Space, Storey, Wall

SCENARIOS = ("office", "site")

_DOOR = dict(width=1.0, height=2.1)
_WINDOW = dict(width=1.5, height=1.3, sill=0.9, kind="window")


def _spaces(walls: list[Wall], rooms: dict[str, Polygon]) -> list[Space]:
    solid = unary_union([LineString([w.start, w.end]).buffer(w.thickness / 2, cap_style="flat") for w in walls])
    spaces = []
    for name, outline in rooms.items():
        inner = orient(outline.difference(solid), 1.0)
        coords = [(round(x, 9), round(y, 9)) for x, y in inner.exterior.coords[:-1]]
        spaces.append(Space(name, tuple(coords)))
    return spaces


def office(rooms_per_side: int = 4, room_width: float = 4.0, room_depth: float = 5.0, corridor: float = 2.0) -> Building:
    height, ext, inner = 3.0, 0.3, 0.12
    length = rooms_per_side * room_width
    y_corr0, y_corr1 = room_depth, room_depth + corridor
    depth = 2 * room_depth + corridor
    windows = tuple(Opening(along=i * room_width + (room_width - 1.5) / 2, **_WINDOW) for i in range(rooms_per_side))
    walls = [
        Wall("facade south", (0.0, 0.0), (length, 0.0), ext, height, openings=windows),
        Wall("facade north", (length, depth), (0.0, depth), ext, height, openings=windows),
        Wall("facade west", (0.0, depth), (0.0, 0.0), ext, height),
        Wall("facade east", (length, 0.0), (length, depth), ext, height),
        Wall("corridor south", (0.0, y_corr0), (length, y_corr0), inner, height,
             openings=tuple(Opening(along=i * room_width + room_width - 1.6, **_DOOR) for i in range(rooms_per_side))),
        Wall("corridor north", (0.0, y_corr1), (length, y_corr1), inner, height,
             openings=tuple(Opening(along=i * room_width + 0.6, **_DOOR) for i in range(rooms_per_side))),
    ]
    for i in range(1, rooms_per_side):
        x = i * room_width
        walls.append(Wall(f"partition {i} south", (x, 0.0), (x, y_corr0), inner, height))
        walls.append(Wall(f"partition {i} north", (x, y_corr1), (x, depth), inner, height))
    rooms = {"corridor": box(0.0, y_corr0, length, y_corr1)}
    for i in range(rooms_per_side):
        rooms[f"office S{i + 1}"] = box(i * room_width, 0.0, (i + 1) * room_width, y_corr0)
        rooms[f"office N{i + 1}"] = box(i * room_width, y_corr1, (i + 1) * room_width, depth)
    return Building("office", [Storey("Level 0", 0.0, height)], walls, _spaces(walls, rooms))


def site() -> Building:
    height, ext, inner, core = 3.2, 0.3, 0.2, 0.25
    W, D = 24.0, 16.0
    big_window = dict(width=2.4, height=1.6, sill=0.9, kind="window")
    opening = dict(width=1.4, height=2.2)
    walls = [
        Wall("shell south", (0.0, 0.0), (W, 0.0), ext, height,
             openings=tuple(Opening(along=x, **big_window) for x in (2.0, 6.5, 13.0, 19.0))),
        Wall("shell north", (W, D), (0.0, D), ext, height,
             openings=tuple(Opening(along=x, **big_window) for x in (2.0, 14.5, 19.5))),
        Wall("shell west", (0.0, D), (0.0, 0.0), ext, height, openings=(Opening(along=5.0, **big_window),)),
        Wall("shell east", (W, 0.0), (W, D), ext, height, openings=(Opening(along=6.0, **big_window),)),
        Wall("wall A", (10.0, 0.0), (10.0, D), inner, height,
             openings=(Opening(along=3.0, **opening), Opening(along=11.5, **opening))),
        Wall("wall B", (0.0, 8.0), (10.0, 8.0), inner, height, openings=(Opening(along=4.0, **opening),)),
        Wall("wall C", (17.0, 0.0), (17.0, D), inner, height,
             openings=(Opening(along=2.0, **opening), Opening(along=12.0, **opening))),
        Wall("core west", (12.0, D), (12.0, 12.0), core, height),
        Wall("core south", (12.0, 12.0), (15.0, 12.0), core, height, openings=(Opening(along=1.0, width=1.0, height=2.1),)),
        Wall("core east", (15.0, 12.0), (15.0, D), core, height),
    ]
    rooms = {
        "zone 1": box(0.0, 0.0, 10.0, 8.0),
        "zone 2": box(0.0, 8.0, 10.0, D),
        "zone 3": box(10.0, 0.0, 17.0, D).difference(box(12.0, 12.0, 15.0, D)),
        "core": box(12.0, 12.0, 15.0, D),
        "zone 4": box(17.0, 0.0, W, D),
    }
    return Building("site", [Storey("Level 0", 0.0, height)], walls, _spaces(walls, rooms))


def make(name: str) -> Building:
    return {"office": office, "site": site}[name]()
