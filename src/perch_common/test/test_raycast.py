"""Ray casting against analytic cases."""

import numpy as np
import pytest
import trimesh

from perch_common.mesh import Mesh
from perch_common.raycast import MISS, RayScene


@pytest.fixture(scope="module")
def cube():
    box = trimesh.creation.box((2.0, 2.0, 2.0))  # [-1, 1]^3
    return RayScene(Mesh(box.vertices, box.faces))


def test_first_hit_distance_and_normal(cube):
    hits = cube.cast(np.array([[-5.0, 0.2, 0.3], [0, 0, 0], [5, 5, 5]]), np.array([[1.0, 0, 0], [0, 0, 2.0], [1, 0, 0]]))
    assert hits.distance[0] == pytest.approx(4.0, abs=1e-5)
    assert np.allclose(hits.normal[0], [-1, 0, 0], atol=1e-6)
    assert hits.distance[1] == pytest.approx(0.5, abs=1e-5)  # non-unit direction: t in its units
    assert hits.face[2] == MISS and not hits.hit[2] and np.isinf(hits.distance[2])


def test_occlusion_of_segments(cube):
    origins = np.array([[-3.0, 0, 0], [-3.0, 0, 0], [-3.0, 0, 0], [0, 0, 0], [1.0, 0, 0]])
    targets = np.array([[3.0, 0, 0], [-1.5, 0, 0], [-3.0, 3.0, 0], [0.5, 0, 0], [3.0, 0, 0]])
    # through the cube, stops short, passes above, inside, starts on the surface (epsilon)
    assert cube.occluded(origins, targets).tolist() == [True, False, False, False, False]


def test_occlusion_epsilon_ignores_target_on_surface(cube):
    assert not cube.occluded(np.array([[-3.0, 0, 0]]), np.array([[-1.0, 0, 0]]), epsilon=1e-3)[0]
    assert cube.occluded(np.array([[-3.0, 0, 0]]), np.array([[-0.9, 0, 0]]), epsilon=1e-3)[0]


def test_closest_points_and_crossings(cube):
    closest, _, distance = cube.closest_points(np.array([[0.0, 0, 3.0], [0.0, 0.0, 0.5]]))
    assert np.allclose(closest[0], [0, 0, 1]) and distance[0] == pytest.approx(2.0)
    assert distance[1] == pytest.approx(0.5)
    crossings = cube.count_crossings(np.array([[0.0, 0, 0], [-3.0, 0.1, 0.1]]), np.array([[1.0, 0, 0], [1.0, 0, 0]]))
    assert crossings.tolist() == [1, 2]


def test_empty_batches(cube):
    assert cube.cast(np.zeros((0, 3)), np.zeros((0, 3))).face.shape == (0,)
    assert cube.occluded(np.zeros((0, 3)), np.zeros((0, 3))).shape == (0,)
