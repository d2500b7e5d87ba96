"""Bag round trip (write, read back identical), bag info, and bad-bag errors."""

from __future__ import annotations

import numpy as np
import pytest

from perch_common.errors import PerchError
from perch_reconstruction import msgdefs
from perch_reconstruction.bag_read import bag_info, iter_raw, read_bag_frames
from perch_reconstruction.bag_write import BagTopics, write_bag


def _read_all(path, **kwargs):
    bag = read_bag_frames(path, **kwargs)
    return bag, list(bag.frames)


@pytest.mark.parametrize("compressed, pose_type", [(False, "pose"), (True, "odometry")])
def test_round_trip_is_identical(synthetic, tmp_path, compressed, pose_type):
    _, frames, intrinsics = synthetic
    frames = frames[:5]
    path = tmp_path / "rt.mcap"
    result = write_bag(path, frames, intrinsics, gravity=np.array([0.1, 0.0, -0.99]), compressed=compressed,
                       pose_type=pose_type)
    assert result["messages"] == {**{t: 5 for t in (BagTopics.color, BagTopics.depth, BagTopics.camera_info,
                                                    BagTopics.color_info, BagTopics.pose, "/tf")}, "/tf_static": 1}
    bag, back = _read_all(path)
    assert bag.intrinsics == intrinsics
    assert bag.has_poses and len(back) == 5
    np.testing.assert_allclose(bag.gravity, [0.1, 0.0, -0.99])
    for original, read in zip(frames, back):
        assert read.stamp_ns == original.stamp_ns
        # depth travels as millimetres: identical after rounding to 1 mm
        np.testing.assert_array_equal(np.round(read.depth * 1000), np.round(original.depth * 1000))
        if compressed:  # JPEG is lossy; the mean error stays small
            assert np.abs(read.color.astype(int) - original.color).mean() < 3.0
        else:
            np.testing.assert_array_equal(read.color, original.color)
        np.testing.assert_allclose(read.pose, original.pose, atol=1e-9)


def test_bag_is_standard_ros2_mcap(synthetic_bag):
    info = bag_info(synthetic_bag)
    assert info["topics"][BagTopics.color]["type"] == msgdefs.IMAGE
    assert info["topics"][BagTopics.camera_info]["type"] == msgdefs.CAMERA_INFO
    assert info["topics"][BagTopics.pose]["type"] == msgdefs.POSE_STAMPED
    assert all(t["encoding"] == "cdr" for t in info["topics"].values())
    assert "rosbag2" in info["metadata"]
    from mcap.reader import make_reader

    with open(synthetic_bag, "rb") as f:
        reader = make_reader(f)
        assert reader.get_header().profile == "ros2"
        summary = reader.get_summary()
        assert all(s.encoding == "ros2msg" for s in summary.schemas.values())
        assert all("offered_qos_profiles" in c.metadata for c in summary.channels.values())
    # the CDR payload decodes with the generic decoder, as Foxglove/ros2 bag would
    from mcap_ros2.decoder import DecoderFactory

    raw = next(iter_raw(synthetic_bag, [BagTopics.depth]))
    msg = DecoderFactory().decoder_for("cdr", raw.schema)(raw.data)
    assert (msg.encoding, msg.width, msg.height, msg.step) == ("16UC1", 320, 240, 640)


def test_messages_come_in_time_order(synthetic_bag):
    times = [m.log_time_ns for m in iter_raw(synthetic_bag)]
    # per frame: colour, depth, both camera infos, pose and /tf; /tf_static once
    assert times == sorted(times) and len(times) == 6 * 40 + 1


def test_missing_file_is_named(tmp_path):
    with pytest.raises(PerchError, match="no such bag file"):
        bag_info(tmp_path / "nope.mcap")


def test_not_an_mcap(tmp_path):
    path = tmp_path / "x.mcap"
    path.write_bytes(b"hello world, not a bag")
    with pytest.raises(PerchError, match="not an MCAP file"):
        bag_info(path)


def test_truncated_bag(synthetic_bag, tmp_path):
    """Read as far as it goes, and said so (test_bag_damage has the cases)."""
    data = synthetic_bag.read_bytes()
    path = tmp_path / "cut.mcap"
    path.write_bytes(data[: len(data) // 2])
    bag = read_bag_frames(path)
    assert 0 < len(list(bag.frames)) < 40 and "the file is cut short, with no summary" in bag.damage


def test_empty_frame_list_writes_nothing(tmp_path, synthetic):
    with pytest.raises(PerchError, match="no frames"):
        write_bag(tmp_path / "e.mcap", [], synthetic[2])
    assert not (tmp_path / "e.mcap").exists()


def test_missing_topics_are_listed(synthetic_bag):
    with pytest.raises(PerchError, match=r"missing topic\(s\) /other/depth.*the bag has: /camera/color"):
        read_bag_frames(synthetic_bag, BagTopics(depth="/other/depth"))


def test_wrong_topic_type(synthetic_bag):
    with pytest.raises(PerchError, match="has type geometry_msgs/msg/PoseStamped, expected"):
        read_bag_frames(synthetic_bag, BagTopics(depth="/camera/pose"))


def test_bag_without_messages(tmp_path):
    from mcap.writer import Writer

    path = tmp_path / "empty.mcap"
    with open(path, "wb") as f:
        writer = Writer(f)
        writer.start(profile="ros2", library="test")
        writer.finish()
    assert bag_info(path)["messages"] == 0
    with pytest.raises(PerchError, match=r"empty.mcap: missing topic\(s\) /camera/color/image_raw.*has: none"):
        read_bag_frames(path)


def _assert_rosbag2_layout(path, expected_counts: dict[str, int]) -> None:
    """rosbag2's metadata record (version at the top) and every channel's QoS, as rosbag2 reads them."""
    import yaml
    from mcap.reader import make_reader
    from rosbags.rosbag2.metadata import parse_qos

    with open(path, "rb") as f:
        reader = make_reader(f)
        records = {r.name: r.metadata for r in reader.iter_metadata()}
        channels = reader.get_summary().channels.values()
        # sensors as drivers offer them, /tf_static latched as a static broadcaster, /tf as tf broadcasters
        offered = {"/tf_static": ("RELIABLE", "TRANSIENT_LOCAL", 1), "/tf": ("RELIABLE", "VOLATILE", 100)}
        for channel in channels:
            [qos] = parse_qos(channel.metadata["offered_qos_profiles"])
            assert (qos.reliability.name, qos.durability.name, qos.depth) == offered.get(
                channel.topic, ("RELIABLE", "VOLATILE", 10))
            assert channel.metadata["topic_type_hash"].startswith("RIHS01_")   # as rosbag2 Jazzy writes
    described = yaml.safe_load(records["rosbag2"]["serialized_metadata"])
    assert described["version"] == 9 and described["storage_identifier"] == "mcap"
    assert described["message_count"] == sum(expected_counts.values())
    listed = {t["topic_metadata"]["name"]: t["message_count"] for t in described["topics_with_message_count"]}
    assert listed == expected_counts
    for topic in described["topics_with_message_count"]:
        assert parse_qos(topic["topic_metadata"]["offered_qos_profiles"])[0].depth == \
            {"/tf_static": 1, "/tf": 100}.get(topic["topic_metadata"]["name"], 10)
        assert topic["topic_metadata"]["type_description_hash"].startswith("RIHS01_")


def _assert_every_message_decodes(path, expected_counts: dict[str, int]) -> None:
    """rosbags (its AnyReader, from the file's own schemas) and Foxglove's decoders read all of them."""
    from perch_common.bag_check import DecoderUnavailable, foxglove_counts, rosbags_counts

    assert rosbags_counts(path) == {t: (n, n) for t, n in expected_counts.items()}
    try:
        assert foxglove_counts(path) == {t: (n, n) for t, n in expected_counts.items()}
    except DecoderUnavailable as exc:
        pytest.skip(f"Foxglove's decoders not run: {exc} (rosbags decoded every message)")


@pytest.mark.parametrize("compressed, pose_type", [(False, "pose"), (True, "odometry")])
def test_written_bag_has_rosbag2_layout_and_decodes_everywhere(synthetic, tmp_path, compressed, pose_type):
    _, frames, intrinsics = synthetic
    path = tmp_path / "written.mcap"
    result = write_bag(path, frames[:4], intrinsics, compressed=compressed, pose_type=pose_type)
    _assert_rosbag2_layout(path, result["messages"])
    _assert_every_message_decodes(path, result["messages"])


def test_from_frames_bag_of_the_real_kitchen_decodes_everywhere(kitchen_dir, tmp_path):
    import json
    import subprocess
    import sys

    path = tmp_path / "kitchen.mcap"
    done = subprocess.run([sys.executable, "-m", "perch_common.cli", "bag", "from-frames", str(kitchen_dir),
                           "-o", str(path), "--limit", "20"], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    counts = json.loads(done.stdout)["messages"]
    assert counts == {**{t: 20 for t in (BagTopics.color, BagTopics.depth, BagTopics.camera_info, BagTopics.color_info,
                                         BagTopics.pose, "/tf")}, "/tf_static": 1}
    _assert_rosbag2_layout(path, counts)
    _assert_every_message_decodes(path, counts)
