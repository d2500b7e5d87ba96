"""Simulated views, per-camera point scores and the `perch place` command."""

import numpy as np
import pytest
import yaml
from placement_rooms import box_room

from perch_common.target import TargetVolume
from perch_common.types import CameraPlacement
from perch_placement.config import CameraSpec
from perch_placement.render import TARGET_COLOUR, point_scores, render_view

ROOM, REGIONS = box_room()


def facing_wall(position=(3.0, 2.5, 1.5)) -> CameraPlacement:
    pose = np.eye(4)
    pose[:3, :3] = np.column_stack([[-1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]])  # z_opt = +y, image down = -z
    pose[:3, 3] = position
    return CameraPlacement(0, 0, pose.copy(), pose, 0.0, 0.0)


def test_depth_of_a_wall_straight_ahead_and_target_edges_drawn():
    target = TargetVolume(center=np.array([3.0, 4.0, 1.5]), size=np.array([0.6, 0.4, 0.6]))
    rgb, depth = render_view(ROOM, facing_wall(), CameraSpec(), target, scale=0.25)
    assert rgb.shape == (180, 320, 3) and rgb.dtype == np.uint8 and depth.dtype == np.float32
    # The wall y = 5 fills the 87 x 58 deg view from 2.5 m: z-depth 2.5 everywhere.
    assert np.allclose(depth, 2.5, atol=1e-4)
    edge = np.all(rgb == TARGET_COLOUR, axis=-1)
    assert edge.sum() > 100
    # The target's projected box: centre column, rows around the centre.
    rows, cols = np.nonzero(edge)
    assert abs(cols.mean() - 160) < 8 and abs(rows.mean() - 90) < 8


def test_point_scores_per_camera_and_fused():
    points = np.array([[3.0, 4.0, 1.5], [3.0, 1.0, 1.5]])  # ahead of the camera / behind it
    scores = point_scores(ROOM, [facing_wall()], CameraSpec(), points)
    assert scores.seen.tolist() == [[True, False]]
    d = 1.5
    assert scores.per_camera[0, 0] == pytest.approx(1 - (d / CameraSpec().max_distance()) ** 4)
    assert scores.fused.tolist() == pytest.approx(scores.per_camera[0].tolist())


def test_perch_place_writes_placements_and_views(tmp_path):
    from perch_common.cli import main

    assert main(["place", "--scene", "2", "--scene-kind", "room", "--regions", "unfiltered", "--cameras", "2",
                 "--view-scale", "0.1", "-o", str(tmp_path)]) == 0
    doc = yaml.safe_load((tmp_path / "placements.yaml").read_text())
    assert len(doc["placements"]) == 2 and 0 < doc["fitness"] <= 1
    assert doc["placements"][1]["fitness"] == pytest.approx(doc["fitness"], abs=1e-6)
    assert (tmp_path / "view_0.png").stat().st_size > 0 and (tmp_path / "depth_1.png").exists()
    # Again with one camera: the second camera's views of the first run do not stay beside its placements.
    (tmp_path / "notes.png").write_bytes(b"the user's")
    assert main(["place", "--scene", "2", "--scene-kind", "room", "--regions", "unfiltered", "--cameras", "1",
                 "--view-scale", "0.1", "-o", str(tmp_path)]) == 0
    assert sorted(p.name for p in tmp_path.glob("*.png")) == ["depth_0.png", "notes.png", "view_0.png"]


def test_perch_place_refuses_what_it_cannot_do_before_the_search(tmp_path, capsys):
    from perch_common.cli import main

    a_file = tmp_path / "placements.txt"
    a_file.write_text("kept")
    for args, said in ((["-o", str(a_file)], "is a file; give a folder for the outputs"),
                       (["--view-scale", "1e6", "-o", str(tmp_path)], "--view-scale must be above 0 and at most 4"),
                       (["--view-scale", "nan", "-o", str(tmp_path)], "--view-scale must be above 0 and at most 4"),
                       (["--cameras", "0", "-o", str(tmp_path)], "--cameras must be 1 or more"),
                       (["--target-box", "1", "1", "1", "0", "0", "0", "-o", str(tmp_path)], "sizes above 0")):
        with pytest.raises(SystemExit) as exit_info:
            main(["place", "--scene", "2", "--scene-kind", "room", "--regions", "unfiltered", *args])
        assert exit_info.value.code == 1 and said in capsys.readouterr().err, args
    assert a_file.read_text() == "kept"


def test_perch_place_without_a_target_is_a_clear_error(tmp_path, capsys):
    from perch_common.cli import main

    with pytest.raises(SystemExit) as exit_info:
        main(["place", str(tmp_path / "missing.ply"), "--regions", "unfiltered", "-o", str(tmp_path)])
    assert exit_info.value.code == 1
    assert "missing.ply: no such file" in capsys.readouterr().err
