"""Recording introspection events to MCAP and `replay --check` against the live crop service."""

import io
import time

import numpy as np
import pytest

from perch_common.ros import testing

pytestmark = pytest.mark.ros

# A node process just started takes 6 s to be discovered on a machine at load 15 (measured), more
# under CI's load: discovery and calls get generous deadlines, and the test waits for what it needs.
DISCOVERY = 120.0
EVENTS = "/perch/crop/_service_event"


def test_crop_calls_are_recorded_and_replay_check_catches_a_parameter_change(ros_node, operator, meshes, tmp_path):
    from mcap.reader import make_reader

    from perch_common.ros.conversions import from_array, mesh_to_msg, pose_msg, vector_msg
    from perch_interfaces import msg as pm
    from perch_interfaces.srv import Crop
    from perch_operator.cli.replay import replay, summary_line
    from perch_operator.cli.runner import spin_for
    from perch_operator.outputs.recorder import MissionRecorder
    from perch_operator.outputs.runfile import channel_counts, stage_calls

    path = tmp_path / "run.mcap"
    room = mesh_to_msg(meshes.room())
    keep = Crop.Request(mesh=room, return_kept_faces=True)
    pose = np.eye(4)
    pose[:3, 3] = [1.0, 1.5, 1.25]
    keep.keep_boxes = [pm.OrientedBox(pose=pose_msg(pose), size=vector_msg([2.0, 3.2, 3.0]))]
    with operator():
        recorder = MissionRecorder(ros_node, path)
        assert recorder.wait_matched([EVENTS], lambda t: spin_for(ros_node, t), DISCOVERY) == []
        first = testing.call_service(ros_node, Crop, "/perch/crop", Crop.Request(mesh=room), timeout=DISCOVERY)
        second = testing.call_service(ros_node, Crop, "/perch/crop", keep, timeout=DISCOVERY)
        assert first.success and second.success
        # The reply-sent event is published after the reply: wait for all four events, not a fixed time.
        deadline = time.monotonic() + DISCOVERY
        while recorder.counts.get(EVENTS, 0) < 4 and time.monotonic() < deadline:
            spin_for(ros_node, 0.1)
        recorder.close()

        calls = stage_calls(path)
        assert [c.stage for c in calls] == ["crop", "crop"]
        assert len(calls[1].request.keep_boxes) == 1 and len(calls[0].request.keep_boxes) == 0
        np.testing.assert_array_equal(from_array(calls[1].response.kept_faces, np.uint32),
                                      from_array(second.kept_faces, np.uint32))
        assert channel_counts(path)[EVENTS] == 4  # received + sent, twice
        with open(path, "rb") as handle:  # the standard reader sees ros2 schemas
            summary = make_reader(handle).get_summary()
        schemas = {s.name: s.encoding for s in summary.schemas.values()}
        assert schemas["perch_interfaces/srv/Crop_Event"] == "ros2msg"

        out = io.StringIO()
        clean = replay(ros_node, path, check=True, out=out, wait=DISCOVERY)
        assert all(o.ok for o in clean), out.getvalue()
        assert summary_line(clean, True).startswith("replay check passed: 2 stage call(s)")

    # The stopped operator must be gone from this node's view first: a client still matched to it
    # would send the first replayed request to it and never get a reply from the new one.
    deadline = time.monotonic() + DISCOVERY
    while ros_node.count_publishers(EVENTS) and time.monotonic() < deadline:
        spin_for(ros_node, 0.1)
    assert ros_node.count_publishers(EVENTS) == 0
    with operator(**{"crop.target_height": 2.0}):
        out = io.StringIO()
        changed = replay(ros_node, path, check=True, out=out, wait=DISCOVERY)
        text = out.getvalue()
        assert not changed[0].ok and changed[1].ok is False
        assert "target.height: recorded 1.2, replayed 2" in text
        assert "target.footprint.vertices" not in text  # the floor outline is unchanged, only the height
        assert summary_line(changed, True).startswith("replay check FAILED: 2 of 2")
