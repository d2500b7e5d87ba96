"""Bags with real time and tf: from-frames stamps, the tf tree it writes, poses taken from /tf."""

from __future__ import annotations

import dataclasses
import json
import time

import numpy as np
import pytest

from perch_common.cli import main
from perch_reconstruction.synthetic import write_frame_folder
from perch_reconstruction.tf_buffer import OPTICAL_FROM_LINK, TransformBuffer

FRAMES = 12


@pytest.fixture(scope="module")
def frame_folder(synthetic, tmp_path_factory):
    _, frames, intrinsics = synthetic
    folder = tmp_path_factory.mktemp("frames")
    write_frame_folder(folder, frames[:FRAMES], intrinsics, gravity=np.array([0.0, 0.0, -1.0]))
    return folder


def _messages(path, topics):
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    with open(path, "rb") as handle:
        return [(channel.topic, message.log_time, decoded)
                for _, channel, message, decoded in make_reader(handle, decoder_factories=[DecoderFactory()])
                .iter_decoded_messages(topics=topics)]


def _stamp(msg) -> int:
    return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec


def test_from_frames_stamps_from_now_and_writes_the_tf_tree(frame_folder, tmp_path, capsys):
    bag = tmp_path / "now.mcap"
    before = time.time_ns()
    assert main(["bag", "from-frames", str(frame_folder), "-o", str(bag), "--fps", "10"]) == 0
    captured = capsys.readouterr()
    written = json.loads(captured.out[captured.out.index("{"):])
    assert f"{FRAMES}/{FRAMES} frames (100 %)" in captured.err   # progress on stderr
    assert written["messages"]["/tf"] == FRAMES and written["messages"]["/tf_static"] == 1
    assert written["messages"]["/camera/color/camera_info"] == written["messages"]["/camera/depth/camera_info"] == FRAMES
    images = _messages(bag, ["/camera/color/image_raw"])
    first_log, first = images[0][1], images[0][2]
    assert before <= first_log <= time.time_ns() and _stamp(first) == first_log   # now, not 1970
    assert [_stamp(m) - _stamp(first) for _, _, m in images] == [i * 100_000_000 for i in range(FRAMES)]
    assert first.header.frame_id == "camera_optical_frame"
    # The tree: map -> camera_link (moving) -> camera_optical_frame (static); composed it gives the poses.
    buffer = TransformBuffer()
    for topic, _, msg in _messages(bag, ["/tf", "/tf_static"]):
        buffer.add_message(msg, static=topic == "/tf_static")
    assert buffer.chain("map", "camera_optical_frame") == ["camera_optical_frame", "camera_link", "map"]
    _, frames, _ = _synthetic_frames(frame_folder)
    for i, (_, _, msg) in enumerate(images):
        pose = buffer.lookup("map", "camera_optical_frame", _stamp(msg), 0)
        np.testing.assert_allclose(pose, frames[i].pose, atol=1e-6)
    print("from-frames first stamps (ns):", [_stamp(m) for _, _, m in images[:3]])
    print("tf tree:", " -> ".join(reversed(buffer.chain("map", "camera_optical_frame"))))


def _synthetic_frames(folder):
    from perch_reconstruction.frames import iter_folder_frames, open_frame_folder

    opened = open_frame_folder(folder)
    return opened, list(iter_folder_frames(opened)), opened.intrinsics


def test_from_frames_takes_the_folders_own_timestamps_else_start(frame_folder, tmp_path, capsys):
    import shutil

    stamped = tmp_path / "stamped"
    shutil.copytree(frame_folder, stamped)
    stems = sorted(p.name.split(".")[0] for p in stamped.glob("*.color.*"))
    seconds = [1305031102.175304 + 0.0333 * i for i in range(len(stems))]
    (stamped / "timestamps.txt").write_text("# SECONDS NAME\n" + "".join(
        f"{s:.6f} {stem}.color.png\n" for s, stem in zip(seconds, stems)))
    assert main(["bag", "from-frames", str(stamped), "-o", str(tmp_path / "own.mcap")]) == 0
    assert "stamps from timestamps.txt" in capsys.readouterr().err
    stamps = [_stamp(m) for _, _, m in _messages(tmp_path / "own.mcap", ["/camera/depth/image_raw"])]
    np.testing.assert_allclose(np.array(stamps) / 1e9, seconds, atol=1e-6)
    assert main(["bag", "from-frames", str(frame_folder), "-o", str(tmp_path / "start.mcap"),
                 "--start", "2024-05-01T10:00:00Z", "--fps", "5"]) == 0
    stamps = [_stamp(m) for _, _, m in _messages(tmp_path / "start.mcap", ["/camera/depth/image_raw"])]
    assert stamps[0] == 1714557600 * 1_000_000_000 and stamps[1] - stamps[0] == 200_000_000
    (stamped / "timestamps.txt").write_text(f"{seconds[0]} {stems[0]}\n")
    with pytest.raises(SystemExit) as exited:
        main(["bag", "from-frames", str(stamped), "-o", str(tmp_path / "bad.mcap")])
    assert exited.value.code == 1
    assert "no time stamp for" in capsys.readouterr().err


def test_a_bag_with_poses_only_as_tf_reconstructs_like_one_with_a_pose_topic(synthetic, tmp_path):
    from perch_reconstruction.bag_read import bag_info
    from perch_reconstruction.bag_write import write_bag
    from perch_reconstruction.config import ReconstructionConfig
    from perch_reconstruction.core import reconstruct_bag

    _, frames, intrinsics = synthetic
    start = 1_700_000_000 * 1_000_000_000
    stamped = [dataclasses.replace(f, stamp_ns=start + i * 33_333_333) for i, f in enumerate(frames[:FRAMES])]
    tf_bag, pose_bag = tmp_path / "tf.mcap", tmp_path / "pose.mcap"
    write_bag(tf_bag, stamped, intrinsics, gravity=np.array([0.0, 0.0, -1.0]), pose_type="tf")
    write_bag(pose_bag, stamped, intrinsics, gravity=np.array([0.0, 0.0, -1.0]))
    assert "/camera/pose" not in bag_info(tf_bag)["topics"]
    # The frames get the same poses from the tf tree as from the pose topic.
    from perch_reconstruction.bag_read import read_bag_frames

    via_tf, via_topic = read_bag_frames(tf_bag), read_bag_frames(pose_bag)
    assert via_tf.has_poses and via_tf.pose_frame_id == via_topic.pose_frame_id == "map"
    for a, b in zip(via_tf.frames, via_topic.frames):
        assert a.stamp_ns == b.stamp_ns
        np.testing.assert_allclose(a.pose, b.pose, atol=1e-12)
    config = ReconstructionConfig(target_faces=0)
    from_tf, stats_tf = reconstruct_bag(tf_bag, config, use_poses=True)
    from_topic, stats_topic = reconstruct_bag(pose_bag, config, use_poses=True)
    assert stats_tf.frames_integrated == stats_topic.frames_integrated == FRAMES
    assert stats_tf.frames_without_pose == 0 and from_tf.frame_id == from_topic.frame_id
    # Open3D's integration is not bit-reproducible across runs (threads): the same room within a voxel or two.
    assert abs(from_tf.num_faces - from_topic.num_faces) <= 0.01 * from_topic.num_faces
    np.testing.assert_allclose(from_tf.vertices.min(0), from_topic.vertices.min(0), atol=0.05)
    np.testing.assert_allclose(from_tf.vertices.max(0), from_topic.vertices.max(0), atol=0.05)
    # A world frame the tree does not have: said so, with the frames it does have.
    from perch_common.errors import PerchError

    with pytest.raises(PerchError, match=r"no /tf chain from the images' frame up to 'odom'"):
        reconstruct_bag(tf_bag, ReconstructionConfig(tf_world_frame="odom"), use_poses=True)


def test_the_buffer_composes_a_moving_base_with_a_static_mount():
    """odom -> base_link moving (interpolated between samples), base_link -> camera fixed."""
    from scipy.spatial.transform import Rotation

    buffer = TransformBuffer()
    mount = np.eye(4)
    mount[:3, 3] = [0.1, 0.0, 0.3]
    mount = mount @ np.linalg.inv(OPTICAL_FROM_LINK)   # base_link <- optical frame
    buffer.add("base_link", "camera_optical", 0, mount, static=True)
    for stamp, yaw, x in ((0, 0.0, 0.0), (1_000_000_000, 90.0, 2.0)):
        base = np.eye(4)
        base[:3, :3] = Rotation.from_euler("z", yaw, degrees=True).as_matrix()
        base[0, 3] = x
        buffer.add("odom", "base_link", stamp, base)
    halfway = buffer.lookup("odom", "camera_optical", 500_000_000, 0)
    expected = np.eye(4)
    expected[:3, :3] = Rotation.from_euler("z", 45.0, degrees=True).as_matrix()
    expected[0, 3] = 1.0
    np.testing.assert_allclose(halfway, expected @ mount, atol=1e-9)
    assert buffer.lookup("odom", "camera_optical", 2_000_000_000, 10_000_000) is None   # no extrapolation
    assert buffer.lookup("odom", "camera_optical", 1_005_000_000, 10_000_000) is not None
    assert "no transform chain from 'camera_optical' up to 'map'" in buffer.why_not("map", "camera_optical")


@pytest.mark.ros
def test_the_live_node_takes_poses_from_tf_while_a_bag_with_poses_only_as_tf_plays(synthetic, tmp_path):
    import subprocess
    import sys

    import rclpy

    from perch_common.ros.node_main import ros_context
    from perch_common.ros.testing import call_service, node_process, use_isolated_ros_env
    from perch_interfaces.srv import Reconstruct
    from perch_reconstruction.bag_write import write_bag

    _, frames, intrinsics = synthetic
    bag = tmp_path / "tf_only.mcap"
    write_bag(bag, frames[:FRAMES], intrinsics, gravity=np.array([0.0, 0.0, -1.0]), pose_type="tf")
    use_isolated_ros_env()
    params = {"lossless_replay": True, "queue_size": 200, "gravity": "[0.0, 0.0, -1.0]", "pose_type": "tf"}
    with ros_context(), node_process("perch_reconstruction.node", params=params, log_path=tmp_path / "node.log"):
        client = rclpy.create_node("tf_live_test")
        from std_srvs.srv import Trigger

        assert call_service(client, Trigger, "/perch/reconstruct/reset", Trigger.Request(), timeout=60,
                            resend_every=5).success
        play = subprocess.run([sys.executable, "-m", "perch_common.cli", "bag", "play", str(bag), "--rate", "1",
                               "--wait-subscribers", "120"], capture_output=True, text=True, timeout=300)
        assert play.returncode == 0, play.stderr
        reply = call_service(client, Reconstruct, "/perch/reconstruct", Reconstruct.Request(use_poses=True),
                             timeout=120)
        log = (tmp_path / "node.log").read_text()
        assert reply.success, reply.message + "\n" + log
        assert reply.frames_integrated == FRAMES, reply.message + "\n" + log
        assert "0 without pose" in reply.message and reply.mesh.header.frame_id.startswith("map"), reply.message
        client.destroy_node()


def test_frames_missing_their_pose_file_go_without_one_and_are_counted(frame_folder, tmp_path, capsys):
    """One missing .pose.txt used to drop every frame's pose without a word (the bag then had no pose topic
    and the mission tracked by odometry): the others keep theirs, and the count is said."""
    import shutil

    from perch_reconstruction.frames import iter_folder_frames, open_frame_folder

    partial = tmp_path / "partial"
    shutil.copytree(frame_folder, partial)
    removed = sorted(partial.glob("*.pose.txt"))[::3]
    for path in removed:
        path.unlink()
    folder = open_frame_folder(partial)
    assert folder.has_poses and folder.frames_without_pose_file == len(removed) == 4
    posed = [frame.pose is not None for frame in iter_folder_frames(folder)]
    assert posed.count(False) == len(removed) and posed.count(True) == FRAMES - len(removed)
    capsys.readouterr()
    assert main(["bag", "from-frames", str(partial), "-o", str(tmp_path / "partial.mcap")]) == 0
    out, err = capsys.readouterr()
    assert "warning: 4 of 12 frames have no .pose.txt" in err and json.loads(out)["frames_without_pose_file"] == 4
    poses = [m for topic, _, m in _messages(tmp_path / "partial.mcap", None) if "pose" in topic]
    assert len(poses) == FRAMES - len(removed)
