"""The segment stage's cheaper paths give the straightforward code's answers, float for float.

Each reference below is the code the fast path replaced (np.roll / np.linalg.norm / np.cross, and
make_valid on every outline, a cross product per surface); segment_mesh with the references patched in must match exactly.
"""

from __future__ import annotations

import numpy as np
import pytest
import shapely

from perch_common.scene_generator import generate_scene
from perch_segmentation import core, outline
from perch_segmentation import surfaces as step3
from perch_segmentation.config import SegmentationConfig


def reference_edge_lengths(tri: np.ndarray) -> np.ndarray:
    return np.linalg.norm(tri - np.roll(tri, 1, axis=1), axis=2)


def reference_shrink(tri: np.ndarray, inset: float, edges=None) -> np.ndarray:
    lengths = np.linalg.norm(np.roll(tri, -1, axis=1) - np.roll(tri, 1, axis=1), axis=2)
    perimeter = lengths.sum(axis=1)
    incentre = (lengths[:, :, None] * tri).sum(axis=1) / perimeter[:, None]
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    area2 = np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    radius = area2 / perimeter
    scale = np.clip((radius - inset) / np.maximum(radius, 1e-12), 0.0, 1.0)
    return incentre[:, None] + (tri - incentre[:, None]) * scale[:, None, None]


def reference_reliable_face_normals(triangles: np.ndarray, normals: np.ndarray) -> np.ndarray:
    edges = triangles - np.roll(triangles, 1, axis=1)
    longest2 = np.einsum("fij,fij->fi", edges, edges).max(axis=1)
    cross = np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0])
    twice_area = np.sqrt(np.einsum("ij,ij->i", cross, cross))
    sliver = twice_area <= core.SLIVER_HEIGHT_RATIO * longest2
    return np.where(sliver[:, None], 0.0, normals)


def random_triangles(seed: int, count: int, dims: int, scale: float) -> np.ndarray:
    rng = np.random.default_rng(seed)
    tri = rng.normal(size=(count, 3, dims)) * scale
    tri[: count // 10, 2] = tri[: count // 10, 1]  # degenerate: repeated corner
    tri[count // 10: count // 5, 2] = 0.5 * (tri[count // 10: count // 5, 0] + tri[count // 10: count // 5, 1])
    return tri


@pytest.mark.parametrize("scale", [1e-3, 1.0, 300.0])
def test_edge_lengths_and_shrink_are_the_straightforward_floats(scale):
    tri = random_triangles(7, 5000, 2, scale)
    edges = outline._edge_lengths(tri)
    assert np.array_equal(edges, reference_edge_lengths(tri))
    with np.errstate(invalid="ignore", divide="ignore"):
        assert np.array_equal(outline._shrink(tri, 0.5, edges), reference_shrink(tri, 0.5), equal_nan=True)
        assert np.array_equal(outline._shrink(tri, 0.5), reference_shrink(tri, 0.5), equal_nan=True)


@pytest.mark.parametrize("scale", [1e-3, 1.0, 300.0])
def test_reliable_face_normals_are_the_straightforward_floats(scale):
    tri = random_triangles(3, 5000, 3, scale)
    normals = np.random.default_rng(4).normal(size=(5000, 3))
    assert np.array_equal(core.reliable_face_normals(tri, normals), reference_reliable_face_normals(tri, normals))


def reference_polygons(rings, parents):
    polygons = []
    for k in np.flatnonzero(parents < 0):
        if len(rings[k]) < 3:
            continue
        holes = [rings[h] for h in np.flatnonzero(parents == k) if len(rings[h]) >= 3]
        polygons.append(shapely.Polygon(rings[k], holes))
    return polygons


def always_make_valid(monkeypatch):
    """The straightforward outline: every shape through make_valid, a Polygon built per outer ring."""
    monkeypatch.setattr(shapely, "is_valid", lambda shape: False)
    monkeypatch.setattr(outline, "_polygons", reference_polygons)


def square_ring(inner: float, outer: float) -> np.ndarray:
    """Triangles of the square annulus between half-widths inner and outer (a polygon with a hole)."""
    a = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1.0]])
    tris = []
    for k in range(4):
        i0, i1, o0, o1 = a[k] * inner, a[(k + 1) % 4] * inner, a[k] * outer, a[(k + 1) % 4] * outer
        tris += [[o0, o1, i1], [o0, i1, i0]]
    return np.array(tris)


def test_outline_of_overlapping_and_touching_triangles_matches_make_valid_always(monkeypatch):
    rng = np.random.default_rng(11)
    soups = [rng.uniform(0, 2.0, size=(40, 3, 2)),                     # overlapping, holes, pieces
             np.array([[[0, 0], [1, 0], [0, 1]], [[1, 0], [2, 0], [1, 1.0]]]),  # touching at a corner
             np.array([[[0, 0], [3, 0], [0, 3]], [[0.5, 0.5], [1.5, 0.5], [0.5, 1.5]]]),  # overlap
             np.concatenate([square_ring(0.5, 1.0), square_ring(2.0, 2.5), square_ring(0.1, 0.3) + 3.0])]
    fast = [outline.outline(uv, 0.05, 0.02) for uv in soups]
    always_make_valid(monkeypatch)
    slow = [outline.outline(uv, 0.05, 0.02) for uv in soups]
    assert_same_polygons(fast, slow)


def assert_same_polygons(a, b):
    assert len(a) == len(b)
    for x, y in zip(a, b):
        assert len(x) == len(y)
        for px, py in zip(x, y):
            assert len(px) == len(py)
            for rx, ry in zip(px, py):
                assert np.array_equal(np.asarray(rx), np.asarray(ry))


def summary(result):
    return result.face_labels, [(s.id, s.face_indices, s.frame.origin, s.frame.axis_u, s.frame.axis_v,
                                 s.frame.normal, s.area, s.rms_distance, s.mean_color, int(s.surface_class),
                                 s.boundary) for s in result.surfaces]


@pytest.mark.parametrize("kind,seed,holes", [("apartment", 4, 0), ("room", 3, 4)])
def test_segment_mesh_matches_the_straightforward_code(monkeypatch, kind, seed, holes):
    mesh = generate_scene(seed, kind, holes=holes).mesh
    labels, surfaces = summary(core.segment_mesh(mesh, SegmentationConfig()))
    always_make_valid(monkeypatch)
    monkeypatch.setattr(outline, "_edge_lengths", reference_edge_lengths)
    monkeypatch.setattr(outline, "_shrink", reference_shrink)
    monkeypatch.setattr(core, "reliable_face_normals", reference_reliable_face_normals)
    monkeypatch.setattr(step3, "frames_of", reference_frames_of)
    mesh = generate_scene(seed, kind, holes=holes).mesh
    ref_labels, ref_surfaces = summary(core.segment_mesh(mesh, SegmentationConfig()))
    assert np.array_equal(labels, ref_labels)
    assert len(surfaces) == len(ref_surfaces)
    for s, r in zip(surfaces, ref_surfaces):
        for x, y in zip(s[:-1], r[:-1]):
            assert np.array_equal(np.asarray(x), np.asarray(y))
        assert_same_polygons(s[-1], r[-1])


def reference_frames_of(table, centre):
    from perch_common.types import PlaneFrame
    from perch_segmentation import stats as st

    centroid, values, vectors = st.pca_frames(table)
    normals = st.oriented_normals(table, vectors)
    frames = []
    for k in range(len(table)):
        u = vectors[k, :, 2]
        v = np.cross(normals[k], u)
        frames.append(PlaneFrame(centroid[k] + centre, u, v / np.linalg.norm(v), normals[k]))
    return frames, np.sqrt(values[:, 0])


def test_frames_are_the_straightforward_floats():
    from perch_segmentation import stats as st
    from perch_segmentation.surfaces import frames_of

    rng = np.random.default_rng(5)
    tri = rng.normal(size=(3000, 3, 3)) * np.array([3.0, 2.0, 0.05])
    table = st.aggregate(st.face_table(tri, np.abs(rng.normal(size=3000)) + 0.01, rng.normal(size=(3000, 3)),
                                       None, None), rng.integers(0, 300, 3000), 300)
    centre = np.array([1.5, -2.0, 0.25])
    frames, rms = frames_of(table, centre)
    ref_frames, ref_rms = reference_frames_of(table, centre)
    assert np.array_equal(rms, ref_rms)
    for f, r in zip(frames, ref_frames, strict=True):
        for name in ("origin", "axis_u", "axis_v", "normal"):
            assert np.array_equal(getattr(f, name), getattr(r, name))
