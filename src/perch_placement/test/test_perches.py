"""Drone and camera poses on regions, the gimbal window, encodings and feasibility."""

import math

import numpy as np
import pytest
from placement_rooms import box_room, rectangle_region

from perch_common.types import ExclusionZone, SurfaceClass
from perch_placement.config import DroneSpec
from perch_placement.perches import Perches

TARGET = np.array([3.0, 2.5, 0.8])


def perches(regions=None, **drone):
    regions = regions if regions is not None else box_room()[1]
    return Perches(regions, TARGET, DroneSpec(**drone))


def test_wall_drone_faces_down_and_its_camera_looks_into_the_room():
    p = perches()
    wall = 0  # y = 0 wall, normal +y
    perch = p.pose(np.array([wall]), np.array([[2.0, 0.0, 2.0]]), np.array([[0.5, 0.5]]))
    rot = perch.drone_rotation[0]
    assert rot[:, 0] == pytest.approx([0, 0, -1])        # forward: gravity down
    assert rot[:, 2] == pytest.approx([0, 1, 0])         # z: the wall normal
    assert np.linalg.det(rot) == pytest.approx(1.0)
    assert perch.camera_position[0] == pytest.approx([2.0, 0.1, 2.0])  # camera offset along the normal
    cam = perch.camera_rotation[0]
    assert cam.T @ cam == pytest.approx(np.eye(3), abs=1e-12) and np.linalg.det(cam) == pytest.approx(1.0)
    assert cam[:, 2] @ np.array([0, 1, 0]) > 0.5          # looks into the room
    assert cam[:, 1] @ np.array([0, 0, -1]) > 0.5         # image down is roughly world down (upright view)


def test_ceiling_drone_faces_the_target():
    p = perches()
    ceiling = 4
    position = np.array([[1.0, 1.0, 3.0]])
    rot = p.drone_rotations(np.array([ceiling]), position)[0]
    towards = (TARGET - position[0])[:2] / np.linalg.norm((TARGET - position[0])[:2])
    assert rot[:2, 0] == pytest.approx(towards) and rot[2, 0] == pytest.approx(0.0, abs=1e-12)
    assert rot[:, 2] == pytest.approx([0, 0, -1])


def test_centred_gimbal_points_at_the_target_centre():
    p = perches(target_deviation_deg=5)  # a narrow window: never clipped by the +-45 deg gimbal here
    for region, point in ((0, [1.5, 0.0, 2.2]), (3, [6.0, 1.0, 1.0]), (4, [3.5, 3.0, 3.0])):
        perch = p.pose(np.array([region]), np.array([point], float), np.array([[0.5, 0.5]]))
        to_target = TARGET - perch.camera_position[0]
        axis = perch.camera_rotation[0][:, 2]
        within = math.degrees(math.acos(min(1.0, axis @ to_target / np.linalg.norm(to_target))))
        assert within == pytest.approx(0.0, abs=1e-5)
        window = p.gimbal_window(perch.camera_position, perch.drone_rotation)[0]
        assert -math.pi / 4 - 1e-12 <= window[0] <= window[1] <= math.pi / 4 + 1e-12
        assert window[1] - window[0] == pytest.approx(math.radians(10))
    wide = perches()  # +-40 deg: clipped by the gimbal on one side, still within the range
    window = wide.gimbal_window(np.array([[1.5, 0.1, 2.2]]), wide.drone_rotations(np.array([0]), np.array([[1.5, 0, 2.2]])))
    assert -math.pi / 4 - 1e-12 <= window[0, 0] < window[0, 1] == pytest.approx(math.pi / 4)


def test_window_collapses_to_the_gimbal_limit_when_the_target_is_out_of_reach():
    p = perches(target_deviation_deg=10)
    # On the y=0 wall far to the side of the target: the direction is ~63 deg off the normal.
    perch = p.pose(np.array([0]), np.array([[8.0, 0.0, 0.8]]), np.array([[0.0, 0.5]]))
    window = p.gimbal_window(perch.camera_position, perch.drone_rotation)[0]
    assert window[0] == window[1] == pytest.approx(-math.pi / 4)  # optical x is world +x here


def test_gimbal_window_without_targeting_is_the_full_range():
    p = perches(gimbal_limited_targeting=False, pan_range_deg=60, tilt_range_deg=30)
    perch = p.pose(np.array([0]), np.array([[2.0, 0.0, 2.0]]), np.array([[0.0, 1.0]]))
    assert perch.pan[0] == pytest.approx(-math.radians(30)) and perch.tilt[0] == pytest.approx(math.radians(15))


def test_plane_encoding_round_trips_and_detects_outside_points():
    region = rectangle_region(7, (0, 0, 1.5), (1, 0, 0), 2.0, 1.0)
    # An L-shaped region: the rectangle minus its upper-right quarter.
    region.polygons = [[np.array([[-1, -0.5], [1, -0.5], [1, 0], [0, 0], [0, 0.5], [-1, 0.5]], float)]]
    p = perches([region, rectangle_region(8, (2, 5, 1.5), (0, -1, 0), 1.0, 1.0)])
    x = np.array([[0.1, 0.25, 0.25, 0.5, 0.5], [0.1, 0.9, 0.9, 0.5, 0.5]])
    decoded = p.decode(x)
    assert decoded.region.tolist() == [0, 0]
    assert decoded.inside.tolist() == [True, False]
    enc = p.encode_position(0, decoded.drone_position[0])
    again = p.decode(np.concatenate([enc, [0.5, 0.5]]))
    assert again.region[0] == 0 and again.drone_position[0] == pytest.approx(decoded.drone_position[0])


def test_area_weighted_region_selector():
    big = rectangle_region(0, (0, 0, 1.5), (1, 0, 0), 3.0, 1.0)   # 3 m^2
    small = rectangle_region(1, (2, 5, 1.5), (0, -1, 0), 1.0, 1.0)  # 1 m^2
    p = perches([big, small])
    assert p.region_of(np.array([0.0, 0.74, 0.76, 1.0])).tolist() == [0, 0, 1, 1]


def test_spacing_and_exclusion_make_perches_infeasible():
    p = perches(min_spacing=1.0)
    points = np.array([[2.0, 0.0, 2.0], [2.9, 0.0, 2.0], [4.5, 0.0, 2.0]])
    perch = p.pose(np.zeros(3, int), points, np.full((3, 2), 0.5))
    ok = p.feasible(perch, np.array([[2.0, 0.0, 1.5]]), (ExclusionZone(np.array([4.5, 0.0, 2.2]), 0.5),))
    assert ok.tolist() == [False, True, False]


def test_regions_without_polygons_are_rejected():
    region = rectangle_region(0, (0, 0, 1), (1, 0, 0), 1.0, 1.0, SurfaceClass.WALL)
    region.polygons = []
    with pytest.raises(ValueError, match="region 0 has no polygon"):
        perches([region])
    with pytest.raises(ValueError, match="no perch regions"):
        perches([])
