"""Command-line inputs are never harmed and bad ones get one clear line (issue 11, items 4 and 5)."""

from __future__ import annotations

import numpy as np
import pytest

from perch_common.cli import main


@pytest.fixture(scope="module")
def room_ply(tmp_path_factory):
    from perch_common.mesh import save_mesh
    from perch_common.scene_generator import generate_scene

    path = tmp_path_factory.mktemp("mesh") / "room.ply"
    save_mesh(path, generate_scene(3, "room").mesh)
    return path


@pytest.fixture(scope="module")
def frame_folder(tmp_path_factory):
    from perch_reconstruction.synthetic import DEFAULT_INTRINSICS, synthetic_room_frames, write_frame_folder

    _, frames = synthetic_room_frames(seed=1, count=4)
    folder = tmp_path_factory.mktemp("frames")
    write_frame_folder(folder, frames, DEFAULT_INTRINSICS, gravity=np.array([0.0, 0.0, -1.0]))
    return folder


def fails(capsys, *argv) -> str:
    """Run `perch ARGV`, expect exit 1 and return the one error line (progress lines may come before it)."""
    with pytest.raises(SystemExit) as info:
        main([str(a) for a in argv])
    assert info.value.code == 1
    err = capsys.readouterr().err
    errors = [line for line in err.splitlines() if line.startswith("perch: error: ")]
    assert len(errors) == 1 and err.rstrip().endswith(errors[0]) and "Traceback" not in err, err
    return errors[0]


def test_segment_onto_its_own_input_is_refused(room_ply, capsys):
    before = room_ply.read_bytes()
    assert "is the input" in fails(capsys, "segment", room_ply, "-o", room_ply)
    assert room_ply.read_bytes() == before


def test_clean_and_filter_onto_their_inputs_are_refused(room_ply, tmp_path, capsys):
    before = room_ply.read_bytes()
    assert "is the input" in fails(capsys, "clean", room_ply, "-o", room_ply)
    assert room_ply.read_bytes() == before
    surfaces = tmp_path / "surfaces.json"
    surfaces.write_text('{"surfaces": []}')
    message = fails(capsys, "filter", room_ply, "--surfaces", surfaces, "--target-box", 2, 2, 0.6, 1, 1, 1,
                    "-o", tmp_path)
    assert "is the input" in message and surfaces.read_text() == '{"surfaces": []}'


def test_bag_from_frames_never_replaces_a_bag_with_a_broken_one(frame_folder, tmp_path, capsys):
    import shutil

    bag = tmp_path / "scan.mcap"
    assert main(["bag", "from-frames", str(frame_folder), "-o", str(bag)]) == 0
    good = bag.read_bytes()
    capsys.readouterr()
    broken = tmp_path / "broken"
    shutil.copytree(frame_folder, broken)
    (broken / "frame-000002.depth.png").write_bytes(b"not a png")
    assert "frame-000002.depth.png" in fails(capsys, "bag", "from-frames", broken, "-o", bag)
    assert bag.read_bytes() == good
    assert sorted(p.name for p in tmp_path.iterdir()) == ["broken", "scan.mcap"]  # no partial file left
    assert "is an existing folder" in fails(capsys, "bag", "from-frames", frame_folder, "-o", tmp_path)


def test_garbage_intrinsics_and_pose_files_are_named(frame_folder, tmp_path, capsys):
    import shutil

    folder = tmp_path / "frames"
    shutil.copytree(frame_folder, folder)
    (folder / "camera-intrinsics.txt").write_text("fx fy\nhello\n")
    message = fails(capsys, "bag", "from-frames", folder, "-o", tmp_path / "a.mcap")
    assert "camera-intrinsics.txt: cannot be read as a 3x3 intrinsic matrix K" in message
    shutil.copy(frame_folder / "camera-intrinsics.txt", folder / "camera-intrinsics.txt")
    (folder / "frame-000001.pose.txt").write_text("1 0 0\n0 1 0\n")
    message = fails(capsys, "bag", "from-frames", folder, "-o", tmp_path / "b.mcap")
    assert "frame-000001.pose.txt: holds 6 numbers; a 4x4 camera-to-world pose needs 16" in message


def test_unreadable_meshes_get_clear_messages(room_ply, tmp_path, capsys):
    truncated = tmp_path / "truncated.ply"
    truncated.write_bytes(room_ply.read_bytes()[:120])
    assert "truncated or corrupt" in fails(capsys, "mesh", "info", truncated)
    folder = tmp_path / "folder.ply"
    folder.mkdir()
    assert "is a folder, not a mesh file" in fails(capsys, "mesh", "info", folder)
    cloud = tmp_path / "cloud.ply"
    cloud.write_text("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
                     "property float z\nend_header\n0 0 0\n1 0 0\n0 1 0\n")
    assert "3 points but no faces (a point cloud" in fails(capsys, "mesh", "info", cloud)


def test_a_room_in_millimetres_is_reported_and_scale_fixes_it(room_ply, tmp_path, capsys):
    from perch_common.mesh import load_mesh, save_mesh

    mm = tmp_path / "room_mm.ply"
    room = load_mesh(room_ply)
    room.vertices *= 1000.0
    save_mesh(mm, room)
    main(["mesh", "info", str(mm)])
    out = capsys.readouterr().out
    assert "suggests it is in millimetres" in out and "--scale 0.001" in out
    main(["mesh", "info", str(mm), "--scale", "0.001"])
    assert "problems: none" in capsys.readouterr().out


def test_negative_camera_count_is_an_error_not_a_default(room_ply, tmp_path, capsys):
    with pytest.raises(SystemExit) as info:
        main(["plan", "--mesh", str(room_ply), "--cameras", "-5", "-o", str(tmp_path / "out")])
    assert info.value.code == 2
    assert "--cameras: -5 is negative" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_a_reader_that_leaves_early_gets_no_traceback(room_ply):
    """`perch mesh info FILE | head -1`: the pipe closes before the output is written (issue 22)."""
    import os
    import subprocess
    import sys

    read_end, write_end = os.pipe()
    os.close(read_end)   # the reader is gone before perch writes: every write fails with EPIPE
    try:
        done = subprocess.run([sys.executable, "-m", "perch_common.cli", "mesh", "info", str(room_ply)],
                              stdout=write_end, stderr=subprocess.PIPE, text=True, timeout=120)
    finally:
        os.close(write_end)
    assert done.returncode == 1 and done.stderr == "", done.stderr
