"""Mesh model, validation errors and file I/O."""

import numpy as np
import pytest

from perch_common.mesh import Mesh, MeshError, inspect_mesh, load_mesh, save_mesh, validate_mesh


def square() -> Mesh:
    return Mesh([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], [[0, 1, 2], [0, 2, 3]],
                vertex_colors=[[255, 0, 0]] * 4)


def test_geometry_of_unit_square():
    m = square()
    assert m.face_areas() == pytest.approx([0.5, 0.5])
    assert np.allclose(m.face_normals(), [[0, 0, 1], [0, 0, 1]])
    assert np.allclose(m.bounds(), [[0, 0, 0], [1, 1, 0]])
    assert np.allclose(m.face_colors(), [[1, 0, 0], [1, 0, 0]])


def test_submesh_matches_the_sorted_unique_vertices_of_its_faces():
    """The vertex-mask submesh gives what np.unique of the faces' vertices gave (order included)."""
    rng = np.random.default_rng(3)
    mesh = Mesh(rng.random((400, 3)), rng.integers(0, 400, (900, 3)), rng.integers(0, 255, (400, 3)))
    for which in (rng.choice(900, 200, replace=False), rng.random(900) < 0.3):
        used, inverse = np.unique(mesh.faces[which], return_inverse=True)
        sub = mesh.submesh(which)
        assert np.array_equal(sub.vertices, mesh.vertices[used]) and np.array_equal(sub.faces, inverse.reshape(-1, 3))
        assert np.array_equal(sub.vertex_colors, mesh.vertex_colors[used])


def test_submesh_keeps_only_used_vertices_and_colours():
    sub = square().submesh(np.array([1]))
    assert sub.num_vertices == 3 and sub.num_faces == 1
    assert np.allclose(sub.vertices[sub.faces[0]], [[0, 0, 0], [1, 1, 0], [0, 1, 0]])
    assert sub.vertex_colors.shape == (3, 3)


@pytest.mark.parametrize("vertices, faces, expected", [
    (np.zeros((0, 3)), np.zeros((0, 3)), "mesh is empty"),
    ([[0, 0, np.nan], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]], "1 vertices are NaN or infinite (first: vertex 0)"),
    ([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 3]], "faces index vertices outside 0..2"),
    ([[0, 0, 0], [1, 0, 0], [2, 0, 0]], [[0, 1, 2]], "every face is degenerate"),
])
def test_validation_names_the_problem(vertices, faces, expected):
    with pytest.raises(MeshError, match="mesh:.*" + expected.replace("(", r"\(").replace(")", r"\)").replace(".", r"\.")):
        validate_mesh(Mesh(vertices, faces))


def test_warnings_count_degenerate_and_duplicate_faces():
    m = Mesh([[0, 0, 0], [1, 0, 0], [0, 1, 0], [2, 0, 0]], [[0, 1, 2], [2, 1, 0], [0, 1, 3]])
    problems = inspect_mesh(m)
    assert problems.fatal == []
    assert problems.duplicate_faces == 1 and problems.degenerate_faces == 1


def test_save_and_load_round_trip(tmp_path):
    m = square()
    for suffix in (".ply", ".obj", ".stl", ".glb"):
        loaded = load_mesh(save_mesh(tmp_path / f"sq{suffix}", m))
        assert loaded.face_areas().sum() == pytest.approx(1.0)
    assert np.array_equal(load_mesh(tmp_path / "sq.ply").vertex_colors, m.vertex_colors)


def test_load_errors_are_precise(tmp_path):
    with pytest.raises(MeshError, match="no such file"):
        load_mesh(tmp_path / "missing.ply")
    (tmp_path / "x.txt").write_text("hello")
    with pytest.raises(MeshError, match="unsupported format '.txt'"):
        load_mesh(tmp_path / "x.txt")
    (tmp_path / "bad.ply").write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 99\n")
    with pytest.raises(MeshError, match="bad.ply"):
        load_mesh(tmp_path / "bad.ply")


@pytest.mark.parametrize("suffix", [".ply", ".stl", ".off"])
def test_a_single_mesh_file_read_directly_equals_trimesh_load(tmp_path, suffix, monkeypatch):
    """PLY, STL and OFF files are read by trimesh's format reader straight into one mesh (trimesh.load
    copies it through a scene: 7 s on a 7.2 M-face PLY); vertices, faces and colours are the same."""
    import perch_common.mesh as mesh_module
    from perch_common.scene_generator import generate_scene

    scene = generate_scene(2, "room")
    path = save_mesh(tmp_path / f"room{suffix}", scene.mesh)
    direct = load_mesh(path)
    assert mesh_module._load_single_mesh(path) is not None
    monkeypatch.setattr(mesh_module, "_load_single_mesh", lambda path: None)
    through_scene = load_mesh(path)
    assert np.array_equal(direct.vertices, through_scene.vertices) and np.array_equal(direct.faces, through_scene.faces)
    if through_scene.vertex_colors is None:
        assert direct.vertex_colors is None
    else:
        assert np.array_equal(direct.vertex_colors, through_scene.vertex_colors)
    assert direct.num_faces == scene.mesh.num_faces
