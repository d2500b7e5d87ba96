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


def test_face_centroids_are_the_mean_of_the_corners_bit_for_bit():
    """face_centroids sums the corners in place: the same floats as triangles().mean(axis=1) (what
    it computed before; crop, segmentation and the filter read them)."""
    rng = np.random.default_rng(5)
    mesh = Mesh(rng.normal(0.0, 40.0, (500, 3)), rng.integers(0, 500, (2000, 3)))
    assert np.array_equal(mesh.face_centroids(), mesh.triangles().mean(axis=1))
    assert np.array_equal(square().face_centroids(), [[2 / 3, 1 / 3, 0], [1 / 3, 2 / 3, 0]])


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
    # A format scans arrive in that Perch does not read names what turns it into one it does.
    for name, fix in (("room.usdz", "export the scan as OBJ, GLB or PLY from the capture app"),
                      ("room.E57", "point cloud format, and Perch needs a surface mesh: mesh it first"),
                      ("room.fbx", "export it as OBJ, GLB or PLY from the tool that wrote it")):
        (tmp_path / name).write_bytes(b"PK\x03\x04")
        with pytest.raises(MeshError, match=f"unsupported format .*: .*{fix}"):
            load_mesh(tmp_path / name)
    (tmp_path / "bad.ply").write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 99\n")
    with pytest.raises(MeshError, match="bad.ply"):
        load_mesh(tmp_path / "bad.ply")
    # Bytes that are no OBJ: said so, not "mesh is empty".
    (tmp_path / "noise.obj").write_bytes(np.random.default_rng(0).integers(0, 256, 5000, np.uint8).tobytes())
    with pytest.raises(MeshError, match=r"no vertex or face could be read from its 5,000 bytes: not a mesh in the \.obj"):
        load_mesh(tmp_path / "noise.obj")


def _glb(path, header: dict, body: bytes):
    """Write a GLB: `header` (the glTF JSON) and one binary chunk."""
    import json
    import struct

    text = json.dumps(header).encode()
    text += b" " * (-len(text) % 4)
    body += b"\0" * (-len(body) % 4)
    with open(path, "wb") as stream:
        stream.write(struct.pack("<III", 0x46546C67, 2, 28 + len(text) + len(body)))
        stream.write(struct.pack("<II", len(text), 0x4E4F534A) + text + struct.pack("<II", len(body), 0x004E4942) + body)
    return path


def _draco_room_glb(path, extension: str = "KHR_draco_mesh_compression"):
    """A generated room as a Draco-compressed GLB (as web and phone apps export), requiring `extension`."""
    import DracoPy

    from perch_common.scene_generator import generate_scene

    room = generate_scene(2, "room").mesh
    blob = DracoPy.encode(room.vertices.astype(np.float32), room.faces.astype(np.uint32), quantization_bits=16)
    header = {
        "asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
        "extensionsUsed": [extension], "extensionsRequired": [extension],
        "buffers": [{"byteLength": len(blob) + (-len(blob) % 4)}],
        "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": len(blob)}],
        "accessors": [{"componentType": 5126, "count": len(room.vertices), "type": "VEC3",
                       "min": room.vertices.min(axis=0).tolist(), "max": room.vertices.max(axis=0).tolist()},
                      {"componentType": 5125, "count": room.faces.size, "type": "SCALAR"}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1, "mode": 4, "extensions": {
            "KHR_draco_mesh_compression": {"bufferView": 0, "attributes": {"POSITION": 0}}}}]}]}
    return room, _glb(path, header, blob)


def test_a_draco_compressed_glb_is_read_and_one_needing_an_unknown_decoder_is_refused(tmp_path):
    room, path = _draco_room_glb(tmp_path / "room.glb")
    loaded = load_mesh(path)
    extent = float(np.ptp(room.vertices, axis=0).max())
    assert loaded.face_areas().sum() == pytest.approx(room.face_areas().sum(), rel=1e-3)
    assert np.allclose(loaded.bounds(), room.bounds(), atol=2 * extent / 2 ** 16)
    # meshopt: trimesh would read its compressed bytes as vertices; refused, naming the extension and the fix.
    _, path = _draco_room_glb(tmp_path / "meshopt.glb", "EXT_meshopt_compression")
    with pytest.raises(MeshError, match="requires the glTF extension EXT_meshopt_compression .* export it again"):
        load_mesh(path)


def test_a_gltf_missing_its_buffer_is_named_and_a_missing_texture_leaves_only_the_colours(tmp_path, caplog):
    import shutil

    import trimesh
    from PIL import Image

    from perch_common.scene_generator import generate_scene

    room = generate_scene(2, "room").mesh
    textured = trimesh.Trimesh(room.vertices, room.faces, process=False)
    textured.visual = trimesh.visual.TextureVisuals(uv=np.random.default_rng(0).random((len(room.vertices), 2)),
                                                    image=Image.new("RGB", (8, 8), (200, 40, 40)))
    (tmp_path / "gltf").mkdir()
    for name, data in trimesh.exchange.gltf.export_gltf(textured).items():
        (tmp_path / "gltf" / name).write_bytes(data)
    (tmp_path / "alone").mkdir()
    shutil.copy(tmp_path / "gltf" / "model.gltf", tmp_path / "alone")
    with pytest.raises(MeshError, match=r"refers to gltf_buffer_\d\.bin, which is not beside it: copy"):
        load_mesh(tmp_path / "alone" / "model.gltf")
    # A textured OBJ (phone apps: OBJ + MTL + image) is coloured from its texture, and read without
    # colours, with a warning, when its image was not copied along (before: a traceback).
    textured.export(tmp_path / "room.obj")
    assert np.array_equal(load_mesh(tmp_path / "room.obj").vertex_colors[0], [200, 40, 40])
    next(tmp_path.glob("*.png")).unlink()
    with caplog.at_level("WARNING"):
        bare = load_mesh(tmp_path / "room.obj")
    assert bare.vertex_colors is None and bare.num_faces == room.num_faces
    assert "texture colours cannot be read" in caplog.text


@pytest.mark.parametrize("extent, first, others", [
    (342.0, "inches (8.69 m across: --scale 0.0254)", ["centimetres (3.42 m", "feet (104 m"]),  # a room in inches
    (870.0, "centimetres (8.7 m across: --scale 0.01)", ["inches (22.1 m"]),
    (8000.0, "millimetres (8 m across: --scale 0.001)", ["centimetres (80 m"])])
def test_a_size_no_space_has_in_metres_names_every_plausible_unit_likeliest_first(extent, first, others):
    """The size alone cannot tell a room in centimetres from a larger one in inches: each unit giving
    an indoor size is named with that size (before: a room in inches was said to be in centimetres)."""
    from perch_common.mesh import scale_problem

    message = scale_problem(extent)
    assert f"suggests it is in {first}" in message and all(f"or {other}" in message for other in others)
    assert message.count("--scale 0.") == 1 + len(others)
    assert scale_problem(150.0) is None   # a 150 m hall in metres


def test_nan_vertices_no_face_uses_are_left_out_and_used_ones_refused_with_the_fix(tmp_path, caplog):
    """Depth-camera exports keep a NaN vertex per invalid pixel, used by no face: no geometry, left out
    (faces renumbered, colours kept with their vertices). A face on one is refused, naming the fix."""
    import trimesh

    from perch_common.scene_generator import generate_scene

    room = generate_scene(2, "room").mesh
    n = room.num_vertices
    holes = np.array([3, 50, n // 2])   # NaN vertices between real ones, so every later index shifts
    vertices = np.insert(room.vertices, holes, np.nan, axis=0)
    colors = np.insert(np.tile([[10, 20, 30, 255]], (n, 1)), holes, [[255, 0, 0, 255]], axis=0)
    old_index = np.flatnonzero(~np.isnan(vertices[:, 0]))
    trimesh.Trimesh(vertices, old_index[room.faces], vertex_colors=colors, process=False).export(tmp_path / "nan.ply")
    with caplog.at_level("WARNING"):
        loaded = load_mesh(tmp_path / "nan.ply")
    assert "3 vertices with NaN or infinite coordinates, used by no face, are left out" in caplog.text
    np.testing.assert_allclose(loaded.triangles(), room.triangles(), atol=1e-6)
    assert np.array_equal(loaded.vertex_colors, np.tile([[10, 20, 30]], (n, 1)))
    used = np.vstack([old_index[room.faces], [[holes[1] + 1, 0, 1]]])
    trimesh.Trimesh(vertices, used, process=False).export(tmp_path / "used.ply")
    with pytest.raises(MeshError, match="3 vertices are NaN or infinite .*used by 1 face: remove those faces"):
        load_mesh(tmp_path / "used.ply")


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


def test_a_shift_moves_a_georeferenced_file_near_its_origin_after_the_scale(tmp_path):
    from perch_common.viewpoints import VIEWPOINT_COLUMNS, moved_viewpoints

    offset = np.array([450123.25, 5201234.5, 312.0])
    room = Mesh(np.array([[0, 0, 0], [4, 0, 0], [4, 3, 0], [0, 3, 2.5]], float) * 1000 + offset * 1000,
                [[0, 1, 2], [0, 2, 3]])
    path = tmp_path / "site.obj"   # an OBJ keeps every digit of the millimetre UTM coordinates
    path.write_text("".join(f"v {x:.3f} {y:.3f} {z:.3f}\n" for x, y, z in room.vertices) + "f 1 2 3\nf 1 3 4\n")
    as_metres = inspect_mesh(load_mesh(path, validate=False))   # 4,000 m across: the units are named first
    assert any("in millimetres" in w for w in as_metres.warnings) and not as_metres.fatal
    with pytest.raises(MeshError, match=r"georeferenced .*--shift=-450130,-5201240,-310;") as refused:
        load_mesh(path, scale=0.001)   # the room's centre (450125.25, 5201236, 313.25) in whole tens of metres
    named = tuple(float(v) for v in str(refused.value).split("--shift=")[1].split(";")[0].split(","))
    loaded = load_mesh(path, scale=0.001, shift=named)   # the shift it names, in metres after the scale
    assert np.allclose(loaded.vertices, np.array([[0, 0, 0], [4, 0, 0], [4, 3, 0], [0, 3, 2.5]]) + offset + named,
                       atol=1e-6)
    views = np.zeros((1, VIEWPOINT_COLUMNS))
    views[0, :3], views[0, 6] = offset * 1000 + [1000, 2000, 1500], 3000.0   # a camera 1,2,1.5 m into the room
    moved = moved_viewpoints(views, 0.001, -offset)
    assert np.allclose(moved[0, :3], [1, 2, 1.5]) and moved[0, 6] == pytest.approx(3.0)
    with pytest.raises(MeshError, match="shift must be three finite numbers"):
        load_mesh(path, shift=(1.0, float("nan"), 0.0))


def test_a_georeferenced_file_written_in_float32_is_refused_whatever_the_shift(tmp_path):
    """Single precision 5,201 km out holds half-metre steps: the room is lost in the file itself (planned
    on with the exact shift, ICL office and the Phanto room moved there gave 4 of 10 perches perch-audit
    finds unsafe)."""
    import trimesh

    offset = np.array([452113.0, 5201244.0, 312.0])
    corners = np.array([[0, 0, 0], [4, 0, 0], [4, 3, 0], [0, 3, 2.5]], float) + [0.123, 0.456, 0.0]
    faces = [[0, 1, 2], [0, 2, 3]]
    single = tmp_path / "site.ply"
    trimesh.Trimesh(corners + offset, faces, process=False).export(single)   # trimesh writes float32 PLY
    with pytest.raises(MeshError, match=r"single-precision \(float32\).* 5,201.2 km .* 0.5 m steps.*no --shift"):
        load_mesh(single, shift=tuple(-offset))
    double = tmp_path / "site.obj"   # the same room as text, every decimal kept
    double.write_text("".join(f"v {x:.6f} {y:.6f} {z:.6f}\n" for x, y, z in corners + offset) + "f 1 2 3\nf 1 3 4\n")
    assert np.allclose(load_mesh(double, shift=tuple(-offset)).vertices, corners, atol=1e-6)
    near = tmp_path / "near.ply"   # float32 near the origin: its steps are far below a millimetre
    trimesh.Trimesh(corners, faces, process=False).export(near)
    assert np.allclose(load_mesh(near).vertices, corners, atol=1e-6)


def test_the_shift_and_scale_arguments_refuse_what_they_cannot_use():
    import argparse

    from perch_common.mesh import add_units_arguments

    parser = argparse.ArgumentParser(exit_on_error=False)
    add_units_arguments(parser)
    args = parser.parse_args(["--shift=-450120,-5201240,-310", "--scale", "0.001"])
    assert args.shift == (-450120.0, -5201240.0, -310.0) and args.scale == 0.001
    for bad in (["--shift=1,2"], ["--shift=1,x,3"], ["--shift=1,inf,3"], ["--scale", "0"], ["--scale", "-1"]):
        with pytest.raises(argparse.ArgumentError):
            parser.parse_args(bad)


def test_mesh_info_refuses_a_georeferenced_file_and_reads_it_with_the_shift_it_names(tmp_path, capsys):
    import json

    from perch_common.cli import main

    path = tmp_path / "site.obj"
    corners = np.array([[0, 0, 0], [4, 0, 0], [4, 3, 0], [0, 3, 2.5]]) + [450000.5, 5200000.25, 300.0]
    path.write_text("".join(f"v {x:.3f} {y:.3f} {z:.3f}\n" for x, y, z in corners) + "f 1 2 3\nf 1 3 4\n")
    assert main(["mesh", "info", str(path), "--json"]) == 1
    problem = json.loads(capsys.readouterr().out)["problems"][0]
    shift = problem.split("--shift=")[1].split(";")[0]
    assert main(["mesh", "info", str(path), "--json", f"--shift={shift}"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert np.allclose(summary["size"], [4, 3, 2.5]) and max(map(abs, summary["bounds_max"])) < 10


def test_an_obj_with_relative_indices_reads_each_face_after_its_own_vertices(tmp_path):
    """The OBJ specification's relative indices (-1: the latest vertex so far), as an exporter writes each face
    after its own vertices: trimesh counted them from the end of the file, and every face became the last
    one (a 4 mm blob of the ICL living room)."""
    path = tmp_path / "relative.obj"
    path.write_text("o first\nv 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\nf -3/-3 -2/-2 -1/-1\n"
                    "o second\nv 5 5 2\nv 6 5 2\nv 5 6 2\nf -3 -2 -1\nf 1 2 3\n")
    mesh = load_mesh(path)
    corners = np.sort(mesh.vertices[mesh.faces].reshape(-1, 3, 3).sum(axis=1), axis=0)
    assert np.allclose(corners, [[1, 1, 0], [1, 1, 0], [16, 16, 6]])
    assert np.isclose(mesh.face_areas().sum(), 1.5)


@pytest.mark.parametrize("kind", ["room", "l_shaped", "apartment", "multi_storey"])
def test_a_space_in_feet_is_told_by_its_furniture_and_one_in_metres_is_not(kind):
    """Hunt 5: a scan in feet read as metres (8-10 m tall, its tables 2.4 m high) was planned without a word.
    Its size cannot tell (a hall's), its furniture can; a multi-storey building's furniture is measured from
    the storey it stands on (from the ground, its upper storeys' tables stood 3 m high)."""
    from perch_common.mesh import feet_problem
    from perch_common.scene_generator import generate_scene

    scene = generate_scene(1, kind, **({"floors": 3} if kind == "multi_storey" else {}))
    up = np.asarray(scene.up, np.float64)
    assert feet_problem(scene.mesh, up) is None
    message = feet_problem(Mesh(scene.mesh.vertices / 0.3048, scene.mesh.faces), up)
    assert message is not None and message.startswith("mesh is ") and message.endswith(" m tall: --scale 0.3048)")
    assert "its furniture tops stand" in message and "which suggests it is in feet" in message


def test_the_shared_real_scans_are_in_metres_and_the_office_in_feet_is_not():
    from perch_common.data import shared_file
    from perch_common.mesh import feet_problem
    from perch_common.scan_orientations import REAL_SCANS

    path = shared_file("meshes", "icl_office_kt2.obj")
    if path is None:
        pytest.skip("../shared/data/meshes/icl_office_kt2.obj is absent (real scans are optional)")
    office = load_mesh(path)
    up = REAL_SCANS["icl_office_kt2.obj"]
    assert feet_problem(office, up) is None
    assert "suggests it is in feet (2.4 m tall" in feet_problem(Mesh(office.vertices / 0.3048, office.faces), up)
