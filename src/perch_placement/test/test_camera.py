"""The camera simulator against hand-computed cases: visibility, range cap, distortion, covariance."""

import math

import numpy as np
import pytest
from placement_rooms import box_mesh

from perch_common.raycast import RayScene
from perch_common.symmetric import unpack
from perch_placement.camera import (
    covariance,
    distort,
    in_view,
    information6,
    max_covariance_norm,
    project,
    sigmas,
    undistort,
)
from perch_placement.config import CameraSpec
from perch_placement.fitness import Evaluator, point_score

CAM = CameraSpec()
LOOK_X = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])  # optical z = world +x, y = world -z


def visible(points, camera=CAM, rotation=LOOK_X, position=np.zeros(3), scene=None):
    points = np.asarray(points, np.float64)
    if scene is None:
        return in_view(camera, position[None], rotation[None], points)[0][0]
    return Evaluator(scene, points, camera).views(position, rotation)[0][0]


def test_r_max_is_the_feature_cap():
    # f = min(fx, fy) = 360 / tan(29 deg); R_max = f * 0.05 / 10.
    assert CAM.max_distance() == pytest.approx(360 / math.tan(math.radians(29)) * 0.005)
    assert CAM.max_distance() == pytest.approx(3.2473, abs=1e-4)
    assert CameraSpec(min_feature_pixels=1.0).max_distance() == 10.0  # capped by max_range


def test_visibility_hand_computed_cases():
    r_max = CAM.max_distance()
    half_h = math.radians(87 / 2)
    points = [
        [2.0, 0.0, 0.0],                                  # straight ahead: seen
        [-2.0, 0.0, 0.0],                                 # behind the camera
        [2.0, 2.0 * math.tan(half_h) * 0.98, 0.0],        # just inside the horizontal edge (y world = left)
        [2.0, 2.0 * math.tan(half_h) * 1.02, 0.0],        # just outside the sensor
        [2.0, 0.0, 2.0 * math.tan(math.radians(29)) * 1.05],  # above the vertical field of view
        [r_max * 0.99, 0.0, 0.0],                         # inside R_max
        [r_max * 1.01, 0.0, 0.0],                         # beyond R_max
        [0.15, 0.0, 0.0],                                 # closer than r_min
    ]
    assert visible(points).tolist() == [True, False, True, False, False, True, False, False]


def test_occluded_points_are_not_seen():
    wall = box_mesh((1.0, -0.5, -1.0), (1.1, 0.5, 1.0))  # a slab between x=1 and x=1.1, |y| < 0.5
    scene = RayScene(wall)
    seen = visible([[2.0, 0.0, 0.0], [2.0, 1.5, 0.0], [0.8, 0.0, 0.0]], scene=scene)
    assert seen.tolist() == [False, True, True]


def test_projection_matches_pinhole_and_distortion_round_trips():
    pix, ok = project(CAM, np.array([[0.0, 0.0, 2.0], [0.5, -0.25, 1.0]]))
    assert ok.all()
    assert pix[0] == pytest.approx([CAM.cx, CAM.cy])
    assert pix[1] == pytest.approx([CAM.cx + CAM.fx * 0.5, CAM.cy - CAM.fy * 0.25])
    coeffs = (-0.2, 0.05, 0.001, -0.002, -0.01)
    x, y = np.array([0.3, -0.6, 0.8]), np.array([0.2, 0.4, -0.5])
    xd, yd, ok = distort(x, y, coeffs)
    xu, yu = undistort(xd, yd, coeffs, iterations=50)
    assert ok.all() and xu == pytest.approx(x, abs=1e-6) and yu == pytest.approx(y, abs=1e-6)


def test_distortion_near_the_border():
    # Barrel distortion pulls border points inwards: a point just outside the pinhole sensor is
    # imaged once k1 < 0, and a point far outside, past the fold of the radial map, is not.
    barrel = CameraSpec(distortion=(-0.2, 0.0, 0.0, 0.0, 0.0))
    x_edge = (CAM.width - CAM.cx) / CAM.fx
    just_outside = [2.0, -2.0 * x_edge * 1.05, 0.0]  # world -y = image right
    assert visible([just_outside]).tolist() == [False]
    assert visible([just_outside], camera=barrel).tolist() == [True]
    # k1 = -0.2 folds back at r = 1/sqrt(0.6) = 1.29: beyond it d(r_d)/dr < 0.
    _, _, ok = distort(np.array([1.2, 1.4]), np.array([0.0, 0.0]), barrel.distortion)
    assert ok.tolist() == [True, False]
    folded = [1.0, -1.4, 0.0]  # r = 1.4: r_d = 1.4 * (1 - 0.2 * 1.96) = 0.85, would land on the sensor
    assert visible([folded], camera=barrel).tolist() == [False]


def test_covariance_closed_form_and_information_is_its_inverse():
    d = np.array([1.5, 3.0])
    u = np.array([[1.0, 0.0, 0.0], [0.0, 0.6, 0.8]])
    s_xy, s_z = sigmas(CAM, d)
    f = CAM.focal
    assert s_xy == pytest.approx(d * 0.08 / f)
    assert s_z == pytest.approx(d ** 2 * 0.08 / (f * 0.05))
    c = covariance(CAM, d, u)
    assert np.linalg.eigvalsh(c[1]) == pytest.approx(sorted([s_xy[1] ** 2, s_xy[1] ** 2, s_z[1] ** 2]))
    assert c[1] @ u[1] == pytest.approx(s_z[1] ** 2 * u[1])  # along the ray: sigma_z^2
    info = unpack(information6(CAM, d, u, scale=1.0))
    assert np.einsum("nij,njk->nik", info, c) == pytest.approx(np.broadcast_to(np.eye(3), (2, 3, 3)), abs=1e-9)


def test_fusion_of_two_orthogonal_cameras_matches_the_closed_form():
    d = 2.0
    s_xy, s_z = sigmas(CAM, np.float64(d))
    scale = max_covariance_norm(CAM)
    u = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    info = information6(CAM, np.array([d, d]), u).sum(axis=0)
    # Per axis the information adds: x and y get 1/s_z^2 + 1/s_xy^2, z gets 2/s_xy^2.
    expected = np.diag([1 / s_z ** 2 + 1 / s_xy ** 2, 1 / s_z ** 2 + 1 / s_xy ** 2, 2 / s_xy ** 2])
    fused = np.linalg.inv(unpack(info) / scale)
    assert fused == pytest.approx(np.linalg.inv(expected), rel=1e-9)
    score, ratio = point_score(info[None], np.array([True]))
    assert ratio[0] == pytest.approx(np.linalg.eigvalsh(fused).max() / scale, rel=1e-6)
    single = point_score(information6(CAM, np.array([d]), u[:1]), np.array([True]))[0]
    assert single[0] == pytest.approx(1 - s_z ** 2 / scale, rel=1e-9)  # one camera: 1 - (d / R_max)^4
    assert single[0] == pytest.approx(1 - (d / CAM.max_distance()) ** 4, rel=1e-9)
    assert score[0] > single[0]
