"""The node across processes: bag play -> node -> Reconstruct equals the offline CLI; error replies."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from perch_common.ros.testing import call_service, node_process, use_isolated_ros_env
from perch_reconstruction.core import ReconstructionConfig, reconstruct_bag
from perch_reconstruction.metrics import chamfer_distance

pytestmark = pytest.mark.ros

VOXEL = ReconstructionConfig().voxel_size


@pytest.fixture(scope="module")
def ros(tmp_path_factory):
    use_isolated_ros_env()
    import rclpy

    from perch_common.ros.node_main import ros_context

    log = tmp_path_factory.mktemp("node") / "node.log"
    with ros_context():
        client = rclpy.create_node("perch_reconstruction_test")
        params = {"lossless_replay": True, "queue_size": 200, "gravity": "[0.0, 0.0, -1.0]", "progress_period": 0.1}
        with node_process("perch_reconstruction.node", params=params, log_path=log) as proc:
            yield client, proc, log
        client.destroy_node()


def _reconstruct(client, bag_path: str = "", use_poses: bool = True, timeout: float = 120.0):
    from perch_interfaces.srv import Reconstruct

    return call_service(client, Reconstruct, "/perch/reconstruct",
                        Reconstruct.Request(bag_path=bag_path, use_poses=use_poses), timeout=timeout)


def _progress(client, until=lambda status: True, timeout: float = 60.0) -> list:
    """ReconstructionProgress messages on /perch/reconstruct/progress until one satisfies `until` (or the timeout)."""
    import time

    import rclpy

    from perch_interfaces.msg import ReconstructionProgress

    received = []
    sub = client.create_subscription(ReconstructionProgress, "/perch/reconstruct/progress", received.append, 10)
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline and not (received and until(received[-1])):
        rclpy.spin_once(client, timeout_sec=0.1)
    client.destroy_subscription(sub)
    assert received, f"no progress message within {timeout} s"
    return received


def test_live_replay_matches_offline(ros, synthetic_bag):
    from perch_common.ros.conversions import mesh_from_msg

    client, proc, log = ros
    offline, offline_stats = reconstruct_bag(synthetic_bag, ReconstructionConfig(), use_poses=True)
    # wait for the node before playing (its services appear once its subscriptions exist)
    from std_srvs.srv import Trigger

    assert call_service(client, Trigger, "/perch/reconstruct/reset", Trigger.Request(), resend_every=5).success
    play = subprocess.run([sys.executable, "-m", "perch_common.cli", "bag", "play", str(synthetic_bag),
                           "--rate", "1", "--wait-subscribers", "120"], capture_output=True, text=True, timeout=300)
    assert play.returncode == 0, play.stderr
    assert json.loads(play.stdout.strip().splitlines()[-1])["published"]["/camera/color/image_raw"] == 40
    progress = _progress(client, until=lambda status: status.frames_integrated == 40)
    assert all(p.mode == p.MODE_LIVE and p.header.frame_id == "map_gravity_aligned" for p in progress)
    last = progress[-1]
    assert (last.frames_received, last.frames_integrated, last.frames_dropped, last.queued) == (40, 40, 0, 0)
    assert list(last.dropped_reasons) == ["queue_full", "unpaired", "no_camera_info"]
    assert list(last.dropped_counts) == [0, 0, 0] and last.last_error == ""
    assert last.blocks > 0 and last.seconds_integrate > 0 and last.header.stamp.sec > 0
    reply = _reconstruct(client)
    assert reply.success, reply.message + "\n" + log.read_text()
    assert reply.frames_integrated == offline_stats.frames_integrated == 40, reply.message + "\n" + log.read_text()
    assert reply.frames_dropped == 0
    from perch_common.ros.static_transforms import alignment_from_msg

    live = mesh_from_msg(reply.mesh)
    assert abs(live.num_faces - offline.num_faces) <= 0.01 * offline.num_faces
    # Compared in the frame of the bag's poses: each alignment turns the walls onto the axes as its own
    # mesh shows them, which may differ by a hair.
    back = np.eye(4)
    back[:3, :3] = offline_stats.clean.rotation.T
    live_in_pose_frame = live.transformed(alignment_from_msg(reply.alignment).to_input())
    assert chamfer_distance(live_in_pose_frame, offline.transformed(back), samples=20_000) < 0.1 * VOXEL
    assert proc.poll() is None


def test_offline_bag_through_the_service(ros, synthetic_bag):
    from perch_common.ros.conversions import mesh_from_msg
    from perch_interfaces.msg import ReconstructionProgress

    client, proc, _ = ros
    received = []
    sub = client.create_subscription(ReconstructionProgress, "/perch/reconstruct/progress", received.append, 10)
    reply = _reconstruct(client, str(synthetic_bag), use_poses=True)  # spins the client: progress arrives meanwhile
    client.destroy_subscription(sub)
    assert reply.success, reply.message
    # While the bag is read its report is zeros with no frame yet; once integrating, the bag's pose frame.
    bag = [p for p in received if p.mode == ReconstructionProgress.MODE_BAG]
    assert bag and all(p.bag_path == str(synthetic_bag) for p in bag), [(p.mode, p.bag_path) for p in received]
    assert all(p.header.frame_id == ("map_gravity_aligned" if p.frames_received else "") for p in bag)
    assert [p.frames_received for p in bag] == sorted(p.frames_received for p in bag) and bag[-1].frames_received <= 40
    offline, _ = reconstruct_bag(synthetic_bag, ReconstructionConfig(), use_poses=True)
    assert abs(mesh_from_msg(reply.mesh).num_faces - offline.num_faces) <= 0.01 * offline.num_faces
    assert "up from gravity" in reply.message


def test_error_replies_keep_the_node_running(ros, tmp_path):
    from std_srvs.srv import Trigger

    from perch_interfaces.srv import CleanMesh

    client, proc, _ = ros
    reply = _reconstruct(client, str(tmp_path / "missing.mcap"))
    assert not reply.success and "missing.mcap: no such bag file" in reply.message
    corrupt = tmp_path / "corrupt.mcap"
    corrupt.write_bytes(b"\x89MCAP0\r\n" + b"\x00" * 100)
    reply = _reconstruct(client, str(corrupt))
    assert not reply.success and "corrupt.mcap" in reply.message
    reply = call_service(client, CleanMesh, "/perch/clean_mesh", CleanMesh.Request())
    assert not reply.success and "mesh to clean: mesh is empty" in reply.message
    assert call_service(client, Trigger, "/perch/reconstruct/reset", Trigger.Request(), resend_every=5).success
    reply = _reconstruct(client)
    assert not reply.success and reply.message.startswith("nothing integrated")
    assert proc.poll() is None


def test_clean_mesh_service(ros, synthetic):
    from perch_common.ros.conversions import mesh_from_msg, mesh_to_msg, vector_msg
    from perch_interfaces.srv import CleanMesh

    client, _, _ = ros
    scene = synthetic[0]
    request = CleanMesh.Request(mesh=mesh_to_msg(scene.mesh), gravity=vector_msg(np.array([0, 0, -1.0])),
                                target_faces=5000)
    reply = call_service(client, CleanMesh, "/perch/clean_mesh", request)
    assert reply.success, reply.message
    from perch_common.ros.static_transforms import alignment_from_msg

    cleaned = mesh_from_msg(reply.mesh)
    assert cleaned.num_faces <= 5000 and cleaned.vertex_colors is not None
    # The reply is gravity-aligned (walls onto the axes): its alignment takes it back to the input frame.
    assert reply.alignment.header.frame_id == "map" and reply.alignment.child_frame_id == "map_gravity_aligned"
    assert reply.mesh.header.frame_id == "map_gravity_aligned" and reply.up_source == "gravity"
    back = cleaned.transformed(alignment_from_msg(reply.alignment).to_input())
    np.testing.assert_allclose(back.bounds(), scene.mesh.bounds(), atol=0.15)
    assert list(reply.warnings) == []
    # What the cleaning repaired comes back one line each (a mission's failure quotes them).
    from perch_common.mesh import Mesh

    faces = scene.mesh.faces
    doubled = Mesh(scene.mesh.vertices, np.vstack([faces, faces[: len(faces) // 50]]), scene.mesh.vertex_colors)
    request.mesh = mesh_to_msg(doubled)
    reply = call_service(client, CleanMesh, "/perch/clean_mesh", request)
    assert reply.success and f"removed {len(faces) // 50} duplicate or degenerate faces" in reply.warnings, reply.warnings
    assert reply.message.endswith("; ".join(reply.warnings))


def _progress_during(client, call) -> tuple:
    """(reply of `call()`, the progress messages that arrived while it ran: the call spins the client)."""
    from perch_interfaces.msg import ReconstructionProgress

    received = []
    sub = client.create_subscription(ReconstructionProgress, "/perch/reconstruct/progress", received.append, 10)
    try:
        return call(), received
    finally:
        client.destroy_subscription(sub)


def test_real_kitchen_progress_live_and_bag_in_the_pose_and_odometry_frames(ros, kitchen_dir, tmp_path):
    """The real 7-Scenes frames: played live, then reconstructed as a bag with its poses and with odometry."""
    from std_srvs.srv import Trigger

    from perch_interfaces.msg import ReconstructionProgress

    client, proc, log = ros
    bag = tmp_path / "kitchen.mcap"
    done = subprocess.run([sys.executable, "-m", "perch_common.cli", "bag", "from-frames", str(kitchen_dir),
                           "-o", str(bag), "--limit", "30"], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert call_service(client, Trigger, "/perch/reconstruct/reset", Trigger.Request(), resend_every=5).success
    play = subprocess.run([sys.executable, "-m", "perch_common.cli", "bag", "play", str(bag), "--rate", "1",
                           "--wait-subscribers", "120"], capture_output=True, text=True, timeout=300)
    assert play.returncode == 0, play.stderr
    live = _progress(client, until=lambda status: status.frames_integrated == 30)[-1]
    assert live.mode == live.MODE_LIVE and live.header.frame_id == "map_gravity_aligned", log.read_text()
    assert (live.frames_received, live.frames_integrated, live.frames_dropped, live.frames_without_pose) == (30, 30, 0, 0)
    assert list(live.dropped_counts) == [0, 0, 0] and live.blocks > 0 and live.faces == 0
    for use_poses, frame in ((True, "map_gravity_aligned"), (False, "odom_gravity_aligned")):
        reply, received = _progress_during(client, lambda: _reconstruct(client, str(bag), use_poses=use_poses))
        assert reply.success and reply.frames_integrated == 30, reply.message
        assert reply.mesh.header.frame_id == frame
        reports = [p for p in received if p.mode == ReconstructionProgress.MODE_BAG]
        assert reports and all(p.bag_path == str(bag) for p in reports)
        assert all(p.header.frame_id == (frame if p.frames_received else "") for p in reports)
        assert all(p.frames_received <= 30 and p.frames_lost == 0 for p in reports)
    # The call over, the topic reports the live integration again, unchanged by the bags.
    after = _progress(client)[-1]
    assert after.mode == after.MODE_LIVE and after.frames_integrated == 30 and after.bag_path == ""
    assert call_service(client, Trigger, "/perch/reconstruct/reset", Trigger.Request(), resend_every=5).success
    assert proc.poll() is None
