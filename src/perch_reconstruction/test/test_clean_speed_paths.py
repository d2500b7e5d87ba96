"""The clean stage's fast paths give exactly the answers of the straightforward code they replace:
the same cleaned mesh (vertices, faces, colours), the same report numbers and warnings, on generated
rooms, the apartment scan and meshes with defects (flipped faces, needles, duplicate vertices and
faces, degenerate faces, small pieces, unused vertices). The straightforward code is kept here as the
reference: np.unique where the fast paths sort once, the vertex graph's edges for the pieces, whole-
array corner copies for cross products and edge lengths."""

from __future__ import annotations

import numpy as np
import pytest

from perch_common import mesh_health
from perch_common.data import shared_file
from perch_common.mesh import Mesh, load_mesh
from perch_common.mesh_health import inspect_health, needle_mask, winding_flips
from perch_reconstruction import cleaning, mesh_ops
from perch_reconstruction.cleaning import clean_mesh_with_report
from perch_reconstruction.config import ReconstructionConfig

# --- the straightforward code -------------------------------------------------------------------


def reference_cells(points: np.ndarray, cell: float) -> tuple[np.ndarray, int]:
    key = np.floor((points - points.min(axis=0)) / cell).astype(np.int64)
    span = key.max(axis=0) + 1
    linear = (key[:, 0] * span[1] + key[:, 1]) * span[2] + key[:, 2]
    unique, first, inverse = np.unique(linear, return_index=True, return_inverse=True)
    if len(unique) == len(points):
        return np.arange(len(points)), len(points)
    rank = np.empty(len(unique), np.int64)
    rank[np.argsort(first)] = np.arange(len(unique))
    return rank[inverse.ravel()], len(unique)


def reference_remap_faces(mesh: Mesh, faces: np.ndarray) -> Mesh:
    keep = (faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 0] != faces[:, 2])
    faces = faces[keep]
    _, first_face = np.unique(np.sort(faces, axis=1), axis=0, return_index=True)
    faces = faces[np.sort(first_face)]
    return mesh_ops._drop_unused(Mesh(mesh.vertices, faces, mesh.vertex_colors, mesh.vertex_normals,
                                      frame_id=mesh.frame_id))


def reference_weld_vertices(mesh: Mesh, distance: float) -> Mesh:
    inverse, count = reference_cells(mesh.vertices, max(distance, 1e-12))
    if count == mesh.num_vertices:
        return reference_remap_faces(Mesh(mesh.vertices, mesh.faces, mesh.vertex_colors, frame_id=mesh.frame_id),
                                     mesh.faces)
    return mesh_ops._remap(mesh, inverse, count, average=False)


def reference_remove_small_pieces(mesh: Mesh, min_diameter: float) -> tuple[Mesh, int]:
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    n, f = mesh.num_vertices, mesh.faces
    rows, cols = np.concatenate([f[:, 0], f[:, 1]]), np.concatenate([f[:, 1], f[:, 2]])
    count, label = connected_components(coo_matrix((np.ones(len(rows), np.int8), (rows, cols)), shape=(n, n)),
                                        directed=False)
    order = np.argsort(label, kind="stable")
    starts = np.searchsorted(label[order], np.arange(count))
    ordered = mesh.vertices[order]
    lo, hi = np.minimum.reduceat(ordered, starts), np.maximum.reduceat(ordered, starts)
    keep = (np.linalg.norm(hi - lo, axis=1) >= min_diameter)[label[f[:, 0]]]
    removed = int((~keep).sum())
    return (mesh if removed == 0 else mesh.submesh(keep)), removed


def reference_cross(mesh: Mesh) -> np.ndarray:
    if "cross" not in mesh._cache:
        first = mesh.vertices[mesh.faces[:, 0]]
        u, v = mesh.vertices[mesh.faces[:, 1]] - first, mesh.vertices[mesh.faces[:, 2]] - first
        cross = np.empty_like(u)
        cross[:, 0] = u[:, 1] * v[:, 2] - u[:, 2] * v[:, 1]
        cross[:, 1] = u[:, 2] * v[:, 0] - u[:, 0] * v[:, 2]
        cross[:, 2] = u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0]
        mesh._cache["cross"] = cross
    return mesh._cache["cross"]


def reference_needle_mask(mesh: Mesh) -> np.ndarray:
    if mesh.num_faces == 0:
        return np.zeros(0, bool)
    corner = [mesh.vertices[mesh.faces[:, i]] for i in range(3)]
    lengths = np.empty((mesh.num_faces, 3))
    for i in range(3):
        edge = corner[(i + 1) % 3] - corner[i]
        lengths[:, i] = edge[:, 0] * edge[:, 0] + edge[:, 1] * edge[:, 1] + edge[:, 2] * edge[:, 2]
    np.sqrt(lengths, out=lengths)
    longest = lengths.max(axis=1)
    typical = float(np.median(lengths))
    needles = np.flatnonzero(longest > mesh_health.NEEDLE_LENGTH * typical)
    altitude = Mesh(mesh.vertices, mesh.faces[needles]).face_areas() * 2.0 / np.maximum(longest[needles], 1e-300)
    mask = np.zeros(mesh.num_faces, bool)
    mask[needles] = altitude < mesh_health.NEEDLE_ASPECT * longest[needles]
    return mask


def reference_inconsistent_edges(faces: np.ndarray) -> int:
    """Edges used by exactly two faces that both run the same way."""
    directed = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    undirected = np.sort(directed, axis=1)
    group = np.unique(undirected, axis=0, return_inverse=True)[1].ravel()
    order = np.argsort(group, kind="stable")
    grouped = group[order]
    starts = np.flatnonzero(np.concatenate([[True], grouped[1:] != grouped[:-1]]))
    pairs = starts[np.diff(np.append(starts, len(grouped))) == 2]
    return int((directed[order[pairs], 0] == directed[order[pairs + 1], 0]).sum())


def reference_winding_flips(faces: np.ndarray, at_least: float = 0) -> tuple[np.ndarray, int]:
    inconsistent = reference_inconsistent_edges(faces) if len(faces) else 0
    if not inconsistent or inconsistent <= at_least:
        return np.zeros(len(faces), bool), inconsistent
    return winding_flips(faces)


def use_straightforward_code(patch: pytest.MonkeyPatch) -> None:
    patch.setattr(mesh_ops, "_cells", reference_cells)
    patch.setattr(mesh_ops, "_remap_faces", reference_remap_faces)
    patch.setattr(cleaning, "weld_vertices", reference_weld_vertices)
    patch.setattr(cleaning, "remove_small_pieces", reference_remove_small_pieces)
    patch.setattr(mesh_health, "needle_mask", reference_needle_mask)
    patch.setattr(mesh_health, "winding_flips", reference_winding_flips)
    patch.setattr(Mesh, "_cross", reference_cross)


# --- meshes -------------------------------------------------------------------------------------


def generated(kind: str, seed: int) -> Mesh:
    from perch_common.scene_generator import generate_scene

    return generate_scene(seed, kind).mesh


def defective(room: Mesh, seed: int = 5) -> Mesh:
    """`room` with every defect the clean stage repairs or says: 20 % of faces flipped, duplicate faces
    (other index order, other winding), exact and near duplicate vertices, degenerate faces (repeated
    index, zero area), needles across the room, small crumbs, and vertices no face uses."""
    rng = np.random.default_rng(seed)
    faces = room.faces.copy()
    flipped = rng.random(len(faces)) < 0.2
    faces[flipped] = faces[flipped][:, ::-1]
    pick = rng.choice(len(faces), len(faces) // 20, replace=False)
    duplicates = np.vstack([faces[pick[::2]][:, [1, 2, 0]], faces[pick[1::2]][:, ::-1]])
    vertices, colors = room.vertices, room.vertex_colors
    # every tenth vertex again (exactly, or 1 um off), used by a copy of one face through it
    again = np.arange(0, room.num_vertices, 10)
    copies = vertices[again] + (rng.random((len(again), 1)) < 0.5) * 1e-6
    users = np.array([np.flatnonzero((faces == v).any(axis=1))[0] for v in again[:200]])
    copied = faces[users].copy()
    for row, (v, new) in enumerate(zip(again[:200], len(vertices) + np.arange(200))):
        copied[row][copied[row] == v] = new
    n = len(vertices) + len(again)
    lo, hi = room.bounds()
    a, b = rng.uniform(lo, lo + 0.3 * (hi - lo), (40, 3)), rng.uniform(hi - 0.3 * (hi - lo), hi, (40, 3))
    needles = np.concatenate([a, b, (a + b) / 2 + 1e-7])
    needle_faces = n + np.arange(40)[:, None] + np.array([0, 40, 80])
    crumb = np.array([[0, 0, 0], [0.05, 0, 0], [0, 0.05, 0]]) + (lo + hi) / 2
    crumb_faces = n + 120 + np.array([[0, 1, 2]])
    line = (lo + hi) / 2 + np.array([[0.0, 0, 0], [0.5, 0, 0], [1.0, 0, 0]])   # a zero-area face
    unused = rng.uniform(lo, hi, (30, 3))
    degenerate = np.array([[faces[0, 0], faces[0, 0], faces[0, 1]], [n + 123, n + 124, n + 125]])
    all_vertices = np.vstack([vertices, copies, needles, crumb, line, unused])
    all_faces = np.vstack([faces, duplicates, copied, needle_faces, crumb_faces, degenerate])
    all_colors = None if colors is None else np.vstack(
        [colors, colors[again], np.full((len(all_vertices) - n, 3), 90, np.uint8)])
    order = rng.permutation(len(all_faces))
    return Mesh(all_vertices, all_faces[order], all_colors)


@pytest.fixture(scope="module")
def meshes() -> dict[str, Mesh]:
    room = generated("room", 1)
    found = {"room-1": room, "two_rooms-3": generated("two_rooms", 3), "room-1 with defects": defective(room),
             "apartment-4 with defects": defective(generated("apartment", 4), seed=9)}
    path = shared_file("meshes", "apartment.ply")
    if path is not None:
        found["apartment.ply"] = load_mesh(path)
    return found


CONFIGS = {"decimated": ReconstructionConfig(target_faces=4000),
           "not decimated": ReconstructionConfig(target_faces=0, gravity_align=False)}


def assert_same_clean(a: tuple[Mesh, cleaning.CleanReport], b: tuple[Mesh, cleaning.CleanReport]) -> None:
    (mesh_a, report_a), (mesh_b, report_b) = a, b
    np.testing.assert_array_equal(mesh_a.vertices, mesh_b.vertices)
    np.testing.assert_array_equal(mesh_a.faces, mesh_b.faces)
    assert (mesh_a.vertex_colors is None) == (mesh_b.vertex_colors is None)
    if mesh_a.vertex_colors is not None:
        np.testing.assert_array_equal(mesh_a.vertex_colors, mesh_b.vertex_colors)
    for name in ("faces_in", "faces_out", "pieces_removed_faces", "up_source", "up_confidence", "warnings"):
        assert getattr(report_a, name) == getattr(report_b, name), name
    np.testing.assert_array_equal(report_a.rotation, report_b.rotation)


def clean_both(mesh: Mesh, config: ReconstructionConfig, monkeypatch, gravity=None):
    """(fast, straightforward) cleans of `mesh`."""
    fast = clean_mesh_with_report(mesh, gravity, config)
    with monkeypatch.context() as patch:
        use_straightforward_code(patch)
        # a fresh mesh: nothing derived by the fast run
        plain = Mesh(mesh.vertices, mesh.faces, mesh.vertex_colors, mesh.vertex_normals, viewpoints=mesh.viewpoints)
        slow = clean_mesh_with_report(plain, gravity, config)
    return fast, slow


# --- the tests ----------------------------------------------------------------------------------


@pytest.mark.parametrize("config", CONFIGS, ids=str)
def test_the_clean_stage_gives_the_straightforward_answers(meshes, config, monkeypatch):
    for name, mesh in meshes.items():
        fast, slow = clean_both(mesh, CONFIGS[config], monkeypatch)
        assert_same_clean(fast, slow)
    # the defects were there to be repaired
    text = "; ".join(clean_both(meshes["room-1 with defects"], CONFIGS[config], monkeypatch)[0][1].warnings)
    for said in ("removed", "needle slivers", "re-wound"):
        assert said in text, text


def test_above_the_exact_face_key_the_hashed_duplicate_test_gives_the_same_answers(meshes, monkeypatch):
    """Meshes of over 2^21 vertices (the multi-storey building) test faces for duplicates by a hash:
    here every mesh does."""
    monkeypatch.setattr(mesh_ops, "EXACT_FACE_KEY_VERTICES", 16)
    for mesh in (meshes["room-1"], meshes["room-1 with defects"]):
        for config in CONFIGS.values():
            fast, slow = clean_both(mesh, config, monkeypatch)
            assert_same_clean(fast, slow)


def test_a_gravity_given_clean_is_the_same(meshes, monkeypatch):
    fast, slow = clean_both(meshes["two_rooms-3"], CONFIGS["decimated"], monkeypatch, gravity=np.array([0, 0, -1.0]))
    assert_same_clean(fast, slow)
    assert fast[1].up_source == "gravity"


def test_the_cleaned_mesh_is_a_copy_when_nothing_changes(meshes):
    room = meshes["room-1"]
    cleaned, report = clean_mesh_with_report(room, None, CONFIGS["not decimated"])
    assert report.warnings == [] and cleaned.num_faces == room.num_faces
    for mine in (cleaned.vertices, cleaned.faces, cleaned.vertex_colors):
        for given in (room.vertices, room.faces, room.vertex_colors):
            assert not np.may_share_memory(mine, given)


def test_the_mesh_health_report_is_the_same(meshes, monkeypatch):
    for mesh in meshes.values():
        fast = inspect_health(mesh)
        with monkeypatch.context() as patch:
            patch.setattr(mesh_health, "needle_mask", reference_needle_mask)
            patch.setattr(mesh_health, "winding_flips", reference_winding_flips)
            slow = inspect_health(Mesh(mesh.vertices, mesh.faces))
        assert vars(fast) == vars(slow)


def test_needles_and_cross_products_are_the_same_numbers(meshes):
    """Also where edges are too short for needles by a sample's bound (rooms), where that bound
    cannot tell (a room with one large wide triangle: its edges are far over the bound) and on rooms
    with needles."""
    room = meshes["room-1"]
    big = np.array([[0.0, 0, 0], [8, 0, 0], [4, 7, 0]]) + room.bounds()[0]
    wide = Mesh(np.vstack([room.vertices, big]), np.vstack([room.faces, room.num_vertices + np.array([[0, 1, 2]])]))
    assert not mesh_health._too_short_for_needles(wide.vertices, wide.faces)
    for mesh in [*meshes.values(), wide]:
        np.testing.assert_array_equal(needle_mask(mesh), reference_needle_mask(mesh))
        np.testing.assert_array_equal(Mesh(mesh.vertices, mesh.faces)._cross(),
                                      reference_cross(Mesh(mesh.vertices, mesh.faces)))


def test_winding_counts_on_tangled_faces():
    """Random faces on a few vertices: edges used once, twice (either way), three times and more,
    degenerate faces and loops; the count and the flips are the straightforward ones."""
    rng = np.random.default_rng(2)
    for trial in range(200):
        faces = rng.integers(0, 4 + trial % 12, (1 + trial % 40, 3))
        expected = reference_inconsistent_edges(faces)
        for at_least in (0, expected, expected + 1):
            flips, count = winding_flips(faces, at_least)
            want_flips, want = reference_winding_flips(faces, at_least)
            assert count == want == expected
            np.testing.assert_array_equal(flips, want_flips)


def test_cells_duplicates_and_pieces_on_small_cases(monkeypatch):
    rng = np.random.default_rng(4)
    for trial in range(100):
        points = rng.integers(0, 3 + trial % 7, (1 + trial % 50, 3)) * 0.1 + rng.random((1 + trial % 50, 3)) * 1e-3
        for cell in (1e-5, 0.05, 0.3):
            inverse, count = mesh_ops._cells(points, cell)
            want, want_count = reference_cells(points, cell)
            assert count == want_count
            np.testing.assert_array_equal(inverse, want)
        faces = rng.integers(0, len(points), (1 + trial % 30, 3))
        mesh = Mesh(points, faces)
        for limit in (mesh_ops.EXACT_FACE_KEY_VERTICES, 2):
            with monkeypatch.context() as patch:
                patch.setattr(mesh_ops, "EXACT_FACE_KEY_VERTICES", limit)
                fast, slow = mesh_ops._remap_faces(mesh, faces), reference_remap_faces(mesh, faces)
            np.testing.assert_array_equal(fast.faces, slow.faces)
            np.testing.assert_array_equal(fast.vertices, slow.vertices)
        for diameter in (0.05, 0.2):
            (fast, removed), (slow, want_removed) = (mesh_ops.remove_small_pieces(mesh, diameter),
                                                     reference_remove_small_pieces(mesh, diameter))
            assert removed == want_removed
            np.testing.assert_array_equal(fast.faces, slow.faces)


def test_face_areas_are_the_norm_of_the_cross_products(meshes):
    rng = np.random.default_rng(6)
    spread = Mesh(rng.standard_normal((3000, 3)) * 10.0 ** rng.uniform(-4, 4, (3000, 1)),
                  rng.integers(0, 3000, (70_000, 3)))
    for mesh in [*meshes.values(), spread]:
        expected = 0.5 * np.linalg.norm(reference_cross(Mesh(mesh.vertices, mesh.faces)), axis=1)
        np.testing.assert_array_equal(mesh.face_areas(), expected)
