"""Perch beside other ROS tools: a recording started after a mission, rosbag2's channel metadata.

One graph (each node its own process) serves the module; the first test runs the mission the
others look at.
"""

from __future__ import annotations

import io
import re
import signal
import subprocess
import sys
import time

import pytest
import yaml

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
    from perch_operator.api.client import run_mission

    scene = generate_scene(3, "room")
    goal = PlanPerches.Goal(mesh=mesh_to_msg(scene.mesh), target=target_to_msg(scene.target),
                            num_cameras=CAMERAS, auto_accept=True, seed=-1)
    result = run_mission(graph.node, goal, timeout=300)
    assert result.success, result.message
    return result


def record_until(node, path, wanted, timeout: float = 60.0):
    """Record like `perch record` (latched) until every `wanted` topic has a message (or the deadline)."""
    from perch_operator.cli.runner import spin_for
    from perch_operator.outputs.recorder import MissionRecorder

    recorder = MissionRecorder(node, path, latched=True)
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline and not all(recorder.counts.get(t) for t in wanted):
        recorder.refresh()
        spin_for(node, 0.2)
    recorder.close()
    return recorder


def test_a_recording_started_after_the_mission_holds_the_latched_state(graph, mission, tmp_path):
    from perch_operator.outputs.runfile import channel_counts, iter_messages

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


PLAN = [sys.executable, "-m", "perch_common.cli", "plan", "--scene", "3", "--kind", "room", "--cameras", "2",
        "--auto-accept", "--quiet"]


def test_plan_uses_the_perch_graph_already_running_on_the_users_domain(graph, mission, tmp_path):
    """The module's graph runs on ROS_DOMAIN_ID: perch plan runs its mission there, never elsewhere."""
    import os

    domain = os.environ["ROS_DOMAIN_ID"]
    done = subprocess.run(PLAN + ["-o", str(tmp_path / "beside")], env=dict(os.environ), capture_output=True,
                          text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    assert f"perch: using the Perch graph already running on ROS domain {domain}" in done.stderr, done.stderr[-2000:]
    assert "free domain" not in done.stderr and "starting perch_" not in done.stderr
    assert len(yaml.safe_load((tmp_path / "beside" / "waypoints.yaml").read_text())["waypoints"]) == 2
    print("perch plan beside a running graph:", done.stderr.strip().splitlines()[0])
    # Its parameters are the running graph's: -p cannot apply, and says so.
    refused = subprocess.run(PLAN + ["-o", str(tmp_path / "p"), "-p", "perch_placement:num_cameras:=3"],
                             env=dict(os.environ), capture_output=True, text=True, timeout=120)
    assert refused.returncode == 1 and "-p cannot change its parameters" in refused.stderr, refused.stderr[-2000:]


def test_plan_refuses_perch_nodes_it_cannot_use(graph, tmp_path):
    """Only a segmentation node runs in namespace `partial`: not a mission graph, and plan will not
    start a second set of nodes beside it (two segment services on one name)."""
    import os

    env = dict(os.environ)
    launched = subprocess.Popen([sys.executable, "-m", "perch_common.cli", "--namespace", "partial", "launch",
                                 "--nodes", "perch_segmentation", "--log-dir", str(tmp_path / "logs")],
                                env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 120
        while "/partial/perch/segment" not in {n for n, _ in graph.node.get_service_names_and_types()}:
            assert time.monotonic() < deadline and launched.poll() is None, "the partial graph did not start"
            time.sleep(0.2)
        done = subprocess.run([sys.executable, "-m", "perch_common.cli", "--namespace", "partial"] + PLAN[3:]
                              + ["-o", str(tmp_path / "out")], env=env, capture_output=True, text=True, timeout=300)
        assert done.returncode == 1, done.stderr[-2000:]
        assert (f"ROS domain {env['ROS_DOMAIN_ID']}, namespace /partial already has Perch nodes this perch cannot "
                "use (/partial/perch/crop is missing") in done.stderr, done.stderr[-2000:]
        print("perch plan beside a partial graph:", done.stderr.strip().splitlines()[-1])
        assert launched.poll() is None, "the partial graph was disturbed"
    finally:
        launched.send_signal(signal.SIGINT)
        launched.communicate(timeout=30)


def _readme_example() -> str:
    from pathlib import Path

    text = (Path(__file__).resolve().parents[1] / "src" / "perch_operator" / "README.md").read_text()
    block = text.split("<!-- commander-example -->", 1)[1]
    return block.split("```python", 1)[1].split("```", 1)[0]


def test_the_readme_commander_example_runs(graph, mission):
    import os

    done = subprocess.run([sys.executable, "-c", _readme_example()], env=dict(os.environ), capture_output=True,
                          text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    lines = done.stdout.strip().splitlines()
    assert lines[-1] == "MissionResult.SUCCEEDED 2 waypoints", done.stdout[-2000:]
    assert any(line.startswith("confirm: ") for line in lines) and any(line.startswith("segment: ") for line in lines)
    print("README example output:\n" + "\n".join(lines))


def test_the_commander_inside_a_users_node_and_executor(graph, mission):
    """The user's node, spun by the user's executor; the commander never spins: start, follow the
    feedback, decide (reject one, accept the rest), get the result; then cancel a second mission."""
    import threading

    import rclpy
    from rclpy.executors import MultiThreadedExecutor

    from perch_common.ros.conversions import mesh_to_msg, target_to_msg
    from perch_common.scene_generator import generate_scene
    from perch_operator.api.commander import MissionResult, PerchCommander

    node = rclpy.create_node("users_own_node")
    executor = MultiThreadedExecutor(num_threads=2)
    executor.add_node(node)
    spinner = threading.Thread(target=executor.spin, daemon=True)
    spinner.start()
    try:
        perch = PerchCommander(node=node, spin=False)
        assert perch.waitUntilReady(timeout=60)
        room = generate_scene(3, "room")
        goal = dict(mesh=mesh_to_msg(room.mesh), target=target_to_msg(room.target), num_cameras=2)
        assert perch.startMission(**goal)
        assert perch.getResult() == MissionResult.UNKNOWN and not perch.isMissionComplete()
        stages, decided, rejected = [], set(), None
        deadline = time.monotonic() + 300
        while not perch.isMissionComplete():
            assert time.monotonic() < deadline, "the mission did not end"
            feedback = perch.getFeedback()
            if feedback and (not stages or stages[-1] != feedback.stage):
                stages.append(feedback.stage)
            for proposal in perch.getProposals():
                if proposal.id in decided:
                    continue
                decided.add(proposal.id)
                if rejected is None:
                    rejected = proposal.id
                    answer = perch.rejectProposal(proposal.id, "blocks the door")
                else:
                    answer = perch.acceptProposal(proposal.id)
                while not answer.done():
                    time.sleep(0.05)
                assert answer.result().success, answer.result().message
            time.sleep(0.05)
        assert perch.getResult() == MissionResult.SUCCEEDED, perch.getMissionResult().message
        result = perch.getMissionResult()
        assert len(result.waypoints) == 2 and rejected is not None and len(decided) == 3   # 2 + the replacement
        # getFeedback() is the latest feedback (polled, as nav2_simple_commander's is): a quick stage such as
        # crop may come and go between two polls, so the stages seen are checked for their order only.
        pipeline = ["clean", "crop", "segment", "review", "filter", "optimise", "confirm"]
        assert stages[0] == "clean" and "confirm" in stages, stages
        assert [pipeline.index(stage) for stage in stages] == sorted(pipeline.index(stage) for stage in stages), stages
        # A second mission, cancelled while it runs.
        assert perch.startMission(**goal)
        deadline = time.monotonic() + 120
        while perch.getFeedback() is None or perch.getFeedback().stage in ("confirm",):
            assert time.monotonic() < deadline
            time.sleep(0.05)
        perch.cancelMission()
        deadline = time.monotonic() + 120
        while not perch.isMissionComplete():
            assert time.monotonic() < deadline, "the cancelled mission did not end"
            time.sleep(0.05)
        assert perch.getResult() == MissionResult.CANCELED, perch.getMissionResult().message
        perch.destroy()
    finally:
        executor.shutdown()
        spinner.join(5)
        node.destroy_node()


def test_mission_feedback_moves_inside_the_reconstruction(graph, mission, tmp_path):
    """A bag mission: while /perch/reconstruct reads the bag, feedback carries the fraction of its
    frames read (stage_fraction) and the mission's fraction moves with it, not only between stages."""
    import numpy as np

    from perch_common.ros.conversions import target_to_msg
    from perch_interfaces.action import PlanPerches
    from perch_operator.api.client import ProgressPrinter, run_mission
    from perch_reconstruction.bag_write import write_bag
    from perch_reconstruction.synthetic import DEFAULT_INTRINSICS, synthetic_room_frames

    scene, frames = synthetic_room_frames(seed=1, count=90, turn=2 * np.pi)
    bag = tmp_path / "scan.mcap"
    write_bag(bag, frames, DEFAULT_INTRINSICS, gravity=np.array([0.0, 0.0, -1.0]))
    received = []
    printed = io.StringIO()
    printer = ProgressPrinter(printed, tty=False)

    def on_feedback(feedback):
        received.append((time.monotonic(), feedback))
        printer(feedback)

    goal = PlanPerches.Goal(bag_path=str(bag), target=target_to_msg(scene.target), num_cameras=2, auto_accept=True,
                            seed=-1)
    result = run_mission(graph.node, goal, timeout=600, on_feedback=on_feedback)
    assert result.success, result.message
    inside = [f for _, f in received if f.stage == "reconstruct" and 0.0 < f.stage_fraction < 1.0]
    assert inside, [(f.stage, f.stage_fraction, f.message) for _, f in received]
    assert all("frames " in f.message and "/90 read" in f.message for f in inside)
    fractions = [f.fraction for _, f in received if f.stage == "reconstruct"]
    assert fractions[0] == 0.0 and 0.0 < max(fractions) < 0.35 and fractions == sorted(fractions)
    print("reconstruction progress lines:\n" + "\n".join(
        f"  {f.stage} {100 * f.fraction:.0f} % (stage {100 * f.stage_fraction:.0f} %): {f.message}"
        for _, f in received if f.stage == "reconstruct"))


def test_files_written_atomically_get_the_umasks_mode(tmp_path):
    """waypoints.yaml and bags go through atomic_path (mkstemp makes 0600): the finished file is
    readable as any file the user writes is."""
    import os

    from perch_common.outputs import atomic_path, current_umask

    previous = os.umask(0o022)
    try:
        assert current_umask() == 0o022
        with atomic_path(tmp_path / "waypoints.yaml") as partial:
            partial.write_text("waypoints: []\n")
        assert (tmp_path / "waypoints.yaml").stat().st_mode & 0o777 == 0o644
        os.umask(0o077)
        with atomic_path(tmp_path / "private.yaml") as partial:
            partial.write_text("x: 1\n")
        assert (tmp_path / "private.yaml").stat().st_mode & 0o777 == 0o600
    finally:
        os.umask(previous)


def test_mission_feedback_moves_inside_every_long_stage(graph, mission):
    """Segmentation phases, filter surfaces and placement cameras reach the mission feedback as
    stage_fraction (perch/stage_progress of the coordinator's own calls), and the bar moves with them."""
    from perch_common.ros.conversions import mesh_to_msg, target_to_msg
    from perch_common.scene_generator import generate_scene
    from perch_interfaces.action import PlanPerches
    from perch_operator.api.client import ProgressPrinter, run_mission

    scene = generate_scene(3, "room")
    received = []
    printed = io.StringIO()
    printer = ProgressPrinter(printed, tty=True)

    def on_feedback(feedback):
        received.append(feedback)
        printer(feedback)

    goal = PlanPerches.Goal(mesh=mesh_to_msg(scene.mesh), target=target_to_msg(scene.target),
                            num_cameras=CAMERAS, auto_accept=True, seed=-1)
    result = run_mission(graph.node, goal, timeout=300, on_feedback=on_feedback)
    printer.close()
    assert result.success, result.message
    print("perch plan's progress bar, one line per update:\n" + "\n".join(
        "  " + line.strip() for line in printed.getvalue().replace("\n", "\r").split("\r") if line.strip()))
    for stage in ("segment", "filter", "optimise"):
        inside = [f for f in received if f.stage == stage and 0.0 < f.stage_fraction < 1.0]
        assert inside, (stage, [(f.stage, f.stage_fraction, f.message) for f in received])
        within = [f.stage_fraction for f in inside]
        assert within == sorted(within)
    fractions = [f.fraction for f in received]
    assert fractions == sorted(fractions) and fractions[-1] <= 1.0
    optimise = [f.message for f in received if f.stage == "optimise" and f.stage_fraction > 0]
    assert any(m.startswith("camera ") for m in optimise), optimise
