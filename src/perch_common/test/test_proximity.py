"""Exact sphere clearance of points from a mesh, against Open3D's closest points."""

import numpy as np
import pytest
import trimesh

from perch_common.mesh import Mesh
from perch_common.proximity import clear_of_mesh, point_triangle_distance
from perch_common.raycast import RayScene


def test_point_triangle_distance_in_every_region():
    triangle = np.array([[0.0, 0, 0], [2.0, 0, 0], [0.0, 2.0, 0]])
    points = np.array([[0.5, 0.5, 3.0],     # above the inside: the plane
                       [1.0, -1.0, 0.0],    # beside edge ab
                       [-1.0, -1.0, 1.0],   # beyond corner a
                       [2.0, 2.0, 0.0],     # beside the hypotenuse
                       [0.2, 0.2, 0.0]])    # on the triangle
    expected = [3.0, 1.0, np.sqrt(3.0), np.sqrt(2.0), 0.0]
    np.testing.assert_allclose(point_triangle_distance(points, np.repeat(triangle[None], 5, axis=0)), expected,
                               atol=1e-12)
    degenerate = np.array([[[0.0, 0, 0], [1.0, 0, 0], [2.0, 0, 0]]])   # a segment: distance to it
    assert point_triangle_distance(np.array([[1.0, 1.0, 0.0]]), degenerate)[0] == pytest.approx(1.0)


def _random_points(mesh: Mesh, count: int, seed: int) -> np.ndarray:
    """Half anywhere in the bounds, half in front of faces (where a drone's standoff points are)."""
    rng = np.random.default_rng(seed)
    low, high = mesh.bounds()
    faces = rng.integers(0, mesh.num_faces, count // 2)
    front = mesh.face_centroids()[faces] + mesh.face_normals()[faces] * rng.uniform(0.1, 0.7, (len(faces), 1))
    return np.vstack([low + rng.random((count - len(faces), 3)) * (high - low), front])


def _agrees_with_open3d(mesh: Mesh, points: np.ndarray, radius: float) -> None:
    distance = RayScene(mesh).closest_points(points)[2]
    decided = np.abs(distance - radius) > 1e-5            # Open3D measures in float32
    clear = clear_of_mesh(mesh, points, radius, large_query=len(points) + 1)   # the sampled-triangle test
    assert (clear[decided] == (distance[decided] >= radius)).all()
    assert 0.05 < clear.mean() < 0.95                     # both answers occur
    by_open3d = clear_of_mesh(mesh, points, radius, large_query=len(points))   # a large query: Open3D's
    assert (by_open3d[decided] == clear[decided]).all()


def test_clearance_of_a_mix_of_huge_and_small_triangles():
    """A room modelled by 12 big triangles with a finely meshed box in it: the few huge triangles
    must not be missed, nor widen the search among the small ones."""
    room = trimesh.creation.box((8.0, 6.0, 3.0))
    clutter = trimesh.creation.icosphere(subdivisions=4, radius=0.4)
    clutter.apply_translation([1.0, 0.5, -0.5])
    mesh = Mesh(np.vstack([room.vertices, clutter.vertices]),
                np.vstack([room.faces, clutter.faces + len(room.vertices)]))
    points = _random_points(mesh, 20000, seed=1)
    for radius in (0.35, 0.1):
        _agrees_with_open3d(mesh, points, radius)


@pytest.mark.data
@pytest.mark.parametrize("name", ["apartment.ply", "icl_office_kt2.obj"])
def test_clearance_on_real_scans_matches_open3d(name):
    from perch_common.data import shared_file
    from perch_common.mesh import load_mesh

    path = shared_file("meshes", name)
    if path is None:
        pytest.skip(f"../shared/data not found: meshes/{name}")
    mesh = load_mesh(path)
    points = _random_points(mesh, 20000, seed=2)
    for radius in (0.35, 0.1):
        _agrees_with_open3d(mesh, points, radius)


def test_nothing_to_test():
    mesh = Mesh(np.eye(3), np.array([[0, 1, 2]]))
    assert clear_of_mesh(mesh, np.zeros((0, 3)), 0.3).shape == (0,)
    assert clear_of_mesh(Mesh(np.zeros((0, 3)), np.zeros((0, 3))), np.ones((2, 3)), 0.3).all()
