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


def test_closest_points(cube):
    closest, _, distance = cube.closest_points(np.array([[0.0, 0, 3.0], [0.0, 0.0, 0.5]]))
    assert np.allclose(closest[0], [0, 0, 1]) and distance[0] == pytest.approx(2.0)
    assert distance[1] == pytest.approx(0.5)


def test_the_same_hits_as_open3d_on_a_real_scan():
    """Embree through embreex and Open3D's RaycastingScene (the ray caster before it) agree on
    every first hit and every occlusion of random rays through the apartment scan (a batch large
    enough to be split over the ray threads)."""
    from perch_common.data import shared_file
    from perch_common.mesh import load_mesh
    from perch_common.open3d_loader import open3d

    path = shared_file("meshes", "apartment.ply")
    if path is None:
        pytest.skip("../shared/data not found: meshes/apartment.ply")
    mesh = load_mesh(path)
    rng = np.random.default_rng(3)
    low, high = mesh.bounds()
    origins = low + rng.random((100000, 3)) * (high - low)
    targets = low + rng.random((100000, 3)) * (high - low)
    o3d = open3d()
    reference = o3d.t.geometry.RaycastingScene()
    reference.add_triangles(o3d.core.Tensor(mesh.vertices.astype(np.float32)),
                            o3d.core.Tensor(mesh.faces.astype(np.uint32)))
    rays = o3d.core.Tensor(np.hstack([origins, targets - origins]).astype(np.float32))
    expected = reference.cast_rays(rays)
    hits = RayScene(mesh).cast(origins, targets - origins)
    face = expected["primitive_ids"].numpy().astype(np.int64)
    face[face == np.iinfo(np.uint32).max] = MISS
    assert (hits.face == face).all() and hits.hit.mean() > 0.5
    np.testing.assert_allclose(hits.distance[hits.hit], expected["t_hit"].numpy()[hits.hit], rtol=1e-5)
    np.testing.assert_allclose(np.abs(np.einsum("ij,ij->i", hits.normal[hits.hit],
                                                expected["primitive_normals"].numpy()[hits.hit])), 1.0, atol=1e-4)
    blocked = reference.test_occlusions(rays, tnear=0.0, tfar=1.0).numpy().astype(bool)
    assert (RayScene(mesh).occluded(origins, targets, epsilon=0.0) == blocked).all()


def test_a_batch_split_over_threads_answers_as_ray_by_ray(cube):
    from perch_common.raycast import PARALLEL_RAYS

    rng = np.random.default_rng(5)
    origins, targets = rng.uniform(-3, 3, (PARALLEL_RAYS + 999, 3)), rng.uniform(-3, 3, (PARALLEL_RAYS + 999, 3))
    whole, hits = cube.occluded(origins, targets), cube.cast(origins, targets - origins)
    pieces = [slice(i, i + 5000) for i in range(0, len(origins), 5000)]   # each below the split size
    assert (whole == np.concatenate([cube.occluded(origins[p], targets[p]) for p in pieces])).all()
    assert (hits.face == np.concatenate([cube.cast(origins[p], targets[p] - origins[p]).face for p in pieces])).all()
    assert 0.2 < whole.mean() < 0.8


def test_empty_batches(cube):
    assert cube.cast(np.zeros((0, 3)), np.zeros((0, 3))).face.shape == (0,)
    assert cube.occluded(np.zeros((0, 3)), np.zeros((0, 3))).shape == (0,)
