"""A BCF topic's viewpoint on a wall face (`bimgraph.deviations.viewpoint`): it looks at the
wall, not at the window in its middle, and stands in the room, however shallow."""

import numpy as np
import pytest

from bimgraph.bim.planemap import BimFace, PlaneMap
from bimgraph.deviations.viewpoint import TARGET_MARGIN_M, face_target, first_hit, viewpoint


def wall(face_id: str, y: float, normal_y: float, holes=()) -> BimFace:
    """A face 4 m long and 2.7 m high on the plane y = `y`, facing +y or -y."""
    return BimFace(id=face_id, wall_guid=face_id, normal=(0.0, normal_y, 0.0), offset=-normal_y * y,
                   polygon=[(0.0, y, 0.0), (4.0, y, 0.0), (4.0, y, 2.7), (0.0, y, 2.7)], holes=list(holes))


# a window 1.2 x 1.2 m whose centre is the face's
WINDOW = [(1.4, 0.0, 0.75), (2.6, 0.0, 0.75), (2.6, 0.0, 1.95), (1.4, 0.0, 1.95)]


def test_the_target_is_on_the_wall_beside_its_window():
    face = wall("w", 0.0, 1.0, [WINDOW])
    target = face_target(face)
    assert abs(target[1]) < 1e-9  # on the face's plane
    x, z = target[0], target[2]
    in_window = 1.4 - TARGET_MARGIN_M < x < 2.6 + TARGET_MARGIN_M and 0.75 - TARGET_MARGIN_M < z < 1.95 + TARGET_MARGIN_M
    assert not in_window and 0.0 < x < 4.0 and 0.0 < z < 2.7
    # the nearest such point to the centre (2, 1.35): beside the window or above or below it
    assert np.linalg.norm([x - 2.0, z - 1.35]) == pytest.approx(0.6 + TARGET_MARGIN_M, abs=0.02)
    # a plain wall is looked at in its centre
    np.testing.assert_allclose(face_target(wall("p", 0.0, 1.0)), [2.0, 0.0, 1.35], atol=1e-9)
    # a face too narrow for the margin (a pier 0.4 m wide): its middle
    pier = BimFace(id="pier", wall_guid="pier", normal=(0.0, 1.0, 0.0), offset=0.0,
                   polygon=[(0.0, 0.0, 0.0), (0.4, 0.0, 0.0), (0.4, 0.0, 2.7), (0.0, 0.0, 2.7)])
    np.testing.assert_allclose(face_target(pier)[[0, 1]], [0.2, 0.0], atol=0.01)


def test_the_camera_stands_in_a_room_shallower_than_the_view_distance():
    face, opposite = wall("w", 0.0, 1.0), wall("o", 1.5, -1.0)
    plan = PlaneMap(faces=[face, opposite])
    camera, target = viewpoint(plan, face, 3.0, 0.5)
    assert 0.0 < camera[1] < 1.5 and camera[2] > target[2]
    # nor does it see through a window of the opposite face (a BIM tool draws the window)
    window = [(x, 1.5, z) for x, _, z in WINDOW]
    camera, _ = viewpoint(PlaneMap(faces=[face, wall("o", 1.5, -1.0, [window])]), face, 3.0, 0.5)
    assert 0.0 < camera[1] < 1.5
    # a deep room: the full distance
    camera, _ = viewpoint(PlaneMap(faces=[face, wall("o", 5.0, -1.0)]), face, 3.0, 0.5)
    assert camera[1] == pytest.approx(3.0)


def test_the_first_hit_skips_faces_behind_and_beside_the_ray():
    plan = PlaneMap(faces=[wall("w", 0.0, 1.0), wall("behind", -1.0, 1.0), wall("o", 2.0, -1.0)])
    assert first_hit(plan, np.array([2.0, 0.0, 1.0]), np.array([0.0, 1.0, 0.0]), 10.0) == pytest.approx(2.0)
    # beside the opposite face's extent, nothing stops it
    assert first_hit(plan, np.array([6.0, 0.0, 1.0]), np.array([0.0, 1.0, 0.0]), 10.0) == 10.0
