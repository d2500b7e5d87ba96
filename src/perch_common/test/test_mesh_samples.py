"""Surface samples: every point of the mesh lies within `reach` of a sample of its own face."""

import numpy as np
from scipy.spatial import cKDTree

from perch_common.mesh import Mesh
from perch_common.mesh_samples import MAX_SPLITS, mesh_samples, sample_mesh


def test_every_surface_point_is_within_reach_of_a_sample_of_its_face():
    rng = np.random.default_rng(4)
    # Small faces, faces a few spacings long and one longer than MAX_SPLITS spacings.
    vertices = np.vstack([rng.random((60, 3)) * 0.3, rng.random((30, 3)) * 1.5, [[0, 0, 0], [9.0, 0, 0], [0, 7.0, 0]]])
    faces = np.vstack([rng.integers(0, 60, (40, 3)), 60 + rng.integers(0, 30, (20, 3)), [[90, 91, 92]]])
    mesh = Mesh(vertices, faces)
    samples = sample_mesh(mesh, 0.05)
    assert samples.reach > 0.05 and samples.reach <= np.linalg.norm([9.0, -7.0]) / MAX_SPLITS + 1e-12
    u, v = rng.random((2, 200, 1))
    flip = (u + v) > 1
    u, v = np.where(flip, 1 - u, u), np.where(flip, 1 - v, v)
    for face in range(mesh.num_faces):
        a, b, c = mesh.vertices[mesh.faces[face]]
        points = a + u * (b - a) + v * (c - a)
        own = samples.points[(samples.face == face) | np.isin(np.arange(len(samples.points)), mesh.faces[face])]
        assert cKDTree(own).query(points)[0].max() <= samples.reach + 1e-12


def test_kept_with_the_mesh_and_read_only():
    mesh = Mesh(np.eye(3), np.array([[0, 1, 2]]))
    samples = mesh_samples(mesh, 0.1)
    assert mesh_samples(mesh, 0.1) is samples and mesh_samples(mesh, 0.2) is not samples
    assert not samples.points.flags.writeable
