"""clean_mesh: duplicates merged, small pieces removed, decimation with colours, gravity alignment."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from perch_common.mesh import Mesh, MeshError
from perch_reconstruction.cleaning import clean_mesh_with_report
from perch_reconstruction.core import ReconstructionConfig, clean_mesh
from perch_reconstruction.mesh_ops import remove_small_pieces, weld_vertices


def grid_patch(size: float, cells: int, z: float = 0.0, color=(200, 10, 10)) -> Mesh:
    """A flat square of 2*cells^2 triangles in the z plane (normals +z)."""
    u = np.linspace(0, size, cells + 1)
    x, y = np.meshgrid(u, u, indexing="ij")
    vertices = np.column_stack([x.ravel(), y.ravel(), np.full(x.size, z)])
    idx = np.arange(x.size).reshape(cells + 1, cells + 1)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    faces = np.concatenate([np.column_stack([a, b, c]), np.column_stack([a, c, d])])
    return Mesh(vertices, faces, np.tile(np.array(color, np.uint8), (len(vertices), 1)))


def merge(*meshes: Mesh) -> Mesh:
    offset = np.cumsum([0] + [m.num_vertices for m in meshes[:-1]])
    return Mesh(np.concatenate([m.vertices for m in meshes]),
                np.concatenate([m.faces + o for m, o in zip(meshes, offset)]),
                np.concatenate([m.vertex_colors for m in meshes]))


def soup(mesh: Mesh) -> Mesh:
    """Every face with its own three vertices (how STL files and TSDF block seams duplicate them)."""
    return Mesh(mesh.vertices[mesh.faces.ravel()], np.arange(3 * mesh.num_faces).reshape(-1, 3),
                mesh.vertex_colors[mesh.faces.ravel()])


def test_weld_merges_duplicates():
    patch = grid_patch(1.0, 10)
    welded = weld_vertices(soup(patch), 1e-6)
    assert welded.num_vertices == patch.num_vertices and welded.num_faces == patch.num_faces


def test_small_pieces_removed_large_kept():
    room = grid_patch(2.0, 20)
    crumb = grid_patch(0.2, 2, z=1.0)  # diagonal 0.28 m < 0.3 m
    plate = grid_patch(0.25, 2, z=1.5)  # diagonal 0.35 m: kept
    cleaned, removed = remove_small_pieces(merge(room, crumb, plate), 0.3)
    assert removed == crumb.num_faces
    assert cleaned.num_faces == room.num_faces + plate.num_faces


def test_small_detached_fixtures_are_kept_by_default():
    """A lamp shade or wall light the scan left unattached is an obstacle: the clean stage keeps it (removed,
    the filter proposed perches whose approach it blocks)."""
    room = grid_patch(2.0, 20)
    shade = grid_patch(0.16, 2, z=1.0)   # diagonal 0.23 m: was removed by the former 0.3 m default
    cleaned, report = clean_mesh_with_report(merge(room, shade), None,
                                             ReconstructionConfig(target_faces=0, gravity_align=False))
    assert report.pieces_removed_faces == 0 and cleaned.num_faces == room.num_faces + shade.num_faces
    assert np.isclose(cleaned.vertices[:, 2].max(), 1.0)


def test_a_mesh_in_unwelded_blocks_is_said_to_fall_apart():
    """Surfaces are found within a connected piece: a room exported in blocks whose seams are not shared
    yields few, and the clean report says why (HoloLens maps, whose largest block holds 15-30 %, are not)."""
    config = ReconstructionConfig(target_faces=0, gravity_align=False)
    blocks = merge(*(grid_patch(0.25, 2).transformed(_shifted(0.251 * i, 0.251 * j))
                     for i in range(8) for j in range(8)))   # 64 tiles, 1 mm apart: no weld joins them
    _, report = clean_mesh_with_report(blocks, None, config)
    warning = [w for w in report.warnings if "falls apart into fragments" in w]
    assert warning and "64 disconnected pieces" in warning[0] and "(2% of the area)" in warning[0], report.warnings
    few = merge(grid_patch(1.0, 4), *(grid_patch(0.5, 2).transformed(_shifted(2.0 + i, 0.0)) for i in range(10)))
    _, report = clean_mesh_with_report(few, None, config)   # the largest of 11 pieces holds 29 %
    assert not any("falls apart" in w for w in report.warnings), report.warnings


def _shifted(x: float, y: float) -> np.ndarray:
    transform = np.eye(4)
    transform[:2, 3] = (x, y)
    return transform


def room_box(tilt: np.ndarray | None = None) -> Mesh:
    """Floor, ceiling and four walls (floor 4x3 m, walls 2.5 m high), finely tessellated."""
    floor = grid_patch(1.0, 40)
    parts = []
    for name, scale, rot, shift in [
            ("floor", (4, 3, 1), np.eye(3), (0, 0, 0)),
            ("ceiling", (4, 3, 1), Rotation.from_euler("x", 180, degrees=True).as_matrix(), (0, 3, 2.5)),
            ("wall", (4, 2.5, 1), Rotation.from_euler("x", 90, degrees=True).as_matrix(), (0, 0, 0))]:
        part = Mesh(floor.vertices * scale, floor.faces, floor.vertex_colors)
        t = np.eye(4)
        t[:3, :3], t[:3, 3] = rot, shift
        parts.append(part.transformed(t))
    mesh = merge(*parts)
    if tilt is not None:
        t = np.eye(4)
        t[:3, :3] = tilt
        mesh = mesh.transformed(t)
    return mesh


def test_decimates_to_target_and_keeps_colours():
    mesh = room_box()
    config = ReconstructionConfig(target_faces=2000, gravity_align=False)
    out = clean_mesh(mesh, None, config)
    assert 1900 <= out.num_faces <= 2000
    assert out.vertex_colors is not None and len(out.vertex_colors) == out.num_vertices
    np.testing.assert_array_equal(np.unique(out.vertex_colors, axis=0), [[200, 10, 10]])
    # the surface stays where it was: every vertex on one of the box's planes, the extent kept
    v = out.vertices
    on_plane = np.min(np.abs(np.column_stack([v[:, 2], v[:, 2] - 2.5, v[:, 1]])), axis=1)
    assert np.quantile(on_plane, 0.98) < 1e-3 and on_plane.max() < 0.03  # creases may shift by < a cell
    np.testing.assert_allclose(out.bounds(), mesh.bounds(), atol=0.1)


def test_decimated_vertices_keep_their_own_colours():
    """Each kept vertex gets the colours of the vertices collapsed into it, not another part's."""
    floor, ceiling = grid_patch(3.0, 40, z=0.0, color=(200, 10, 10)), grid_patch(3.0, 40, z=2.5, color=(10, 10, 200))
    out = clean_mesh(merge(floor, ceiling), None, ReconstructionConfig(target_faces=800, gravity_align=False))
    assert out.num_faces <= 800
    low = out.vertices[:, 2] < 1.0
    np.testing.assert_array_equal(np.unique(out.vertex_colors[low], axis=0), [[200, 10, 10]])
    np.testing.assert_array_equal(np.unique(out.vertex_colors[~low], axis=0), [[10, 10, 200]])


def test_gravity_vector_aligns_z_up():
    tilt = Rotation.from_euler("xyz", [25, -10, 40], degrees=True).as_matrix()
    mesh = room_box(tilt)
    gravity = tilt @ np.array([0, 0, -9.81])
    out, report = clean_mesh_with_report(mesh, gravity, ReconstructionConfig(target_faces=0))
    assert report.up_source == "gravity"
    normals, areas = out.face_normals(), out.face_areas()
    floor_like = np.abs(normals[:, 2]) > 0.999
    assert areas[floor_like].sum() / areas.sum() > 0.6  # floor + ceiling horizontal again
    np.testing.assert_allclose(report.rotation @ tilt @ [0, 0, 1.0], [0, 0, 1.0], atol=1e-9)


def test_up_estimated_from_floor_and_ceiling():
    """An empty box shows the vertical but not which end is up: the end nearer the mesh's +z is kept."""
    tilt = Rotation.from_euler("xyz", [20, 15, 0], degrees=True).as_matrix()
    out, report = clean_mesh_with_report(room_box(tilt), None, ReconstructionConfig(target_faces=0))
    assert report.up_source == "planes, sign kept" and report.up_estimate.axis_confidence > 0.5
    assert "sign is uncertain" in report.warnings[0]
    up_now = report.rotation @ tilt @ [0, 0, 1.0]
    assert up_now[2] > np.cos(np.radians(1))


def test_furniture_tops_give_the_sign_even_upside_down():
    """A room with a table, turned upside down: the table top faces the real up, so cleaning turns it back."""
    table = grid_patch(1.0, 10, z=0.75)
    table = Mesh(table.vertices + [1.5, 1.0, 0], table.faces, table.vertex_colors)
    flip = Rotation.from_euler("x", 180, degrees=True).as_matrix()
    room = merge(room_box(), table)
    t = np.eye(4)
    t[:3, :3] = flip
    out, report = clean_mesh_with_report(room.transformed(t), None, ReconstructionConfig(target_faces=0))
    assert report.up_source == "planes" and report.up_confidence >= 0.5
    np.testing.assert_allclose(report.rotation @ flip @ [0, 0, 1.0], [0, 0, 1.0], atol=1e-6)


def test_input_is_not_modified():
    mesh = room_box()
    before = (mesh.vertices.copy(), mesh.faces.copy(), mesh.vertex_colors.copy())
    clean_mesh(mesh, np.array([0.1, 0.2, -1.0]), ReconstructionConfig(target_faces=500))
    for a, b in zip(before, (mesh.vertices, mesh.faces, mesh.vertex_colors)):
        np.testing.assert_array_equal(a, b)


def test_bad_meshes_and_gravity_are_reported():
    empty = Mesh(np.zeros((0, 3)), np.zeros((0, 3), np.int64))
    with pytest.raises(MeshError, match="mesh to clean: mesh is empty"):
        clean_mesh(empty, None, ReconstructionConfig())
    with pytest.raises(ValueError, match="gravity must be three finite numbers"):
        clean_mesh(room_box(), np.array([np.nan, 0, 1]), ReconstructionConfig())
    crumbs = grid_patch(0.1, 2)
    with pytest.raises(MeshError, match="nothing left after removing pieces smaller than 0.3 m"):
        clean_mesh(crumbs, None, ReconstructionConfig(min_piece_diameter=0.3))


def test_collapse_mapping_matches_the_decimators_replay():
    """The survivors found by following the collapses are what fast-simplification's replay maps to."""
    import fast_simplification
    from fast_simplification import replay_simplification

    from perch_reconstruction.cleaning import _collapsed_into

    mesh = room_box(Rotation.from_euler("xyz", [5, 3, 20], degrees=True).as_matrix())
    faces = mesh.faces.astype(np.int32)
    _, out_faces, collapses = fast_simplification.simplify(mesh.vertices, faces, target_count=3000, return_collapses=True)
    ours = _collapsed_into(mesh, faces, out_faces, collapses)
    theirs = replay_simplification(mesh.vertices.astype(np.float32), faces, collapses)[2]
    kept = ours >= 0
    assert kept.mean() > 0.95 and np.array_equal(ours[kept], theirs[kept])
    assert set(ours[kept]) == set(range(out_faces.max() + 1))   # every output vertex gets colours
