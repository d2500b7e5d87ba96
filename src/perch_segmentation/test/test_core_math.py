"""Sufficient statistics, eigen solutions, adjacency and outlines: exact numbers on small inputs."""

import numpy as np
import pytest

from perch_segmentation import stats as st
from perch_segmentation.adjacency import face_adjacency, unique_edges
from perch_segmentation.color import rgb_to_lab
from perch_segmentation.outline import outline


def test_triangle_second_moment_matches_monte_carlo():
    rng = np.random.default_rng(3)
    tri = rng.normal(size=(1, 3, 3))
    area = np.array([0.5 * np.linalg.norm(np.cross(tri[0, 1] - tri[0, 0], tri[0, 2] - tri[0, 0]))])
    table = st.face_table(tri, area, np.array([[0.0, 0, 1]]), None, None)
    r1, r2 = rng.random((2, 400000))
    flip = r1 + r2 > 1
    r1[flip], r2[flip] = 1 - r1[flip], 1 - r2[flip]
    points = tri[0, 0] + r1[:, None] * (tri[0, 1] - tri[0, 0]) + r2[:, None] * (tri[0, 2] - tri[0, 0])
    expected = area[0] * np.array([np.mean(points[:, i] * points[:, j])
                                   for i, j in ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2))])
    np.testing.assert_allclose(table[0, st.SECOND], expected, rtol=0.02, atol=1e-3)
    np.testing.assert_allclose(table[0, st.FIRST] / area[0], tri[0].mean(axis=0))


def test_plane_normals_of_a_tilted_noisy_patch():
    rng = np.random.default_rng(1)
    normal = np.array([1.0, 2.0, 2.0]) / 3.0
    u = np.cross(normal, [0, 0, 1.0])
    u /= np.linalg.norm(u)
    v = np.cross(normal, u)
    uv = rng.uniform(-1, 1, size=(300, 3, 2))
    tri = uv[..., :1] * u + uv[..., 1:] * v + rng.normal(0, 0.002, (300, 3, 1)) * normal + 5.0
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    area = 0.5 * np.linalg.norm(cross, axis=1)
    table = st.face_table(tri, area, cross / (2 * area[:, None]), None, None)
    merged = st.aggregate(table, np.zeros(300, np.int64), 1)
    _, normals = st.plane_normals(merged)
    winding = np.sign(merged[0, st.NORMAL] @ normal)
    assert normals[0] @ (winding * normal) > np.cos(np.radians(0.5))
    assert np.sqrt(st.plane_energy(merged)[0]) < 0.01


def test_face_adjacency_and_unique_edges():
    faces = np.array([[0, 1, 2], [2, 1, 3], [3, 1, 4], [5, 6, 7]])
    pairs = face_adjacency(faces, 8)
    assert sorted(map(tuple, pairs.tolist())) == [(0, 1), (1, 2)]
    # Non-manifold edge (0,1) shared by three faces: chained, all connected.
    faces = np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4]])
    assert len(face_adjacency(faces, 5)) == 2
    np.testing.assert_array_equal(unique_edges(np.array([0, 1, 2, 2]), np.array([1, 0, 2, 0]), 3), [[0, 1], [0, 2]])


def test_a_non_manifold_edge_chains_its_faces_in_face_order_on_every_cpu():
    """Faces sharing an edge are chained in their order in the mesh, whatever order the sort leaves equal
    keys in: numpy's unstable argsort orders ties by the CPU's SIMD level, and a real scan's segmentation
    differed between two machines by it (the apartment 21 against 20 surfaces, the ICL office)."""
    rng = np.random.default_rng(0)
    fans, blades = 5000, 4   # many ties, so a SIMD sort has room to reorder them
    hub = np.arange(fans)[:, None]
    tips = 2 * fans + np.arange(fans * blades).reshape(fans, blades)
    # Fan k: `blades` faces sharing the edge (2k, 2k+1); the faces listed in a shuffled order.
    faces = np.stack([2 * np.repeat(hub, blades, 1), 2 * np.repeat(hub, blades, 1) + 1, tips], -1).reshape(-1, 3)
    faces = faces[rng.permutation(len(faces))]
    pairs = face_adjacency(faces, 2 * fans + fans * blades)
    fan_of = faces[:, 0] // 2
    expected = []
    for k in range(fans):   # consecutive faces of a fan in face order: a chain
        members = np.flatnonzero(fan_of == k)
        expected += list(zip(members[:-1].tolist(), members[1:].tolist()))
    assert sorted(map(tuple, pairs.tolist())) == sorted(expected)


def test_lab_of_reference_colours():
    lab = rgb_to_lab(np.array([[255, 255, 255], [255, 0, 0], [0, 0, 0]], np.uint8))
    np.testing.assert_allclose(lab, [[100, 0, 0], [53.24, 80.09, 67.20], [0, 0, 0]], atol=0.02)


def test_outline_of_a_square_with_a_hole():
    # A 2 x 2 m square of 0.1 m cells with the middle 0.6 x 0.6 m missing.
    cells = [(i, j) for i in range(20) for j in range(20) if not (7 <= i < 13 and 7 <= j < 13)]
    tris = []
    for i, j in cells:
        a, b, c, d = (i * 0.1, j * 0.1), ((i + 1) * 0.1, j * 0.1), ((i + 1) * 0.1, (j + 1) * 0.1), (i * 0.1, (j + 1) * 0.1)
        tris += [(a, b, c), (a, c, d)]
    polygons = outline(np.array(tris), cell=0.02, simplify=0.01)
    assert len(polygons) == 1 and len(polygons[0]) == 2  # outer ring and one hole
    import shapely

    shape = shapely.Polygon(polygons[0][0], polygons[0][1:])
    assert shape.area == pytest.approx(4.0 - 0.36, abs=0.03)
    assert shapely.Polygon(polygons[0][1]).area == pytest.approx(0.36, abs=0.04)
