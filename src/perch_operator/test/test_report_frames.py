"""The report, the console's perch lines and the rerun recording give positions in the input frame and
name it; the gravity-aligned frame appears only where labelled (issue 21, item 6)."""

import re

import numpy as np
import pytest

from perch_common.frames import Alignment
from perch_common.target import TargetVolume
from perch_common.transforms import optical_pose_looking_at
from perch_common.types import CameraPlacement
from perch_operator.outputs.mission_data import MissionData


@pytest.fixture
def tilted_mission(meshes) -> MissionData:
    """A mission whose input frame 'odom' has +y up: the stages' geometry is in odom_gravity_aligned."""
    alignment = Alignment.from_up("odom", np.array([0.0, 1.0, 0.0]))
    assert not alignment.is_identity()
    mesh = meshes.room()  # the views' geometry is gravity-aligned
    target = TargetVolume(center=[2.0, 1.5, 0.6], size=[1.5, 1.0, 1.2])
    poses = [optical_pose_looking_at(np.array(p), target.center) for p in [(0.3, 0.3, 2.4), (3.7, 2.7, 2.2)]]
    placements = [CameraPlacement(i, 0, pose, pose, pan=0.1, tilt=-0.2, marginal_gain=0.3, coverage=0.5)
                  for i, pose in enumerate(poses)]
    waypoints = []
    for p in placements:
        at = alignment.point_to_input(np.asarray(p.drone_pose)[:3, 3])
        waypoints.append({"drone_index": p.drone_index, "proposal_id": 10 + p.drone_index, "frame_id": "odom",
                          "position": at.tolist(), "orientation_xyzw": [0, 0, 0, 1], "approach": at.tolist(),
                          "pan": 0.1, "tilt": -0.2, "zoom": 1.0})
    return MissionData(mesh=mesh, cropped=mesh, target=target, placements=placements,
                       rejected=[(placements[1], "too close to the lamp")], waypoints=waypoints,
                       summary={}, alignment=alignment)


def _table_after(text: str, heading: str) -> list[list[str]]:
    """Rows (cell texts) of the first table after the <h2> starting with `heading`."""
    start = text.index(f"<h2>{heading}")
    table = text[text.index("<table>", start):text.index("</table>", start)]
    return [re.findall(r"<t[dh][^>]*>(.*?)</t[dh]>", row) for row in table.split("<tr>")[1:]]


def test_report_tables_are_in_the_input_frame_and_name_it(tilted_mission, tmp_path):
    from perch_operator.outputs.report import write_report

    text = write_report(tilted_mission, tmp_path, views=[]).read_text()
    cameras = _table_after(text, "Cameras")
    assert cameras[0][2:5] == ["x (m, odom)", "y (m, odom)", "z (m, odom)"]
    for row, w in zip(cameras[1:], tilted_mission.waypoints):
        np.testing.assert_allclose([float(c) for c in row[2:5]], w["position"], atol=0.006)
        aligned = np.asarray(tilted_mission.placements[int(row[0])].drone_pose)[:3, 3]
        assert not np.allclose([float(c) for c in row[2:5]], aligned, atol=0.05)  # not the aligned frame
    rejected = _table_after(text, "Rejected")
    np.testing.assert_allclose([float(c) for c in rejected[1][:3]], tilted_mission.waypoints[1]["position"], atol=0.006)
    waypoints = _table_after(text, "Waypoints")
    assert waypoints[0][2] == "position (m, odom)"
    # The gravity-aligned frame is named only where it is used: the overview picture's caption.
    assert "Gravity-aligned frame odom_gravity_aligned, seen from above" in text
    assert "<h2>Cameras (input frame odom)</h2>" in text and "<h2>Waypoints (input frame odom)</h2>" in text


def test_console_perch_lines_are_in_the_input_frame(tilted_mission):
    from perch_operator.outputs.report import perch_text

    lines = perch_text(tilted_mission).splitlines()
    assert "input frame 'odom'" in lines[0]
    x, y, z = tilted_mission.waypoints[0]["position"]
    assert f"at ({x:.2f}, {y:.2f}, {z:.2f}) m" in lines[1]


def test_rerun_recording_names_its_frames(tilted_mission, tmp_path):
    from perch_operator.outputs.rerun_log import frames_markdown, write_rrd

    doc = frames_markdown(tilted_mission)
    assert "input frame `odom`" in doc and "`odom_gravity_aligned`" in doc
    assert write_rrd(tilted_mission, tmp_path / "run.rrd", views=[]).stat().st_size > 5000
