"""The generated house the IFC import tests write (two storeys, rooms, doors and windows), and
helpers to edit a written model."""

import numpy as np
import shapely

from bimgraph.bim.building import Building, Opening, Space, Storey, Wall
from bimgraph.bim.faces import Face
from bimgraph.bim.ifc_write import write_ifc

T, t, H = 0.3, 0.2, 3.0  # outer and inner wall thickness, storey height


def house() -> Building:
    """Two storeys, 10 x 6 m: downstairs a kitchen and a living room either side of an inner
    wall with a door, upstairs a loft; windows in the outer walls, a front door."""
    storeys = [Storey("Ground", 0.0, H), Storey("Upper", H, H)]
    walls = []
    for k in range(2):
        window = (Opening(1.0, 1.2, 1.4, 0.9, "window"),)
        front_door = (Opening(6.0, 1.0, 2.1, 0.0, "door"),) if k == 0 else ()
        walls += [
            Wall(f"S{k}", (-T / 2, 0.0), (10 + T / 2, 0.0), T, H, k, window + front_door),
            Wall(f"E{k}", (10.0, T / 2), (10.0, 6 - T / 2), T, H, k, window),
            Wall(f"N{k}", (10 + T / 2, 6.0), (-T / 2, 6.0), T, H, k, (Opening(2.0, 1.5, 1.2, 1.0, "window"),)),
            Wall(f"W{k}", (0.0, 6 - T / 2), (0.0, T / 2), T, H, k),
        ]
    walls.append(Wall("I0", (5.0, T / 2), (5.0, 6 - T / 2), t, H, 0, (Opening(2.0, 0.9, 2.1, 0.0, "door"),)))
    a, b = T / 2, 6 - T / 2
    spaces = [Space("Kitchen", ((a, a), (5 - t / 2, a), (5 - t / 2, b), (a, b)), 0),
              Space("Living", ((5 + t / 2, a), (10 - a, a), (10 - a, b), (5 + t / 2, b)), 0),
              Space("Loft", ((a, a), (10 - a, a), (10 - a, b), (a, b)), 1)]
    return Building("House", storeys, walls, spaces)


def expected_faces(building: Building):
    """{(wall name, side): (normal, offset, region in the face frame)} for both side faces."""
    out = {}
    for wall in building.walls:
        start, end = np.asarray(wall.start), np.asarray(wall.end)
        length = np.linalg.norm(end - start)
        x = (end - start) / length
        left = np.array([-x[1], x[0], 0.0])
        z0 = building.storeys[wall.storey].elevation
        for side in (1, -1):
            normal = side * left
            on_face = np.append(start, 0.0) + side * wall.thickness / 2 * left
            face = Face(normal, -float(normal @ on_face), None)

            def rect(along, width, bottom, height):
                corners = np.array([[along, bottom], [along + width, bottom], [along + width, bottom + height]])
                p = np.append(start, 0.0) + side * wall.thickness / 2 * left
                uv = face.to_2d(p + corners[:, :1] * np.append(x, 0.0) + corners[:, 1:] * [0, 0, 1])
                return shapely.box(*uv.min(axis=0), *uv.max(axis=0))

            region = rect(0.0, length, z0, wall.height)
            for o in wall.openings:
                region = region.difference(rect(o.along, o.width, z0 + o.sill, o.height))
            out[(wall.name, side)] = (face, region)
    return out


def edited_house(path, edit, **write_args):
    """The house written to `path`, then `edit(model)` applied to it; returns the edited model."""
    import ifcopenshell

    write_ifc(house(), path, **write_args)
    model = ifcopenshell.open(str(path))
    edit(model)
    model.write(str(path))
    return model


def add_opening(model, wall, T_W_opening, context, **box):
    """An IfcOpeningElement voiding `wall`, placed at `T_W_opening`: a box (`length` along its
    x, `height` up, across its y from `offset` to `offset + thickness`)."""
    import ifcopenshell.api.feature
    import ifcopenshell.api.geometry
    import ifcopenshell.api.root

    opening = ifcopenshell.api.root.create_entity(model, ifc_class="IfcOpeningElement", name="opening")
    ifcopenshell.api.geometry.edit_object_placement(model, product=opening, matrix=T_W_opening)
    representation = ifcopenshell.api.geometry.add_wall_representation(model, context=context, **box)
    ifcopenshell.api.geometry.assign_representation(model, product=opening, representation=representation)
    ifcopenshell.api.feature.add_feature(model, feature=opening, element=wall)


def wall_named(model, name):
    return next(w for w in model.by_type("IfcWall") if w.Name == name)


def body_of(element):
    return next(r for r in element.Representation.Representations if r.RepresentationIdentifier == "Body")
