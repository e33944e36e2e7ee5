"""A simple building description: storeys, straight walls with openings, rooms.

It is what the generated models are made from (`ifc_write.write_ifc` turns it into IFC with
ifcopenshell.api) and, because its geometry is known exactly, what importer tests compare
against. Coordinates are metres in B; a wall runs along its axis from `start` to `end`, its
thickness centred on the axis, from its storey's elevation up `height`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

XY = tuple[float, float]


@dataclass(frozen=True)
class Opening:
    """A door or window in a wall: `along` is the distance of its left edge from the wall's
    start along the axis, `sill` its bottom above the storey elevation."""

    along: float
    width: float
    height: float
    sill: float = 0.0
    kind: Literal["door", "window"] = "door"


@dataclass(frozen=True)
class Wall:
    name: str
    start: XY
    end: XY
    thickness: float
    height: float
    storey: int = 0
    openings: tuple[Opening, ...] = ()


@dataclass(frozen=True)
class Space:
    """A room: its floor outline (counter-clockwise seen from above, in B) on a storey."""

    name: str
    footprint: tuple[XY, ...]
    storey: int = 0


@dataclass(frozen=True)
class Storey:
    name: str
    elevation: float
    height: float


@dataclass
class Building:
    name: str
    storeys: list[Storey]
    walls: list[Wall] = field(default_factory=list)
    spaces: list[Space] = field(default_factory=list)
