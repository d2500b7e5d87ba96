"""Mesh files cut short are refused with the reason, never planned on silently (loaders read them)."""

from __future__ import annotations

import pytest

from perch_common.mesh import MeshError, load_mesh, save_mesh


@pytest.fixture(scope="module")
def room(tmp_path_factory):
    from perch_common.scene_generator import generate_scene

    folder = tmp_path_factory.mktemp("meshes")
    mesh = generate_scene(2, "room").mesh
    return mesh, folder


def _cut(path, fraction: float, out):
    data = path.read_bytes()
    out.write_bytes(data[: int(len(data) * fraction)])
    return out


def test_an_obj_cut_at_80_percent_is_refused(room):
    mesh, folder = room
    whole = save_mesh(folder / "room.obj", mesh)
    assert load_mesh(whole).num_faces == mesh.num_faces
    cut = _cut(whole, 0.8, folder / "cut.obj")
    with pytest.raises(MeshError, match=r"cut.obj: ends in the middle of a line \('f .*as a file cut short does"):
        load_mesh(cut)


def test_an_obj_without_a_final_line_break_after_a_comment_loads(room):
    mesh, folder = room
    whole = save_mesh(folder / "room2.obj", mesh)
    path = folder / "commented.obj"
    path.write_bytes(whole.read_bytes() + b"# exported by a tool that ends without a line break")
    assert load_mesh(path).num_faces == mesh.num_faces


def test_an_ascii_ply_cut_short_is_refused_with_its_counts(room):
    import trimesh

    mesh, folder = room
    whole = folder / "room.ply"
    trimesh.Trimesh(mesh.vertices, mesh.faces, process=False).export(whole, encoding="ascii")
    assert load_mesh(whole).num_faces == mesh.num_faces
    cut = _cut(whole, 0.8, folder / "cut.ply")
    with pytest.raises(MeshError, match=rf"cut.ply: holds [\d,]+ of the {mesh.num_faces:,} face elements its header "
                                        r"declares: the file is truncated"):
        load_mesh(cut)


def test_a_binary_ply_cut_short_is_refused(room):
    mesh, folder = room
    whole = save_mesh(folder / "binary.ply", mesh)
    cut = _cut(whole, 0.8, folder / "binary_cut.ply")
    with pytest.raises(MeshError, match="binary_cut.ply: cannot be read as a mesh: the file is truncated or corrupt"):
        load_mesh(cut)
