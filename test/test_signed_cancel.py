"""The signed mission cancel of a networked graph (issue 22, item 6), against a real coordinator process.

The coordinator runs as a child process on a ROS domain of its own (no later module's graph can see it)
and is always stopped when the test ends. Its mission waits on a stand-in stage that works until the
test releases it, so the mission is certainly running while the cancels arrive. The coordinator says
why it refuses a cancel on /rosout; the test waits for each refusal before sending the next.
"""

from __future__ import annotations

import os
import threading

import pytest

pytestmark = pytest.mark.ros

REFUSED = "refused a mission cancel: "
WAIT = 120.0   # s for discovery and replies on a loaded machine


@pytest.fixture
def own_domain(monkeypatch, tmp_path):
    """This process's ROS and DDS environment for a domain nobody else here uses, networked (commands
    signed with a key file of the test's own); os.environ is restored afterwards."""
    from perch_common.launch import current_domain, free_domain
    from perch_common.ros.testing import isolated_ros_env

    domain = free_domain(avoid={0, current_domain()})
    if domain is None:
        pytest.skip("no free ROS domain on this host")
    env = isolated_ros_env(domain)   # the loopback profile: networked commands, host-only transports
    env.update(PERCH_NETWORK="1", PERCH_KEY_FILE=str(tmp_path / "network.key"))
    for key, value in env.items():
        if os.environ.get(key) != value:
            monkeypatch.setenv(key, value)
    import perch_common.network_auth as auth

    monkeypatch.setattr(auth, "_process_key", None)   # this test's key, not one an earlier test loaded
    return domain


def test_a_networked_mission_ends_on_a_signed_cancel_taken_once(own_domain, tmp_path):
    """The action's unsigned cancel is refused, and so are mission cancels that are unsigned, signed with
    another key, changed after signing (reason, service) or for another mission: the mission runs on.
    The signed one (as `perch plan`'s Ctrl-C, `perch operator cancel` and PerchCommander send it:
    MissionCanceller) ends it CANCELED, and the same token sent again is refused as a replay."""
    import rclpy
    from action_msgs.msg import GoalStatus
    from rcl_interfaces.msg import Log
    from rclpy.action import ActionClient
    from rclpy.context import Context
    from rclpy.executors import MultiThreadedExecutor, SingleThreadedExecutor

    import perch_common.network_auth as auth
    from perch_common.conventions import MISSION_ACTION
    from perch_common.ros.conversions import mesh_to_msg, target_to_msg
    from perch_common.ros.service import CANCEL_TOPIC
    from perch_common.ros.spinning import keep_spinning
    from perch_common.ros.testing import node_process, poll_until
    from perch_common.scene_generator import generate_scene
    from perch_interfaces import srv
    from perch_interfaces.action import PlanPerches
    from perch_interfaces.msg import StageCancel
    from perch_operator.api.client import MissionCanceller
    from perch_operator.outputs.mission_data import mission_id_text

    key = auth.process_key()   # created now: the coordinator reads the same file
    log = tmp_path / "coordinator.log"
    client_context, stage_context = Context(), Context()
    rclpy.init(context=client_context, domain_id=own_domain)
    rclpy.init(context=stage_context, domain_id=own_domain)
    release = threading.Event()
    replying = threading.Condition()
    in_call = [0]   # stand-in calls whose reply has not gone out: it must, before the node is destroyed

    def stall(request, response):
        with replying:
            in_call[0] += 1
        release.wait(WAIT * 3)
        response.success, response.message = False, "released by the test"
        return response

    def counted(send):
        def send_then_count(response, header):
            try:
                send(response, header)
            finally:
                with replying:
                    in_call[0] -= 1
                    replying.notify_all()
        return send_then_count

    # The stand-in stage in a thread of its own (its callbacks block until released).
    stage_side = MultiThreadedExecutor(num_threads=2, context=stage_context)
    stage_thread = threading.Thread(target=keep_spinning, args=(stage_side,), daemon=True)
    client_side = SingleThreadedExecutor(context=client_context)
    nodes = []
    try:
        stages = rclpy.create_node("stalling_stages", context=stage_context)
        nodes.append(stages)
        for name, srv_type in (("perch/clean_mesh", srv.CleanMesh), ("perch/segment", srv.Segment)):
            service = stages.create_service(srv_type, name, stall)
            service.send_response = counted(service.send_response)
        stage_side.add_node(stages)
        stage_thread.start()
        caller = rclpy.create_node("remote_operator", context=client_context)
        nodes.append(caller)
        client_side.add_node(caller)
        said: list[str] = []   # the coordinator's log lines, from /rosout
        caller.create_subscription(Log, "/rosout", lambda m: said.append(m.msg) if m.name == "perch_operator"
                                   else None, 100)
        actions = ActionClient(caller, PlanPerches, MISSION_ACTION)
        canceller = MissionCanceller(caller)
        sent: list[StageCancel] = []
        publish = canceller.publisher.publish
        canceller.publisher.publish = lambda msg: (sent.append(msg), publish(msg))

        def spin_until(condition, what: str, timeout: float = WAIT):
            return poll_until(lambda: client_side.spin_once(timeout_sec=0.02) or condition(), timeout, what)

        with node_process("perch_operator.coordinator.node", log_path=log) as coordinator:
            def matched() -> bool:   # every reader the coordinator has on the cancel topic matched ours
                assert coordinator.poll() is None, f"the coordinator exited: {log.read_text()[-2000:]}"
                readers = [e for e in caller.get_subscriptions_info_by_topic("/" + CANCEL_TOPIC)
                           if e.node_name == "perch_operator"]
                return bool(readers) and canceller.publisher.get_subscription_count() >= len(readers)

            spin_until(actions.server_is_ready, "the coordinator's action appeared")
            spin_until(matched, "the cancel publisher matched the coordinator")
            scene = generate_scene(1, "room")
            answer = actions.send_goal_async(PlanPerches.Goal(
                mesh=mesh_to_msg(scene.mesh), target=target_to_msg(scene.target), up_axis="+z", auto_accept=True))
            spin_until(answer.done, "the goal was answered")
            handle = answer.result()
            assert handle.accepted
            spin_until(lambda: handle.status == GoalStatus.STATUS_EXECUTING, "the mission ran")
            mission = mission_id_text(handle.goal_id)

            unsigned = handle.cancel_goal_async()
            spin_until(unsigned.done, "the standard cancel was answered")
            assert not unsigned.result().goals_canceling

            def refusal(token: str, mission_id: str = mission, reason: str = "stop") -> str:
                """Send one mission cancel; the coordinator's reason for refusing it."""
                before = [m for m in said if m.startswith(REFUSED)]
                publish(StageCancel(service=MISSION_ACTION, request_id=mission_id, reason=reason, auth=token))
                refusals = spin_until(lambda: [m for m in said if m.startswith(REFUSED)][len(before):],
                                      "the cancel was refused")
                return refusals[0]

            assert "no authentication token" in refusal("")
            other_key = os.urandom(32)
            assert "does not match" in refusal(auth.sign(other_key, "stage_cancel", MISSION_ACTION, mission, "stop"))
            assert "does not match" in refusal(auth.sign(key, "stage_cancel", MISSION_ACTION, mission, "stop"),
                                               reason="go")
            assert "does not match" in refusal(auth.sign(key, "stage_cancel", "perch/segment", mission, "stop"))
            other = "0" * 32
            assert f"mission {other} is not running (mission {mission} is)" in refusal(
                auth.sign(key, "stage_cancel", MISSION_ACTION, other, "stop"), other)
            assert handle.status == GoalStatus.STATUS_EXECUTING
            assert not any("cancel taken" in m for m in said)

            taken = canceller.cancel(handle.goal_id, "the test", lambda: handle.status, wait=WAIT,
                                     step=lambda: client_side.spin_once(timeout_sec=0.05))
            assert taken and sent
            result = handle.get_result_async()
            spin_until(result.done, "the cancelled mission ended")
            assert result.result().status == GoalStatus.STATUS_CANCELED, result.result().result.message
            assert "cancelled" in result.result().result.message
            # /rosout lines travel apart from the action's result: wait for the line, then count it.
            spin_until(lambda: any(f"mission {mission}: cancel taken" in m for m in said),
                       "the coordinator said it took the cancel")
            assert sum(f"mission {mission}: cancel taken" in m for m in said) == 1

            before = len(said)
            publish(sent[0])   # the very message that was taken, again
            replay = spin_until(lambda: [m for m in said[before:] if m.startswith(REFUSED)], "the replay was refused")
            assert "used before" in replay[0]
            canceller.destroy()
            actions.destroy()
    finally:
        release.set()
        with replying:
            replying.wait_for(lambda: in_call[0] == 0, timeout=10)
        stage_side.shutdown()
        stage_thread.join(10)
        client_side.shutdown()
        for node in nodes:
            node.destroy_node()
        rclpy.try_shutdown(context=client_context)
        rclpy.try_shutdown(context=stage_context)
