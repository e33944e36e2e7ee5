"""The many ways IFC writes a wall's body (tessellated surfaces wound either way, layers, mapped
items, bent and curved axes), each re-extracted as the faces of the plain wall."""

import numpy as np
import pytest
from ifc_house import H, T, add_opening, body_of, edited_house, house, wall_named

from bimgraph.bim.building import Building, Storey, Wall
from bimgraph.bim.ifc_import import import_ifc
from bimgraph.bim.ifc_write import write_ifc
from bimgraph.config import BimImportConfig


def test_triangles_wound_either_way_are_oriented_outward():
    """Tessellated walls (surface models) come with triangles wound at random."""
    from bimgraph.bim.faces import orient_outward

    V = np.array([[x, y, z] for x in (0.0, 4.0) for y in (0.0, 0.3) for z in (0.0, 3.0)])
    # A box as 12 triangles, each wound outward (checked by the volume below).
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    T = np.array([t for a, b, c, d in quads for t in ((a, b, c), (a, c, d))])

    def volume_of(V, T):
        return np.einsum("ij,ij->", V[T[:, 0]], np.cross(V[T[:, 1]], V[T[:, 2]])) / 6

    assert volume_of(V, T) == pytest.approx(3.6)
    rng = np.random.default_rng(0)
    for _ in range(20):
        mixed = T.copy()
        flip = rng.random(len(T)) < 0.5
        mixed[flip] = mixed[flip, ::-1]
        fixed = orient_outward(V, mixed)
        assert volume_of(V, fixed) == pytest.approx(3.6)
        assert np.array_equal(np.sort(fixed, axis=1), np.sort(T, axis=1))
    # Two separate boxes, one of them inside out: each part is oriented on its own.
    two = np.vstack([T, T[:, ::-1] + 8])
    V2 = np.vstack([V, V + [10.0, 0.0, 0.0]])
    assert volume_of(V2, orient_outward(V2, two)) == pytest.approx(7.2)


def test_internal_layer_faces_are_not_faces(tmp_path):
    """A wall built as two layers (two extrusions touching inside the wall) has the faces of
    the one-piece wall: the interface between the layers faces both ways and is no face."""
    import ifcopenshell.api.geometry

    path = tmp_path / "layers.ifc"

    def two_layers(model):
        body = body_of(wall_named(model, "W0"))
        layers = [ifcopenshell.api.geometry.add_wall_representation(
            model, context=body.ContextOfItems, length=6 - T, height=H, thickness=thickness, offset=offset)
            for thickness, offset in ((0.1, -T / 2), (T - 0.1, -T / 2 + 0.1))]
        body.Items = [layer.Items[0] for layer in layers]

    edited_house(path, two_layers, length_unit="mm")
    plane_map, _ = import_ifc(path, BimImportConfig())
    faces = [f for f in plane_map.faces if f.wall_name == "W0"]
    assert sorted(f.offset for f in faces) == pytest.approx([-T / 2, -T / 2])  # x = -0.15 and x = 0.15
    assert sorted(round(f.normal[0]) for f in faces) == [-1, 1]  # one face on each side, not one twice
    assert sum(f.area for f in faces) == pytest.approx(2 * (6 - T) * H)


def test_a_wall_along_a_face_hides_it_and_a_wall_across_does_not(tmp_path):
    """A lining modelled as a wall of its own (Revit's furring) over part of the kitchen side
    of W0: W0's face loses the part behind it, the lining's back face (against W0) is gone,
    its front face stays. I0 butts across S0 and N0, whose faces stay whole."""
    import dataclasses

    from ifc_house import expected_faces

    building = house()
    lining = Wall("L0", (T / 2 + 0.025, 2.0), (T / 2 + 0.025, 4.0), 0.05, H)
    building.walls.append(lining)
    path = tmp_path / "lining.ifc"
    write_ifc(building, path)
    plane_map, _ = import_ifc(path, BimImportConfig())
    area = {}
    for f in plane_map.faces:
        key = (f.wall_name, round(f.normal[0]), round(f.normal[1]))
        area[key] = area.get(key, 0.0) + f.area
    assert area[("W0", 1, 0)] == pytest.approx((6 - T - 2.0) * H)
    assert area[("L0", 1, 0)] == pytest.approx(2.0 * H) and ("L0", -1, 0) not in area
    unlined = expected_faces(dataclasses.replace(building, walls=[w for w in building.walls if w is not lining]))
    for name, normal in (("S0", (0, 1)), ("N0", (0, -1))):
        side = next(region for (wall, _), (face, region) in unlined.items()
                    if wall == name and tuple(np.round(face.normal[:2]).astype(int)) == normal)
        assert area[(name, *normal)] == pytest.approx(side.area)


def test_components_agree_with_scipy():
    """faces._components is a fast path for small meshes; it must partition as scipy does,
    long chains (which fall back to scipy) included."""
    import scipy.sparse
    import scipy.sparse.csgraph

    from bimgraph.bim.faces import _components

    rng = np.random.default_rng(0)
    graphs = [(n, rng.integers(0, n, size=(rng.integers(0, 2 * n), 2))) for n in rng.integers(1, 60, size=300)]
    graphs.append((500, np.stack([np.arange(499), np.arange(1, 500)], axis=1)))  # one long chain
    for n, edges in graphs:
        i, j = edges[:, 0], edges[:, 1]
        count, labels = _components(n, i, j)
        expected_count, expected = scipy.sparse.csgraph.connected_components(
            scipy.sparse.coo_matrix((np.ones(len(i)), (i, j)), shape=(n, n)), directed=False)
        assert count == expected_count
        # Same partition up to numbering: the sets of nodes per label are the same sets.
        def partition(labels):
            return {frozenset(np.flatnonzero(labels == label)) for label in np.unique(labels)}
        assert partition(np.asarray(labels)) == partition(expected)


# Wall E0's box in its own frame (x along it, y across, z up), as quads wound outward: its two
# ends and two sides, without top or bottom, so that it is an open surface.
BOX = [[x, y, z] for x in (0.0, 6 - T) for y in (-T / 2, T / 2) for z in (0.0, H)]
BOX_SIDES_AND_ENDS = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6)]


def open_surface(model, kind, quads):
    """An item of representation `kind` made of the `quads` of BOX."""
    if kind in ("triangulated", "triangulated_unflagged"):
        triangles = [[i + 1 for i in t] for a, b, c, d in quads for t in ((a, b, c), (a, c, d))]
        closed = False if kind == "triangulated" else None
        return model.createIfcTriangulatedFaceSet(model.createIfcCartesianPointList3D(BOX), None, closed, triangles)
    if kind == "polygonal":
        return model.createIfcPolygonalFaceSet(model.createIfcCartesianPointList3D(BOX), False,
                                               [model.createIfcIndexedPolygonalFace([i + 1 for i in q]) for q in quads])
    points = [model.createIfcCartesianPoint(p) for p in BOX]
    faces = [model.createIfcFace([model.createIfcFaceOuterBound(model.createIfcPolyLoop([points[i] for i in q]), True)])
             for q in quads]
    if kind == "surface_model":
        return model.createIfcShellBasedSurfaceModel([model.createIfcOpenShell(faces)])
    return model.createIfcFacetedBrep(model.createIfcClosedShell(faces))  # a "closed" shell that is not


@pytest.mark.parametrize("winding", ["inward", "mixed"])
@pytest.mark.parametrize("kind", ["triangulated", "triangulated_unflagged", "polygonal", "surface_model", "faceted_brep"])
def test_open_tessellated_wall_faces_out_whatever_its_winding(tmp_path, kind, winding):
    """A wall given as an open surface (a face set not Closed, a surface model, a brep whose
    shell lacks faces), its triangles wound inward or each face either way: it encloses no
    volume to be oriented by, yet its faces point out of the wall as the extrusion's do."""
    write_ifc(house(), tmp_path / "reference.ifc")
    reference, _ = import_ifc(tmp_path / "reference.ifc", BimImportConfig())
    quads = [q[::-1] if winding == "inward" or k % 2 == 0 else q for k, q in enumerate(BOX_SIDES_AND_ENDS)]

    def tessellated(model):
        body_of(wall_named(model, "E0")).Items = [open_surface(model, kind, quads)]

    edited_house(tmp_path / "open.ifc", tessellated)
    messages = []
    plane_map, _ = import_ifc(tmp_path / "open.ifc", BimImportConfig(), log=messages.append)
    assert messages == []

    def faces_of_E0(plane_map):
        return sorted((f.normal, round(f.offset, 6), round(f.area, 6)) for f in plane_map.faces if f.wall_name == "E0")

    # E0 runs along x = 10: its outer face is x = 10.15 (normal +x), its inner one x = 9.85
    assert [(n, d) for n, d, _ in faces_of_E0(plane_map)] == [((-1.0, 0.0, 0.0), 9.85), ((1.0, 0.0, 0.0), -10.15)]
    assert faces_of_E0(plane_map) == faces_of_E0(reference)


def test_open_surfaces_face_away_from_their_material():
    """orient_outward on a round wall's two sides alone (a ring: no top, bottom or ends), wound
    inward or at random: the outer side faces away from the centre, the inner one towards it
    (the material lies between them, not within the inner side)."""
    from bimgraph.bim.faces import orient_outward, triangle_normals

    n = 48
    angles = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
    V = np.array([[r * np.cos(a), r * np.sin(a), z] for r in (2.0, 2.3) for z in (0.0, 3.0) for a in angles])
    k = np.arange(n)
    triangles = []
    for side, sign in ((0, -1), (1, 1)):  # inner: wound facing the centre, outer: away from it
        bottom, top = 2 * side * n + k, (2 * side + 1) * n + k
        quads = np.column_stack([bottom, np.roll(bottom, -1), np.roll(top, -1), top])
        quads = quads if sign > 0 else quads[:, ::-1]
        triangles += [quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]]
    outward = np.vstack(triangles)
    rng = np.random.default_rng(0)
    for wound in (outward[:, ::-1], np.where(rng.random((len(outward), 1)) < 0.5, outward[:, ::-1], outward)):
        fixed = orient_outward(V, wound)
        normals, _ = triangle_normals(V, fixed)
        centres = V[fixed].mean(axis=1)
        radial = np.einsum("ij,ij->i", normals[:, :2], centres[:, :2] / np.linalg.norm(centres[:, :2], axis=1)[:, None])
        outer = np.linalg.norm(centres[:, :2], axis=1) > 2.15
        assert (radial[outer] > 0.99).all() and (radial[~outer] < -0.99).all()


@pytest.mark.parametrize("shape", ["sliver", "leaning"])
def test_wall_without_side_face_is_warned_about_and_skipped(tmp_path, shape):
    """A wall whose geometry gives no side face (a 1 x 1 cm sliver; a wall leaning 10 degrees,
    whose sides are not vertical) is warned about like one whose geometry fails."""
    import ifcopenshell.api.geometry

    def faceless(model):
        body = body_of(wall_named(model, "E0"))
        size = {"sliver": dict(length=0.01, thickness=0.01, offset=-0.005),
                "leaning": dict(length=6 - T, thickness=T, offset=-T / 2, x_angle=np.radians(10.0))}[shape]
        body.Items = ifcopenshell.api.geometry.add_wall_representation(
            model, context=body.ContextOfItems, height=H, **size).Items

    wall = wall_named(edited_house(tmp_path / "faceless.ifc", faceless), "E0")
    messages = []
    plane_map, _ = import_ifc(tmp_path / "faceless.ifc", BimImportConfig(), log=messages.append)
    if shape == "leaning":
        assert "lean up to 10.0 deg out of vertical" in messages.pop(0)
    assert len(messages) == 1 and wall.GlobalId in messages[0] and "(E0)" in messages[0]
    assert "no side face" in messages[0] and "skipped" in messages[0]
    assert "E0" not in {f.wall_name for f in plane_map.faces}
    assert len(plane_map.faces) == 18  # the other 8 walls, as when E0's geometry fails


def test_a_battered_side_is_warned_about_and_the_vertical_one_kept(tmp_path):
    """E0 as a retaining wall's batter: 0.3 m thick at its foot, 0.1 m at its top, the outer
    side vertical, the inner one leaning 3.8 degrees. The leaning side is no plane the
    backend can use as vertical; it is left out, and said so."""
    def battered(model):
        body = body_of(wall_named(model, "E0"))
        profile = model.createIfcArbitraryClosedProfileDef("AREA", None, model.createIfcPolyline(
            [model.createIfcCartesianPoint(p) for p in ((-T / 2, 0.0), (T / 2, 0.0), (-T / 2 + 0.1, H), (-T / 2, H), (-T / 2, 0.0))]))
        along_x = model.createIfcAxis2Placement3D(model.createIfcCartesianPoint((0.0, 0.0, 0.0)),
                                                  model.createIfcDirection((1.0, 0.0, 0.0)), model.createIfcDirection((0.0, 1.0, 0.0)))
        body.Items = [model.createIfcExtrudedAreaSolid(profile, along_x, model.createIfcDirection((0.0, 0.0, 1.0)), 6 - T)]

    wall = wall_named(edited_house(tmp_path / "battered.ifc", battered), "E0")
    messages = []
    plane_map, _ = import_ifc(tmp_path / "battered.ifc", BimImportConfig(), log=messages.append)
    (message,) = messages
    leaning = (6 - T) * np.hypot(H, T - 0.1)
    assert wall.GlobalId in message and f"{leaning:.2f} m2" in message
    assert f"{np.degrees(np.arctan2(T - 0.1, H)):.1f} deg" in message
    kept = [f for f in plane_map.faces if f.wall_name == "E0"]
    assert kept and all(f.normal[0] > 0.99 for f in kept)  # the outer side, x = 10.15


def test_slab_without_faces_is_warned_about_and_skipped(tmp_path):
    """With include_slabs, a slab whose geometry fails (an extrusion of no depth) or that has
    no horizontal face (a roof sloped 30 degrees) is warned about and skipped like a wall; a
    flat one gives its top and bottom."""
    import ifcopenshell.api.geometry
    import ifcopenshell.api.root
    import ifcopenshell.api.spatial

    from bimgraph.geometry import make_pose

    guids = {}
    a = np.radians(30.0)
    tilted = make_pose(np.array([[1.0, 0.0, 0.0], [0.0, np.cos(a), -np.sin(a)], [0.0, np.sin(a), np.cos(a)]]), [0.0, 0.0, H])

    def slabs(model):
        context = body_of(wall_named(model, "E0")).ContextOfItems
        for name, T_W_slab in (("flat", make_pose(np.eye(3), [0.0, 0.0, H])), ("broken", np.eye(4)), ("sloped", tilted)):
            slab = ifcopenshell.api.root.create_entity(model, ifc_class="IfcSlab", name=name)
            ifcopenshell.api.spatial.assign_container(model, relating_structure=model.by_type("IfcBuildingStorey")[1],
                                                      products=[slab])
            ifcopenshell.api.geometry.edit_object_placement(model, product=slab, matrix=T_W_slab)
            representation = ifcopenshell.api.geometry.add_slab_representation(
                model, context=context, depth=0.2, polyline=[(0.0, 0.0), (10.0, 0.0), (10.0, 6.0), (0.0, 6.0)])
            if name == "broken":
                representation.Items[0].Depth = 0.0
            ifcopenshell.api.geometry.assign_representation(model, product=slab, representation=representation)
            guids[name] = slab.GlobalId

    edited_house(tmp_path / "slabs.ifc", slabs)
    messages = []
    plane_map, _ = import_ifc(tmp_path / "slabs.ifc", BimImportConfig(include_slabs=True), log=messages.append)
    assert sorted(f.kind for f in plane_map.faces if f.kind != "wall") == ["slab_bottom", "slab_top"]
    assert {f.wall_name for f in plane_map.faces if f.kind != "wall"} == {"flat"}
    assert len(messages) == 2
    assert guids["broken"] in messages[0] and "(broken)" in messages[0] and "no geometry, skipped" in messages[0]
    assert guids["sloped"] in messages[1] and "(sloped)" in messages[1] and "no horizontal face" in messages[1]


@pytest.mark.parametrize("variant", ["mapped", "main_context", "no_identifier", "niche", "halves"])
def test_other_ways_to_write_walls(tmp_path, variant):
    """Walls as authoring tools also write them come out as the plain ones: a body and an axis
    only as IfcMappedItems, a body in the main model context, a body without identifier. An
    opening that does not cut through (a niche 20 cm deep into the 30 cm wall W0 from inside)
    is a hole in the face it opens only, and its back a face of its own: 20 cm behind, 1 m2,
    facing the same room. A window's opening in two halves, one from each side, meeting at
    its frame inside the wall, is a hole in both faces and has no back."""
    import ifcopenshell.util.placement

    from bimgraph.geometry import make_pose

    def mapped(model, representation):
        origin = model.createIfcAxis2Placement3D(model.createIfcCartesianPoint((0.0, 0.0, 0.0)), None, None)
        shared = model.createIfcShapeRepresentation(representation.ContextOfItems, representation.RepresentationIdentifier,
                                                    representation.RepresentationType, list(representation.Items))
        target = model.createIfcCartesianTransformationOperator3D(None, None, origin.Location, None, None)
        representation.Items = [model.createIfcMappedItem(model.createIfcRepresentationMap(origin, shared), target)]
        representation.RepresentationType = "MappedRepresentation"

    def edit(model):
        wall = wall_named(model, "W0")
        body = body_of(wall)
        if variant == "mapped":
            for representation in wall.Representation.Representations:
                mapped(model, representation)
        elif variant == "main_context":
            body.ContextOfItems = body.ContextOfItems.ParentContext
        elif variant == "no_identifier":
            body.RepresentationIdentifier = None
        else:
            T_W_wall = ifcopenshell.util.placement.get_local_placement(wall.ObjectPlacement)
            T_W_opening = T_W_wall @ make_pose(np.eye(3), [2.0, 0.0, 1.0])
            if variant == "niche":
                add_opening(model, wall, T_W_opening, body.ContextOfItems, length=1.0, height=1.0, thickness=0.21, offset=T / 2 - 0.2)
            else:
                for offset in (-T / 2 - 0.01, 0.0):
                    add_opening(model, wall, T_W_opening, body.ContextOfItems, length=1.0, height=1.0, thickness=T / 2 + 0.01, offset=offset)

    write_ifc(house(), tmp_path / "reference.ifc")
    reference, _ = import_ifc(tmp_path / "reference.ifc", BimImportConfig())
    edited_house(tmp_path / "variant.ifc", edit)
    messages = []
    plane_map, _ = import_ifc(tmp_path / "variant.ifc", BimImportConfig(), log=messages.append)
    assert messages == [] and len(plane_map.faces) == len(reference.faces) + (variant == "niche")

    def key(face):  # GlobalIds are new in each file written
        return face.wall_name, face.id.split("/")[1]

    expected = {key(f): f for f in reference.faces}
    if variant == "niche":
        (back,) = [f for f in plane_map.faces if key(f) not in expected]
        inner = next(f for f in plane_map.faces if f.wall_name == "W0" and f.normal[0] > 0.5 and key(f) in expected)
        assert back.wall_name == "W0" and np.allclose(back.normal, inner.normal, atol=1e-9)
        assert back.offset - inner.offset == pytest.approx(0.2, abs=1e-9) and back.area == pytest.approx(1.0, abs=1e-6)
        assert back.space == inner.space and not back.holes
    for face in plane_map.faces:
        if variant == "niche" and key(face) not in expected:
            continue
        plan = expected[key(face)]
        assert np.allclose(face.plane, plan.plane, atol=1e-9)
        # (the niche opens into W0's inner face, x = 0.15; the halves into both)
        opened = face.wall_name == "W0" and (variant == "halves" or variant == "niche" and face.normal[0] > 0.5)
        assert face.area == pytest.approx(plan.area - (1.0 if opened else 0.0), abs=1e-6)
        assert len(face.holes) == len(plan.holes) + opened


def one_wall_model(path, profile, axis, schema="IFC4", length_unit="m"):
    """A model of one storey holding one wall "C0" (placed at the origin of B), as authoring
    tools write walls the house does not have: `profile(f, point, m)` and `axis(f, point, m)`
    make the curves of its body's profile (extruded H up) and of its axis in file `f`, with
    `point(x, y)` making a point and `m(x)` a length, both given in metres. Returns the model
    (unwritten), the wall and the representation contexts by identifier."""
    import ifcopenshell.api.geometry
    import ifcopenshell.api.root
    import ifcopenshell.api.spatial

    s = 1000.0 if length_unit == "mm" else 1.0
    write_ifc(Building("One", [Storey("Ground", 0.0, H)], [], []), path, schema=schema, length_unit=length_unit)
    f = ifcopenshell.open(str(path))
    contexts = {c.ContextIdentifier: c for c in f.by_type("IfcGeometricRepresentationSubContext")}

    def m(x):
        return float(x * s)

    def point(x, y):
        return f.createIfcCartesianPoint((m(x), m(y)))

    solid = f.createIfcExtrudedAreaSolid(f.createIfcArbitraryClosedProfileDef("AREA", None, profile(f, point, m)),
                                         f.createIfcAxis2Placement3D(f.createIfcCartesianPoint((0.0, 0.0, 0.0)), None, None),
                                         f.createIfcDirection((0.0, 0.0, 1.0)), H * s)
    wall = ifcopenshell.api.root.create_entity(f, ifc_class="IfcWall", name="C0")
    ifcopenshell.api.spatial.assign_container(f, relating_structure=f.by_type("IfcBuildingStorey")[0], products=[wall])
    ifcopenshell.api.geometry.edit_object_placement(f, product=wall, matrix=np.eye(4))
    for identifier, kind, item in (("Body", "SweptSolid", solid), ("Axis", "Curve2D", axis(f, point, m))):
        ifcopenshell.api.geometry.assign_representation(
            f, product=wall, representation=f.createIfcShapeRepresentation(contexts[identifier], identifier, kind, [item]))
    return f, wall, contexts


def test_bent_wall_has_no_end_faces(tmp_path):
    """An L-shaped wall (its axis a polyline of two segments at right angles): each leg's end
    faces along the other leg's axis, yet it is no side face; the four sides are."""
    def profile(f, point, m):
        corners = [(0, -T / 2), (4 + T / 2, -T / 2), (4 + T / 2, 3), (4 - T / 2, 3), (4 - T / 2, T / 2), (0, T / 2)]
        return f.createIfcPolyline([point(x, y) for x, y in corners + corners[:1]])

    def axis(f, point, m):
        return f.createIfcPolyline([point(0, 0), point(4, 0), point(4, 3)])

    one_wall_model(tmp_path / "bent.ifc", profile, axis)[0].write(str(tmp_path / "bent.ifc"))
    plane_map, _ = import_ifc(tmp_path / "bent.ifc", BimImportConfig())
    expected = [((-1.0, 0.0, 0.0), 4 - T / 2, (3 - T / 2) * H), ((0.0, -1.0, 0.0), -T / 2, (4 + T / 2) * H),
                ((0.0, 1.0, 0.0), -T / 2, (4 - T / 2) * H), ((1.0, 0.0, 0.0), -4 - T / 2, (3 + T / 2) * H)]
    found = sorted((tuple(np.round(f.normal, 9) + 0.0), f.offset, f.area) for f in plane_map.faces)
    assert [n for n, _, _ in found] == [n for n, _, _ in expected]
    assert np.allclose([(d, a) for _, d, a in found], [(d, a) for _, d, a in expected])


R_C = 5.0  # radius of the curved wall's axis


def write_curved_wall(path, profile: str, schema="IFC4", length_unit="m", opening=False):
    """A model of one wall along a quarter circle, as authoring tools write curved walls: its
    axis an IfcTrimmedCurve of an IfcCircle of radius R_C about the origin from angle 0 to 90
    degrees, its body an extruded arc-shaped profile T thick, `profile` "composite" (an
    IfcCompositeCurve of trimmed circles and polylines, as Revit writes it) or "indexed" (an
    IfcIndexedPolyCurve with IfcArcIndex segments, as ArchiCAD does); with `opening`, a
    window 1 m wide and 1.2 m high through it at 45 degrees."""
    from bimgraph.geometry import make_pose

    def arc(f, point, m, radius):  # angles in radians, the file's plane angle unit
        circle = f.createIfcCircle(f.createIfcAxis2Placement2D(point(0, 0), None), m(radius))
        return f.createIfcTrimmedCurve(circle, [f.createIfcParameterValue(0.0)], [f.createIfcParameterValue(np.pi / 2)],
                                       True, "PARAMETER")

    outer, inner = R_C + T / 2, R_C - T / 2

    def arc_profile(f, point, m):
        if profile == "composite":
            segments = [(arc(f, point, m, outer), True), (f.createIfcPolyline([point(0, outer), point(0, inner)]), True),
                        (arc(f, point, m, inner), False), (f.createIfcPolyline([point(inner, 0), point(outer, 0)]), True)]
            return f.createIfcCompositeCurve([f.createIfcCompositeCurveSegment("CONTINUOUS", sense, c)
                                              for c, sense in segments], False)
        c = np.cos(np.pi / 4)
        corners = [(outer, 0), (outer * c, outer * c), (0, outer), (0, inner), (inner * c, inner * c), (inner, 0)]
        return f.createIfcIndexedPolyCurve(
            f.createIfcCartesianPointList2D([(m(x), m(y)) for x, y in corners]),
            [f.create_entity("IfcArcIndex", (1, 2, 3)), f.create_entity("IfcLineIndex", (3, 4)),
             f.create_entity("IfcArcIndex", (4, 5, 6)), f.create_entity("IfcLineIndex", (6, 1))], False)

    f, wall, contexts = one_wall_model(path, arc_profile, lambda f, point, m: arc(f, point, m, R_C), schema, length_unit)
    if opening:
        # A box 0.6 m deep centred on the wall at 45 degrees: x along the wall, y toward the centre.
        a = np.pi / 4
        along, inward = np.array([-np.sin(a), np.cos(a), 0.0]), -np.array([np.cos(a), np.sin(a), 0.0])
        T_W_opening = make_pose(np.column_stack([along, inward, [0.0, 0.0, 1.0]]),
                                R_C * np.array([np.cos(a), np.sin(a), 0.0]) - 0.5 * along + [0.0, 0.0, 0.9])
        add_opening(f, wall, T_W_opening, contexts["Body"], length=1.0, height=1.2, thickness=0.6, offset=-0.3)
    f.write(str(path))


@pytest.mark.parametrize("profile, schema, unit", [("composite", "IFC4", "m"), ("composite", "IFC2X3", "mm"),
                                                   ("indexed", "IFC4", "m")])
def test_curved_wall_is_planar_facets_within_the_tolerance(tmp_path, profile, schema, unit):
    """A curved wall's sides become planar facets, none farther than curved_face_tol_m (1 cm,
    plus the kernel's 1 mm tessellation) from the true arc, covering it end to end, facing out
    of the wall; its ends are no side faces; a window through it is cut out of the facets."""
    cfg = BimImportConfig()
    tol = 0.01 + 0.001  # curved_face_tol_m's default
    write_curved_wall(tmp_path / "curved.ifc", profile, schema, unit)
    messages = []
    plane_map, _ = import_ifc(tmp_path / "curved.ifc", cfg, log=messages.append)
    assert messages == []
    sides = {1.0: [f for f in plane_map.faces if np.hypot(*f.centre[:2]) > R_C + T / 2 - 2 * tol],
             -1.0: [f for f in plane_map.faces if np.hypot(*f.centre[:2]) < R_C - T / 2 + 2 * tol]}
    assert len(sides[1.0]) + len(sides[-1.0]) == len(plane_map.faces)  # the ends are no side faces
    for radius, side in ((R_C + T / 2, 1.0), (R_C - T / 2, -1.0)):
        facets = sides[side]
        # as few as the tolerance allows: a chord deviates 1 cm from an arc of 2 acos(1 - tol / r)
        fewest = np.ceil((np.pi / 2) / (2 * np.arccos(1 - 0.01 / radius)))
        assert fewest <= len(facets) <= 2 * fewest
        spans = []
        for face in facets:
            polygon = np.asarray(face.polygon)
            assert abs(face.normal[2]) < 1e-9 and np.abs(polygon @ face.normal + face.offset).max() < 1e-6
            angles = np.arctan2(polygon[:, 1], polygon[:, 0])
            spans.append((angles.min(), angles.max()))
            arc = np.linspace(angles.min(), angles.max(), 50)
            distance = radius * (np.cos(arc) * face.normal[0] + np.sin(arc) * face.normal[1]) + face.offset
            assert np.abs(distance).max() <= tol
            middle = np.mean(spans[-1])  # out of the wall: away from the centre outside, toward it inside
            assert side * (np.cos(middle) * face.normal[0] + np.sin(middle) * face.normal[1]) > 0.99
        spans.sort()
        assert spans[0][0] == pytest.approx(0.0, abs=1e-5) and spans[-1][1] == pytest.approx(np.pi / 2, abs=1e-5)
        assert all(abs(a[1] - b[0]) < 1e-5 for a, b in zip(spans, spans[1:]))  # no gap, no overlap
        assert sum(f.area for f in facets) == pytest.approx(radius * np.pi / 2 * H, rel=2e-3)

    write_curved_wall(tmp_path / "window.ifc", profile, schema, unit, opening=True)
    windowed, _ = import_ifc(tmp_path / "window.ifc", cfg)
    for side in (1.0, -1.0):
        def area(plane_map):
            return sum(f.area for f in plane_map.faces if side * (np.hypot(*f.centre[:2]) - R_C) > 0)
        assert area(plane_map) - area(windowed) == pytest.approx(1.0 * 1.2, rel=0.02)
