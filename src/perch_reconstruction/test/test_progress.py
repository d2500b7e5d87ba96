"""Progress reports: the core's typed values, and their message as recorders and viewers decode it."""

from __future__ import annotations

import numpy as np
import pytest

from perch_reconstruction.core import ReconstructionConfig, ReconstructionStats, reconstruct_frames
from perch_reconstruction.progress import (
    DROP_REASONS,
    MODE_BAG,
    MODE_LIVE,
    NO_CAMERA_INFO,
    QUEUE_FULL,
    UNPAIRED,
    ReconstructionProgress,
    bag_progress,
)

TYPE_NAME = "perch_interfaces/msg/ReconstructionProgress"


def _stats() -> ReconstructionStats:
    return ReconstructionStats(frames_received=12, frames_integrated=9, frames_without_pose=1, frames_lost=1,
                               frames_over_budget=1, blocks=340, faces_raw=5000, faces=1200,
                               seconds_integrate=0.75, seconds_track=0.25, seconds_clean=1.5)


def test_from_stats_copies_every_counter_and_lists_every_drop_reason_in_order():
    progress = ReconstructionProgress.from_stats(MODE_LIVE, _stats(), frame_id="map_gravity_aligned",
                                                 dropped={NO_CAMERA_INFO: 2, QUEUE_FULL: 5}, queued=3,
                                                 last_error="no pose")
    assert list(progress.dropped.items()) == [(QUEUE_FULL, 5), (UNPAIRED, 0), (NO_CAMERA_INFO, 2)]
    assert progress.frames_dropped == 7 and progress.queued == 3 and progress.last_error == "no pose"
    assert (progress.frames_received, progress.frames_integrated, progress.frames_without_pose,
            progress.frames_lost, progress.frames_over_budget) == (12, 9, 1, 1, 1)
    assert (progress.blocks, progress.faces_raw, progress.faces) == (340, 5000, 1200)
    assert (progress.seconds_integrate, progress.seconds_track, progress.seconds_clean) == (0.75, 0.25, 1.5)
    assert progress.mode == "live" and progress.frame_id == "map_gravity_aligned" and progress.bag_path == ""


def test_bad_mode_or_drop_reason_is_a_clear_error():
    with pytest.raises(ValueError, match="progress mode 'offline': use 'live' or 'bag'"):
        ReconstructionProgress.from_stats("offline", _stats())
    with pytest.raises(ValueError, match=r"drop reasons \['too_old'\]: known reasons are queue_full"):
        ReconstructionProgress.from_stats(MODE_LIVE, _stats(), dropped={"too_old": 1})


def test_bag_progress_names_the_bag_and_its_output_frame_once_frames_are_read(synthetic):
    _, frames, intrinsics = synthetic
    before = bag_progress("/data/scan.mcap")
    assert before.mode == MODE_BAG and before.bag_path == "/data/scan.mcap" and before.frame_id == ""
    assert before.frames_received == 0 and before.dropped == dict.fromkeys(DROP_REASONS, 0)
    reports: list[ReconstructionProgress] = []
    mesh, stats = reconstruct_frames(frames[:20], intrinsics, ReconstructionConfig(), use_poses=True,
                                     gravity=np.array([0.0, 0.0, -1.0]), progress_every=8, frame_id="scan_world",
                                     progress=lambda s: reports.append(bag_progress("/data/scan.mcap", s)))
    # after frames 8 and 16, then once finished: counters grow, the frame is known from the first report
    assert [r.frames_received for r in reports] == [8, 16, 20]
    assert all(r.frame_id == "scan_world_gravity_aligned" == mesh.frame_id for r in reports)
    assert reports[0].blocks > 0 and reports[0].faces == 0 and reports[0].seconds_integrate > 0
    last = reports[-1]
    assert last.frames_integrated == stats.frames_integrated == 20 and last.faces == mesh.num_faces > 0
    assert last.faces_raw >= last.faces and last.seconds_clean > 0 and last.frames_dropped == 0


def _message():
    from builtin_interfaces.msg import Time

    from perch_reconstruction.node import progress_to_msg

    progress = ReconstructionProgress.from_stats(MODE_BAG, _stats(), frame_id="odom_gravity_aligned",
                                                 bag_path="/data/scan.mcap", dropped={UNPAIRED: 4})
    return progress_to_msg(progress, Time(sec=17, nanosec=500))


def test_message_carries_the_typed_values():
    from perch_interfaces.msg import ReconstructionProgress as Message

    msg = _message()
    assert (Message.MODE_LIVE, Message.MODE_BAG) == (MODE_LIVE, MODE_BAG)
    assert msg.mode == Message.MODE_BAG and msg.bag_path == "/data/scan.mcap"
    assert msg.header.frame_id == "odom_gravity_aligned" and (msg.header.stamp.sec, msg.header.stamp.nanosec) == (17, 500)
    assert list(msg.dropped_reasons) == list(DROP_REASONS) and list(msg.dropped_counts) == [0, 4, 0]
    assert (msg.frames_received, msg.frames_integrated, msg.frames_dropped, msg.blocks, msg.faces) == (12, 9, 4, 340, 1200)
    assert msg.seconds_clean == pytest.approx(1.5) and msg.last_error == ""


def test_recorded_message_decodes_with_mcap_ros2_rosbags_and_foxglove(tmp_path):
    from mcap.well_known import MessageEncoding, SchemaEncoding
    from mcap.writer import Writer
    from mcap_ros2.reader import read_ros2_messages
    from rclpy.serialization import serialize_message

    from perch_common.bag_check import DecoderUnavailable, foxglove_counts, rosbags_counts
    from perch_common.ros import bag_format
    from perch_common.ros.msgdefs import full_definition

    topic, path = "/perch/reconstruct/progress", tmp_path / "progress.mcap"
    profiles = [bag_format.qos_profile(reliable=True, depth=10)]
    with open(path, "wb") as stream:  # as the mission recorder writes it: the schema from full_definition
        writer = Writer(stream)
        writer.start(profile="ros2", library="test")
        schema = writer.register_schema(TYPE_NAME, SchemaEncoding.ROS2, full_definition(TYPE_NAME).encode())
        channel = writer.register_channel(topic, MessageEncoding.CDR, schema, bag_format.channel_metadata(profiles))
        for sequence in range(2):
            writer.add_message(channel, log_time=sequence, publish_time=sequence, data=serialize_message(_message()),
                               sequence=sequence)
        bag_format.add_rosbag2_metadata(writer, [bag_format.TopicRecord(topic, TYPE_NAME, profiles, 2)], 0, 1,
                                        path.name)
        writer.finish()
    [decoded, _] = [m.ros_msg for m in read_ros2_messages(str(path), topics=[topic])]
    assert decoded.mode == "bag" and decoded.header.frame_id == "odom_gravity_aligned"
    assert list(decoded.dropped_reasons) == list(DROP_REASONS) and list(decoded.dropped_counts) == [0, 4, 0]
    assert decoded.frames_integrated == 9 and decoded.seconds_track == pytest.approx(0.25)
    assert rosbags_counts(path) == {topic: (2, 2)}
    try:
        counts = foxglove_counts(path)
    except DecoderUnavailable as exc:
        pytest.skip(f"Foxglove's decoders not run: {exc} (mcap_ros2 and rosbags decoded every message)")
    assert counts == {topic: (2, 2)}
