"""The perch subcommands: bag from-frames / info, reconstruct, clean, and their error exits."""

from __future__ import annotations

import json

import numpy as np
import pytest

from perch_common.cli import main
from perch_common.mesh import load_mesh
from perch_reconstruction.synthetic import write_frame_folder


@pytest.fixture(scope="module")
def frame_folder(synthetic, tmp_path_factory):
    _, frames, intrinsics = synthetic
    folder = tmp_path_factory.mktemp("frames")
    write_frame_folder(folder, frames[:12], intrinsics, gravity=np.array([0.0, 0.0, -1.0]))
    return folder


def _json(capsys) -> dict:
    out = capsys.readouterr().out
    return json.loads(out[out.index("{"):])


def test_bag_from_frames_info_and_reconstruct(frame_folder, tmp_path, capsys):
    bag = tmp_path / "b.mcap"
    assert main(["bag", "from-frames", str(frame_folder), "-o", str(bag), "--fps", "15",
                 "--pose-type", "odometry"]) == 0
    written = _json(capsys)
    assert written["messages"]["/camera/pose"] == 12 and abs(written["duration_s"] - 11 / 15) < 1e-6
    assert main(["bag", "info", str(bag), "--json"]) == 0
    info = _json(capsys)
    assert info["topics"]["/camera/pose"]["type"] == "nav_msgs/msg/Odometry"
    assert info["gravity"] == [0.0, 0.0, -1.0]
    mesh_path = tmp_path / "m.ply"
    raw_path = tmp_path / "raw.ply"
    assert main(["reconstruct", "--bag", str(bag), "-o", str(mesh_path), "--use-poses", "--raw", str(raw_path)]) == 0
    summary = _json(capsys)
    assert summary["frames_integrated"] == 12
    mesh = load_mesh(mesh_path)
    assert mesh.num_faces == summary["faces"] > 1000 and mesh.vertex_colors is not None
    assert load_mesh(raw_path).num_faces == summary["faces_raw"]
    # The cameras' viewpoints, which a PLY cannot hold, were written beside it and load with it.
    assert (tmp_path / "m.ply.viewpoints.json").is_file() and len(mesh.viewpoints) >= 1


def test_clean_command(synthetic, tmp_path, capsys):
    from perch_common.mesh import save_mesh

    source = tmp_path / "room.ply"
    save_mesh(source, synthetic[0].mesh)
    out = tmp_path / "clean.ply"
    assert main(["clean", str(source), "-o", str(out), "--target-faces", "1000", "--gravity", "0", "0", "-1"]) == 0
    report = _json(capsys)
    assert report["faces_out"] <= 1000 and report["up_source"] == "gravity"
    assert load_mesh(out).num_faces == report["faces_out"]


def test_errors_exit_with_one_clear_line(tmp_path, capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["bag", "info", str(tmp_path / "missing.mcap")])
    assert exit_info.value.code == 1
    assert "perch: error:" in capsys.readouterr().err
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(SystemExit):
        main(["bag", "from-frames", str(empty), "-o", str(tmp_path / "x.mcap")])
    assert "no frames named like frame-000000.color.jpg" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["clean", str(tmp_path / "nope.ply"), "-o", str(tmp_path / "o.ply")])
    assert "nope.ply: no such file" in capsys.readouterr().err
