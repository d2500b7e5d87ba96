"""Perch beside other ROS tools: a recording started after a mission, rosbag2's channel metadata.

One graph (each node its own process) serves the module; the first test runs the mission the
others look at.
"""

from __future__ import annotations

import re
import time

import pytest

pytestmark = pytest.mark.ros

CAMERAS = 2
LATCHED_TOPICS = ("/tf_static", "/perch/markers", "/perch/mission_waypoints", "/perch/waypoint_poses")
RIHS01 = re.compile(r"^RIHS01_[0-9a-f]{64}$")


@pytest.fixture(scope="module")
def mission(graph):
    """One auto-accepted mission on a generated room, finished before anything below records."""
    from perch_common.ros.conversions import mesh_to_msg, target_to_msg
    from perch_common.scene_generator import generate_scene
    from perch_interfaces.action import PlanPerches
    from perch_operator.client import run_mission

    scene = generate_scene(3, "room")
    goal = PlanPerches.Goal(mesh=mesh_to_msg(scene.mesh), target=target_to_msg(scene.target),
                            num_cameras=CAMERAS, auto_accept=True, seed=-1)
    result = run_mission(graph.node, goal, timeout=300)
    assert result.success, result.message
    return result


def record_until(node, path, wanted, timeout: float = 60.0):
    """Record like `perch record` (latched) until every `wanted` topic has a message (or the deadline)."""
    from perch_operator.recorder import MissionRecorder
    from perch_operator.runner import spin_for

    recorder = MissionRecorder(node, path, latched=True)
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline and not all(recorder.counts.get(t) for t in wanted):
        recorder.refresh()
        spin_for(node, 0.2)
    recorder.close()
    return recorder


def test_a_recording_started_after_the_mission_holds_the_latched_state(graph, mission, tmp_path):
    from perch_operator.runfile import channel_counts, iter_messages

    path = tmp_path / "late.mcap"
    record_until(graph.node, path, LATCHED_TOPICS)
    counts = channel_counts(path)
    print("perch record after the mission:", dict(sorted(counts.items())))
    assert all(counts.get(t, 0) >= 1 for t in LATCHED_TOPICS), counts
    [final_set] = [m for _, m, _ in iter_messages(path, ["/perch/mission_waypoints"])][-1:]
    assert len(final_set.waypoints) == CAMERAS == len(mission.waypoints)
    poses = [m for _, m, _ in iter_messages(path, ["/perch/waypoint_poses"])][-1]
    assert len(poses.poses) == CAMERAS
    frames = {t.child_frame_id for _, m, _ in iter_messages(path, ["/tf_static"]) for t in m.transforms}
    assert {f"perch_drone_{i}_camera_optical" for i in range(CAMERAS)} <= frames
    assert path.stat().st_mode & 0o777 == 0o666 & ~_umask()   # mode from the umask, not 0600


def _umask() -> int:
    from perch_common.outputs import current_umask

    return current_umask()


def test_channels_carry_what_rosbag2_jazzy_writes(graph, mission, tmp_path):
    """rosbag2_storage_mcap (Jazzy) MCAPStorage::create_topic writes exactly two channel metadata keys,
    `offered_qos_profiles` and `topic_type_hash` (the RIHS01 string of the topic's type description
    hash); its reader maps `topic_type_hash` back to each topic's `type_description_hash`, which the
    bag description (`rosbag2` metadata record) also lists."""
    import yaml
    from mcap.reader import make_reader

    from perch_common.ros.msgdefs import type_hash

    path = tmp_path / "late.mcap"
    record_until(graph.node, path, LATCHED_TOPICS)
    with open(path, "rb") as handle:
        reader = make_reader(handle)
        summary = reader.get_summary()
        records = {r.name: r.metadata for r in reader.iter_metadata()}
    described = yaml.safe_load(records["rosbag2"]["serialized_metadata"])
    listed = {t["topic_metadata"]["name"]: t["topic_metadata"] for t in described["topics_with_message_count"]}
    assert summary.channels
    for channel in summary.channels.values():
        schema = summary.schemas[channel.schema_id]
        assert set(channel.metadata) == {"offered_qos_profiles", "topic_type_hash"}, channel.topic
        assert RIHS01.match(channel.metadata["topic_type_hash"]), (channel.topic, channel.metadata)
        # The publishers' hash from discovery is the one rosidl computed into the installed package.
        assert channel.metadata["topic_type_hash"] == type_hash(schema.name), channel.topic
        assert listed[channel.topic]["type_description_hash"] == channel.metadata["topic_type_hash"]
        assert listed[channel.topic]["type"] == schema.name
    # A known value: Jazzy's tf2_msgs/msg/TFMessage hash (`ros2 topic info -v /tf` on Jazzy prints it;
    # the stand-in tf2_msgs, same definition, hashes the same).
    tf_static = next(c for c in summary.channels.values() if c.topic == "/tf_static")
    assert tf_static.metadata["topic_type_hash"] == (
        "RIHS01_e369d0f05a23ae52508854b66f6aa0437f3449d652e8cbf22d5abe85d020f087")
    assert "durability: transient_local" in tf_static.metadata["offered_qos_profiles"]
