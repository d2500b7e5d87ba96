"""Exposure and authority (issue 22, item 6): the user's discovery settings are honoured or refused,
decisions bind to the current mission, and a dispatcher accepts a waypoint set only from the
coordinator that ran its mission (a spoofing node on the same domain is refused)."""

from __future__ import annotations

import functools
import time

import pytest

from perch_common.config import ConfigError
from perch_common.launch import dds_profile, use_perch_dds


def _spin(executors, condition, timeout: float, what: str):
    """Spin every executor until `condition()` is truthy (its value); AssertionError after `timeout` s."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        for executor in executors:
            executor.spin_once(timeout_sec=0.02)
        value = condition()
        if value:
            return value
    raise AssertionError(f"{what} within {timeout:.0f} s")


def test_host_only_settings_are_honoured_by_the_loopback_profile():
    for given in ({"ROS_LOCALHOST_ONLY": "1"}, {"ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}):
        env = use_perch_dds(dict(given), network=False)
        assert env["FASTRTPS_DEFAULT_PROFILES_FILE"] == str(dds_profile(False))
        # rmw_fastrtps's own host-only transports bind every interface; the profile's are loopback only
        assert env["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "SYSTEM_DEFAULT" and "ROS_LOCALHOST_ONLY" not in env
    # a user's own profile keeps the user's range
    mine = use_perch_dds({"FASTRTPS_DEFAULT_PROFILES_FILE": "/mine.xml", "ROS_AUTOMATIC_DISCOVERY_RANGE": "SUBNET"},
                         network=True)
    assert mine["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "SUBNET"


@pytest.mark.parametrize("env, network, words", [
    ({"ROS_AUTOMATIC_DISCOVERY_RANGE": "OFF"}, False, "turns discovery off"),
    ({"ROS_AUTOMATIC_DISCOVERY_RANGE": "SUBNET"}, False, "pass that, or unset it"),
    ({"ROS_LOCALHOST_ONLY": "1"}, True, "ROS_LOCALHOST_ONLY=1 keeps ROS on this host"),
    ({"ROS_AUTOMATIC_DISCOVERY_RANGE": "localhost"}, True, "unset one of them"),
])
def test_settings_perch_cannot_honour_are_refused_not_replaced(env, network, words):
    given = dict(env)
    with pytest.raises(ConfigError, match=words):
        use_perch_dds(given, network=network)
    assert given == env   # nothing replaced


@pytest.mark.ros
def test_every_client_process_uses_the_host_only_profile(monkeypatch):
    import os

    from perch_common.launch import use_perch_dds as apply

    monkeypatch.delenv("FASTRTPS_DEFAULT_PROFILES_FILE", raising=False)
    monkeypatch.delenv("PERCH_NETWORK", raising=False)
    monkeypatch.setenv("ROS_LOCALHOST_ONLY", "1")
    from perch_operator.cli.runner import client_context

    assert apply is use_perch_dds
    with client_context():
        assert os.environ["FASTRTPS_DEFAULT_PROFILES_FILE"] == str(dds_profile(False))
        assert os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "SYSTEM_DEFAULT"


@pytest.mark.ros
def test_confirms_bind_to_the_current_mission_and_a_spoofed_waypoint_set_is_refused():
    """The real coordinator (its stages absent, so its mission fails after service_wait) in one
    participant, a dispatcher in a second and a spoofing node in a third, all on one domain."""
    from perch_common.ros import testing

    testing.use_isolated_ros_env()
    import rclpy
    from rclpy.action import ActionClient
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.parameter import Parameter

    from perch_interfaces.action import PlanPerches
    from perch_interfaces.msg import PerchWaypoint, PerchWaypointSet
    from perch_interfaces.srv import Confirm
    from perch_operator.cli.dispatcher import Dispatcher
    from perch_operator.coordinator.node import LATCHED_LAST, OperatorNode
    from perch_operator.outputs.mission_data import mission_id_text

    rclpy.init()   # the coordinator's (OperatorNode takes the default context)
    contexts = [rclpy.get_default_context(), Context(), Context()]
    for context in contexts[1:]:
        rclpy.init(context=context)
    executors = [SingleThreadedExecutor(context=c) for c in contexts]
    nodes = []
    try:
        coordinator = OperatorNode()
        coordinator.set_parameters([Parameter("service_wait", value=0.5)])
        dispatcher = Dispatcher(name="honest_dispatcher", context=contexts[1])
        spoofer = rclpy.create_node("spoofer", context=contexts[2])
        nodes = [coordinator, dispatcher, spoofer]
        for executor, node in zip(executors, nodes):
            executor.add_node(node)

        spin = functools.partial(_spin, executors)

        client = rclpy.create_node("decider", context=contexts[2])
        executors[2].add_node(client)
        confirm = client.create_client(Confirm, "perch/confirm")
        spin(lambda: confirm.service_is_ready(), 120, "the confirm service did not appear")

        def decide(proposal_id: int, decision: int) -> Confirm.Response:
            future = confirm.call_async(Confirm.Request(proposal_id=proposal_id, decision=decision))
            spin(future.done, 120, "no confirm reply")
            return future.result()

        unknown = decide(1, Confirm.Request.ACCEPT)
        assert not unknown.success and "unknown" in unknown.message, unknown.message

        # A mission: the coordinator publishes its (empty) waypoint set, then fails (no stages).
        actions = ActionClient(client, PlanPerches, "perch/plan_perches")
        spin(actions.server_is_ready, 120, "the coordinator's action did not appear")
        goal = PlanPerches.Goal(mesh_path="/nonexistent/room.ply")
        sent = actions.send_goal_async(goal)
        spin(sent.done, 120, "the goal was not answered")
        handle = sent.result()
        result = handle.get_result_async()
        spin(result.done, 300, "the mission did not end")
        mission = mission_id_text(handle.goal_id)
        spin(lambda: dispatcher.mission == mission, 120, "the dispatcher did not accept the coordinator's set")
        assert dispatcher.received == [] and not dispatcher.refused
        # the mission failed: a decision on it is refused
        late = decide(1, Confirm.Request.FAILED_IN_FLIGHT)
        assert not late.success and mission in late.message, late.message

        # A spoofing node publishes a set with a far-away perch for that very mission.
        fake = PerchWaypoint(mission_id=handle.goal_id, drone_index=0, proposal_id=1)
        fake.pose.pose.position.x, fake.pose.pose.position.y = 99.0, -99.0
        publisher = spoofer.create_publisher(PerchWaypointSet, "perch/mission_waypoints", LATCHED_LAST)
        publisher.publish(PerchWaypointSet(mission_id=handle.goal_id, waypoints=[fake]))
        spin(lambda: dispatcher.refused, 120, "the spoofed set was neither accepted nor refused")
        assert "/spoofer" in dispatcher.refused[0] and "not the mission coordinator" in dispatcher.refused[0]
        assert dispatcher.received == [] and dispatcher.mission == mission   # the coordinator's set stays
        actions.destroy()
    finally:
        for executor, node in zip(executors, nodes):
            executor.remove_node(node)
            node.destroy_node()
        rclpy.try_shutdown()   # the default context (reset for the next rclpy.init)
        for context in contexts[1:]:
            rclpy.try_shutdown(context=context)



def test_the_network_key_is_made_private_and_tokens_bind_every_field(tmp_path):
    import os
    import stat

    from perch_common.network_auth import AuthError, check, load_key, sign

    path = tmp_path / "perch" / "network.key"
    key = load_key(path)
    assert len(key) == 32 and stat.S_IMODE(path.stat().st_mode) == 0o600
    assert stat.S_IMODE(path.parent.stat().st_mode) == 0o700
    assert load_key(path) == key   # made once
    token = sign(key, "confirm", 7, 2, "slipped", now=1000.0)
    assert check(key, token, "confirm", 7, 2, "slipped", now=1010.0) == ""
    assert "does not match" in check(key, token, "confirm", 8, 2, "slipped", now=1010.0)
    assert "does not match" in check(key, token, "stage_cancel", 7, 2, "slipped", now=1010.0)
    assert "does not match" in check(os.urandom(32), token, "confirm", 7, 2, "slipped", now=1010.0)
    assert "older than" in check(key, token, "confirm", 7, 2, "slipped", now=1000.0 + 500)
    assert "no authentication token" in check(key, "", "confirm", 7, 2, "slipped")
    path.chmod(0o644)
    with pytest.raises(AuthError, match="chmod 600"):
        load_key(path)


@pytest.mark.ros
def test_a_networked_graph_refuses_unsigned_and_forged_commands(tmp_path, monkeypatch):
    """--network: a decision without a token or signed with another key is refused, the signed one is
    taken; the coordinator's waypoint sets carry its token and a dispatcher refuses a forged set even
    from the coordinator's own identity checks' point of view (no token)."""
    import os

    from perch_common.ros import testing

    testing.use_isolated_ros_env()
    monkeypatch.setenv("PERCH_NETWORK", "1")   # commands signed and checked (transports stay loopback here)
    monkeypatch.setenv("PERCH_KEY_FILE", str(tmp_path / "network.key"))
    import perch_common.network_auth as auth

    monkeypatch.setattr(auth, "_process_key", None)
    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor

    from perch_interfaces.msg import PerchWaypointSet
    from perch_interfaces.srv import Confirm
    from perch_operator.cli.dispatcher import Dispatcher
    from perch_operator.coordinator.node import OperatorNode

    rclpy.init()
    other = Context()
    rclpy.init(context=other)
    executors = [SingleThreadedExecutor(), SingleThreadedExecutor(context=other)]
    nodes = []
    try:
        coordinator = OperatorNode()
        dispatcher = Dispatcher(name="networked_dispatcher", context=other)
        caller = rclpy.create_node("remote_operator", context=other)
        nodes = [coordinator, dispatcher, caller]
        executors[0].add_node(coordinator)
        executors[1].add_node(dispatcher)
        executors[1].add_node(caller)

        spin = functools.partial(_spin, executors)

        confirm = caller.create_client(Confirm, "perch/confirm")
        spin(confirm.service_is_ready, 120, "the confirm service did not appear")

        def decide(auth_token: str) -> Confirm.Response:
            future = confirm.call_async(Confirm.Request(proposal_id=1, decision=0, auth=auth_token))
            spin(future.done, 120, "no confirm reply")
            return future.result()

        assert "carries no authentication token" in decide("").message
        forged = auth.sign(os.urandom(32), "confirm", 1, 0, "")
        assert "does not match" in decide(forged).message
        # signed with the graph's key: authenticated, then judged on the mission (none has run)
        signed = decide(auth.sign(auth.process_key(), "confirm", 1, 0, ""))
        assert not signed.success and "unknown" in signed.message, signed.message

        # the coordinator's own sets are signed; an unsigned set is refused whoever writes it
        set_msg = PerchWaypointSet()
        coordinator._signed(set_msg)
        assert auth.check(auth.process_key(), set_msg.auth, "waypoints", *auth.waypoint_set_fields(set_msg)) == ""
        decided, why = dispatcher.attribution(PerchWaypointSet())
        assert decided and "no authentication token" in why
    finally:
        for executor, node in zip([executors[0], executors[1], executors[1]], nodes):
            executor.remove_node(node)
            node.destroy_node()
        rclpy.try_shutdown()
        rclpy.try_shutdown(context=other)
