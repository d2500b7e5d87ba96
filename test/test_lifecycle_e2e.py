"""A graph that runs beside a dispatcher: `perch plan --no-launch` clients against one running graph.

The module's graph is started like `perch launch` (every node its own process); the clients are
real `perch plan` processes, killed, cancelled and refused as a user or a dispatcher would.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

pytestmark = pytest.mark.ros

CAMERAS = 2
PLAN = ["plan", "--scene", "3", "--kind", "room", "--cameras", str(CAMERAS), "--no-launch", "--quiet"]


def perch(*args, log: Path | None = None, timeout: float = 300.0):
    """Run `perch ARGS` in the test graph's environment: the CompletedProcess, or with `log` the running
    Popen writing its output there."""
    cmd = [sys.executable, "-m", "perch_common.cli", *map(str, args)]
    if log is not None:
        with open(log, "w") as stream:
            return subprocess.Popen(cmd, env=dict(os.environ), stdout=stream, stderr=subprocess.STDOUT)
    return subprocess.run(cmd, env=dict(os.environ), capture_output=True, text=True, timeout=timeout)


def check_complete_outputs(out: Path) -> dict:
    """Every output of a successful mission is there and agrees with the others; returns waypoints.yaml."""
    assert not (out / "FAILED").exists()
    doc = yaml.safe_load((out / "waypoints.yaml").read_text())
    assert len(doc["waypoints"]) == CAMERAS, doc
    assert sorted(w["drone_index"] for w in doc["waypoints"]) == list(range(CAMERAS))
    report = (out / "report.html").read_text()
    for i in range(CAMERAS):
        assert f"report_files/camera_{i}.png" in report
        assert (out / "report_files" / f"camera_{i}.png").stat().st_size > 1000
    assert (out / "run.rrd").stat().st_size > 5000 and (out / "run.mcap").stat().st_size > 5000
    return doc


def wait_for_output(proc: subprocess.Popen, log: Path, text: str, timeout: float) -> str:
    """Wait until the client's output holds `text` (it runs with progress lines, one per stage)."""
    seen = ""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        seen = log.read_text()
        if text in seen:
            return seen
        if proc.poll() is not None:
            break
        time.sleep(0.2)
    raise AssertionError(f"{text!r} not printed within {timeout:.0f} s; output so far:\n{seen}")


def run_when_free(node, goal, within: float):
    """Run a mission, retrying while the coordinator still refuses goals; (result, seconds until accepted)."""
    from perch_operator.api.client import GoalRejected, run_mission

    started = time.monotonic()
    while True:
        try:
            accepted_after = time.monotonic() - started
            return run_mission(node, goal, timeout=300), accepted_after
        except GoalRejected:
            if time.monotonic() - started > within:
                raise
            time.sleep(0.5)


def free_after_the_kill(graph, goal, what: str) -> None:
    """Once a mission's client was SIGKILLed, the next mission is accepted within 30 s (lease + client_grace)."""
    result, freed_after = run_when_free(graph.node, goal, within=30)
    assert result.success, result.message
    print(f"coordinator free {freed_after:.1f} s after {what} was killed")


@pytest.fixture(scope="module")
def small_goal():
    from perch_common.scene_generator import generate_scene
    from perch_operator.api.client import scene_goal

    return scene_goal(generate_scene(3, "room"), CAMERAS)


def test_several_no_launch_clients_get_complete_outputs(graph, tmp_path):
    first = None
    for i in range(3):
        out = tmp_path / f"run{i}"
        done = perch(*PLAN, "--auto-accept", "-o", out)
        assert done.returncode == 0, done.stdout + done.stderr
        doc = check_complete_outputs(out)
        perches = [{k: v for k, v in w.items() if k not in ("proposal_id", "mission_id")} for w in doc["waypoints"]]
        first = first or perches
        # Same scene, same seed: the same perches every time (proposal and mission ids change).
        assert perches == first
    # A folder holding an earlier mission is refused without --overwrite, and left as it was.
    before = (tmp_path / "run0" / "waypoints.yaml").read_text()
    refused = perch(*PLAN, "--auto-accept", "-o", tmp_path / "run0")
    assert refused.returncode == 1 and "add --overwrite" in refused.stderr
    assert (tmp_path / "run0" / "waypoints.yaml").read_text() == before


def test_a_failed_mission_leaves_a_reason_and_no_stale_outputs(graph, tmp_path):
    out = tmp_path / "run"
    assert perch(*PLAN, "--auto-accept", "-o", out).returncode == 0
    failed = perch(*PLAN, "--auto-accept", "--overwrite", "--target", "box:nan,1,1,1,1,1", "-o", out)
    assert failed.returncode == 1 and "FAILED" in failed.stderr
    reason = (out / "FAILED").read_text()
    assert "target.box.pose.position.x = nan: must be a finite number" in reason
    # The last good set stays whole (issue 22: a failed re-run keeps the last good waypoints and says
    # so); the failure's recording sits beside it.
    assert "the last good waypoints.yaml" in reason
    assert sorted(p.name for p in out.iterdir() if p.name != "logs") == [
        ".perch-outputs.json", "FAILED", "failed.mcap", "report.html", "report_files", "run.mcap", "run.rrd",
        "waypoints.yaml"]
    # No partial staging folder is left beside it.
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


def test_a_killed_client_frees_the_graph_and_a_refused_one_writes_nothing(graph, tmp_path, small_goal):
    import rclpy
    from rclpy.action import ActionClient

    from perch_common.conventions import MISSION_ACTION
    from perch_interfaces.action import PlanPerches

    # A bystander reading every mission's feedback from before the goal (a console or a robot's commander
    # left open): the coordinator must still see the killed client go, not wait out confirm_timeout (600 s).
    bystander = rclpy.create_node("bystander_console")
    reader = ActionClient(bystander, PlanPerches, MISSION_ACTION)
    log = tmp_path / "waiting.log"
    try:
        waiting = perch(*PLAN[:-1], "-o", tmp_path / "waiting", log=log)   # with progress, no auto-accept
        try:
            wait_for_output(waiting, log, "confirm:", 240)
            refused = perch(*PLAN, "--auto-accept", "-o", tmp_path / "refused")
            assert refused.returncode == 1 and "rejected the goal" in refused.stderr
            assert not (tmp_path / "refused").exists()
            assert not [p for p in tmp_path.iterdir() if p.name.startswith(".refused")]
        finally:
            waiting.kill()   # SIGKILL
            waiting.wait()
        free_after_the_kill(graph, small_goal, "the client")
    finally:
        reader.destroy()
        bystander.destroy_node()


# A plain ROS 2 action client (no Perch client code, so no presence writer): it sends a goal that waits
# for its operator and prints each stage its feedback names.
PLAIN_CLIENT = """
import rclpy
from rclpy.action import ActionClient
from perch_common.conventions import MISSION_ACTION
from perch_common.scene_generator import generate_scene
from perch_interfaces.action import PlanPerches
from perch_operator.api.client import scene_goal

rclpy.init()
node = rclpy.create_node("plain_ros_client")
client = ActionClient(node, PlanPerches, MISSION_ACTION)
client.wait_for_server()
sent = client.send_goal_async(scene_goal(generate_scene(3, "room"), 2, auto_accept=False),
                              feedback_callback=lambda m: print("stage", m.feedback.stage, flush=True))
rclpy.spin_until_future_complete(node, sent)
print("accepted" if sent.result().accepted else "rejected", flush=True)
rclpy.spin(node)
"""


def test_a_killed_plain_ros_client_frees_the_graph_with_bystanders_open(graph, tmp_path, small_goal):
    """A plain ROS client has no presence writer: the coordinator follows the goal's first feedback
    readers of action clients of the mission, and leaves out Perch's observers (here a robot node's
    PerchCommander, left open) and tools that only read the feedback (here a plain subscription, as
    Foxglove's bridge or `ros2 topic echo` make)."""
    import rclpy

    from perch_common.conventions import MISSION_FEEDBACK_TOPIC
    from perch_interfaces.action import PlanPerches
    from perch_operator.api.commander import PerchCommander

    commander = PerchCommander(node_name="bystander_commander")   # reads every mission's feedback
    tool = rclpy.create_node("feedback_echo")
    tool.create_subscription(PlanPerches.Impl.FeedbackMessage, MISSION_FEEDBACK_TOPIC, lambda _: None, 10)
    log = tmp_path / "plain.log"
    try:
        with open(log, "w") as stream:
            plain = subprocess.Popen([sys.executable, "-c", PLAIN_CLIENT], env=dict(os.environ), stdout=stream,
                                     stderr=subprocess.STDOUT)
        try:
            wait_for_output(plain, log, "stage confirm", 240)   # waits for its operator now
        finally:
            plain.kill()   # SIGKILL
            plain.wait()
        free_after_the_kill(graph, small_goal, "the plain client")
    finally:
        tool.destroy_node()
        commander.destroy()


def test_perch_operator_cancel_ends_a_stuck_mission(graph, tmp_path, small_goal):
    out = tmp_path / "stuck"
    log = tmp_path / "stuck.log"
    stuck = perch(*PLAN[:-1], "-o", out, log=log)
    try:
        wait_for_output(stuck, log, "confirm:", 240)
        cancel = perch("operator", "cancel")
        assert cancel.returncode == 0 and "cancelling 1 mission(s)" in cancel.stdout, cancel.stdout + cancel.stderr
        stuck.wait(60)
    finally:
        stuck.kill()
        stuck.wait()
    assert stuck.returncode == 1
    assert "cancelled while waiting for operator decisions" in (out / "FAILED").read_text()
    assert not (out / "waypoints.yaml").exists()
    nothing = perch("operator", "cancel")
    assert nothing.returncode == 0 and "no mission is running" in nothing.stdout
    result, _ = run_when_free(graph.node, small_goal, within=10)
    assert result.success, result.message


def test_cancelling_during_a_long_segment_stops_it_and_the_next_mission_is_fast(graph, restart_with, small_goal,
                                                                                 request):
    import trimesh
    from rclpy.qos import qos_profile_services_default

    from perch_common.mesh import Mesh
    from perch_common.ros.conversions import mesh_to_msg
    from perch_common.ros.testing import poll_until
    from perch_common.scene_generator import generate_scene
    from perch_interfaces.action import PlanPerches
    from perch_interfaces.srv import Segment
    from perch_operator.api.client import run_mission
    from perch_operator.coordinator.action_client import RegisteringActionClient

    started = time.monotonic()
    assert run_mission(graph.node, small_goal, timeout=300).success
    baseline = time.monotonic() - started
    scene = generate_scene(2, "apartment")
    vertices, faces = trimesh.remesh.subdivide(*trimesh.remesh.subdivide(scene.mesh.vertices, scene.mesh.faces))
    big = PlanPerches.Goal(mesh=mesh_to_msg(Mesh(vertices, faces)), num_cameras=CAMERAS, auto_accept=True, seed=-1)
    # The client exists before the coordinator restarts, so the new coordinator discovers its response
    # reader while it starts: a server answering a goal before it has matched the client's reader drops
    # the response (rmw: "failed to send response (timeout)"), and the goal is never seen as accepted.
    # Sent while a spinner thread spins the node: rclpy's own ActionClient can drop the answer (rclpy#1123).
    client = RegisteringActionClient(graph.node, PlanPerches, "perch/plan_perches")
    request.addfinalizer(client.destroy)   # a failure must leave no client of perch/plan_perches behind
    # Without cleaning, segmentation gets all 750k faces (seconds of work even on an idle machine).
    with restart_with("perch_operator", {"clean_given_mesh": False}):
        events: list = []
        sub = graph.node.create_subscription(Segment.Event, "/perch/segment/_service_event", events.append,
                                             qos_profile_services_default)
        with graph.spinner(graph.node):
            # Both event writers matched (volatile): the service's, and the action's, which the goal's use.
            poll_until(lambda: sub.get_publisher_count() >= 2, 60, "segment's two event writers")
            assert client.wait_for_server(timeout_sec=30)
            sent = client.send_goal_async(big)
            deadline = time.monotonic() + 180
            result_future = None
            while not (sent.done() and any(e.info.event_type == 1 for e in events)):  # REQUEST_RECEIVED
                assert time.monotonic() < deadline, "segmentation never received the request"
                if sent.done() and result_future is None:
                    result_future = sent.result().get_result_async()
                if result_future is not None and result_future.done():
                    raise AssertionError(f"the mission ended before segmenting: {result_future.result().result.message}")
                time.sleep(0.1)
            time.sleep(1.0)
            cancel_sent = time.monotonic()
            sent.result().cancel_goal_async()
            while not any(e.info.event_type == 2 for e in events):  # REQUEST... RESPONSE_SENT
                assert time.monotonic() - cancel_sent < 60, "segmentation kept computing after the cancel"
                time.sleep(0.1)
            stopped_after = time.monotonic() - cancel_sent
        reply = next(e for e in events if e.info.event_type == 2).response[0]
        graph.node.destroy_subscription(sub)
        assert not reply.success and "cancelled" in reply.message, reply.message
        started = time.monotonic()
        result, _ = run_when_free(graph.node, small_goal, within=30)
        after_cancel = time.monotonic() - started
    assert result.success, result.message
    assert after_cancel < 2 * baseline + 10, f"next mission {after_cancel:.1f} s, normal {baseline:.1f} s"
    print(f"segment stopped {stopped_after:.1f} s after the cancel; next mission {after_cancel:.1f} s "
          f"(normal {baseline:.1f} s)")
