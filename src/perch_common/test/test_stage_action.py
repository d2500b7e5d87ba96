"""create_stage_action: a stage's long-running form. A goal runs the service's callback with feedback
(fraction, phase) and the service's reply as its result; the standard cancel stops it at its next
checkpoint; a networked graph refuses that cancel (it carries no token); each goal publishes the
service's introspection events (request received, response sent), as a service call would."""

from __future__ import annotations

import threading
import time

import pytest

from perch_common.cancellation import checkpoint
from perch_common.ros.testing import poll_until
from perch_common.work import report

pytestmark = pytest.mark.ros

WAIT = 60.0   # s, generous deadline for anything that crosses the executor


@pytest.fixture
def result_timeout() -> float:
    """The action server's action_server_result_timeout (a test parametrises it to change it)."""
    return 60.0


@pytest.fixture
def graph(result_timeout):
    """A node serving perch/segment (service and action, introspection on) with a callback that works until
    cancelled or released, and a client node that also reads the service's events; both spun by one
    multi-threaded executor. Yields (action client, release event, events received); the server node
    is `client.server` (its action server `client.server.action`)."""
    import rclpy
    from rclpy.action import ActionClient
    from rclpy.executors import MultiThreadedExecutor
    from rclpy.node import Node
    from rclpy.qos import qos_profile_services_default

    from perch_common.ros.service import answering, create_stage_action, create_stage_service
    from perch_common.ros.spinning import keep_spinning
    from perch_common.ros.testing import use_isolated_ros_env
    from perch_interfaces import action, srv

    use_isolated_ros_env()
    context = rclpy.Context()
    rclpy.init(context=context)
    release = threading.Event()

    class Server(Node):
        def __init__(self):
            super().__init__("stage_action_test_server", context=context)
            create_stage_service(self, srv.Segment, "perch/segment", self._segment, introspection=True)
            self.action = create_stage_action(self, action.Segment, srv.Segment, "perch/segment", self._segment,
                                              result_timeout=result_timeout)

        @answering
        def _segment(self, request, response):
            report(0.25, "waiting for the test")
            deadline = time.monotonic() + WAIT
            while not release.is_set() and time.monotonic() < deadline:
                checkpoint("the next wait")
                report(0.5, "waiting for the test")
                time.sleep(0.01)
            response.success, response.message = True, f"released {request.request_id}"
            return response

    server = Server()
    client_node = rclpy.create_node("stage_action_test_client", context=context)
    client = ActionClient(client_node, action.Segment, "perch/segment")
    client.server = server
    events = []
    subscription = client_node.create_subscription(srv.Segment.Event, "perch/segment/_service_event", events.append,
                                                   qos_profile_services_default)
    executor = MultiThreadedExecutor(num_threads=4, context=context)
    executor.add_node(server)
    executor.add_node(client_node)
    spinner = threading.Thread(target=keep_spinning, args=(executor,), daemon=True)
    spinner.start()
    try:
        assert client.wait_for_server(timeout_sec=WAIT)
        # Matched with the service's event writer and the action's (volatile: none may be missed).
        poll_until(lambda: subscription.get_publisher_count() >= 2, WAIT, "both event writers")
        yield client, release, events
    finally:
        release.set()
        executor.shutdown()
        server.destroy_node()
        client_node.destroy_node()
        rclpy.shutdown(context=context)
        spinner.join(10)


def _wait(future):
    deadline = time.monotonic() + WAIT
    while not future.done():
        assert time.monotonic() < deadline, "no answer within the deadline"
        time.sleep(0.01)
    return future.result()


def _start(client, feedback: list):
    from perch_interfaces.action import Segment

    handle = _wait(client.send_goal_async(Segment.Goal(request_id="goal/1"),
                                          feedback_callback=lambda m: feedback.append(m.feedback)))
    assert handle.accepted
    deadline = time.monotonic() + WAIT
    while not feedback:   # the goal runs (and the feedback subscription is matched)
        assert time.monotonic() < deadline, "no feedback"
        time.sleep(0.01)
    return handle


def test_a_goal_gives_feedback_and_the_services_reply_as_its_result(graph):
    from action_msgs.msg import GoalStatus

    client, release, _ = graph
    feedback = []
    handle = _start(client, feedback)
    release.set()
    answer = _wait(handle.get_result_async())
    assert answer.status == GoalStatus.STATUS_SUCCEEDED
    assert answer.result.success and answer.result.message == "released goal/1"
    assert feedback[0].phase == "waiting for the test" and 0.25 <= feedback[0].fraction <= 0.5


@pytest.mark.parametrize("result_timeout", [1.0])
def test_a_finished_goal_is_let_go_after_the_result_time(graph):
    from action_msgs.msg import GoalStatus

    client, release, _ = graph
    handle = _start(client, [])
    result = handle.get_result_async()   # asked before the goal ends: a slow ask could come after the expiry
    release.set()
    assert _wait(result).status == GoalStatus.STATUS_SUCCEEDED
    # Its request and result are freed: a late get_result finds no such goal (rclpy keeps them 900 s).
    poll_until(lambda: _wait(handle.get_result_async()).status == GoalStatus.STATUS_UNKNOWN, WAIT,
               "the finished goal let go")


def test_a_finished_goal_keeps_its_result_but_not_its_request(graph):
    """rclpy keeps a finished goal's handle, with its request, until the result expires (60 s here):
    each mission's meshes would stay in every stage that long. The request is dropped once it has run."""
    from action_msgs.msg import GoalStatus

    from perch_interfaces.action import Segment

    client, release, _ = graph
    goal = Segment.Goal(request_id="goal/1")
    goal.mesh.vertices = [0.0, 1.0, 2.0] * 1000
    handle = _wait(client.send_goal_async(goal))
    release.set()
    answer = _wait(handle.get_result_async())
    assert answer.status == GoalStatus.STATUS_SUCCEEDED and answer.result.message == "released goal/1"
    kept = client.server.action._goal_handles[bytes(handle.goal_id.uuid)]
    assert kept.request.request_id == "" and len(kept.request.mesh.vertices) == 0
    late = _wait(handle.get_result_async())   # the result itself stays for a late get_result
    assert late.status == GoalStatus.STATUS_SUCCEEDED and late.result.message == "released goal/1"


def test_the_standard_cancel_stops_the_goal_at_its_next_checkpoint(graph):
    from action_msgs.msg import GoalStatus

    client, _, _ = graph
    handle = _start(client, [])
    cancel = _wait(handle.cancel_goal_async())
    assert len(cancel.goals_canceling) == 1
    answer = _wait(handle.get_result_async())
    assert answer.status == GoalStatus.STATUS_CANCELED
    assert not answer.result.success
    assert answer.result.message.startswith("perch/segment: cancelled by its caller (action cancel)")


def test_a_networked_graph_refuses_the_standard_cancel(graph, monkeypatch):
    from action_msgs.msg import GoalStatus

    client, release, _ = graph
    monkeypatch.setenv("PERCH_NETWORK", "1")
    handle = _start(client, [])
    cancel = _wait(handle.cancel_goal_async())
    assert len(cancel.goals_canceling) == 0   # refused: the goal goes on
    release.set()
    answer = _wait(handle.get_result_async())
    assert answer.status == GoalStatus.STATUS_SUCCEEDED and answer.result.success


def test_each_goal_publishes_the_services_introspection_events(graph):
    """REQUEST_RECEIVED with the request as sent, RESPONSE_SENT with the service's reply, both keyed by
    the goal id (client_gid) and the goal request's sequence number, which counts up per client as a
    service client's does; so a recorder pairs them as it pairs a service call's."""
    from action_msgs.msg import GoalStatus

    from perch_interfaces.action import Segment

    client, release, events = graph
    release.set()
    answers, goal_ids = [], []
    for n in (1, 2):
        handle = _wait(client.send_goal_async(Segment.Goal(request_id=f"goal/{n}")))
        goal_ids.append(bytes(handle.goal_id.uuid))
        answers.append(_wait(handle.get_result_async()))
    assert [a.status for a in answers] == [GoalStatus.STATUS_SUCCEEDED] * 2
    poll_until(lambda: len(events) >= 4, WAIT, "four events")
    by_goal = {goal: [e for e in events if bytes(e.info.client_gid) == goal] for goal in goal_ids}
    sequences = []
    for n, goal in enumerate(goal_ids, start=1):
        received, sent = by_goal[goal]
        assert (received.info.event_type, sent.info.event_type) == (1, 2)
        assert received.info.sequence_number == sent.info.sequence_number
        sequences.append(received.info.sequence_number)
        assert len(received.request) == 1 and not received.response
        assert received.request[0].request_id == f"goal/{n}"
        assert len(sent.response) == 1 and not sent.request
        assert sent.response[0].success and sent.response[0].message == f"released goal/{n}"
        stamp = lambda e: e.info.stamp.sec * 10**9 + e.info.stamp.nanosec   # noqa: E731
        assert stamp(received) <= stamp(sent)
    assert sequences[1] == sequences[0] + 1   # one client, its second goal request


@pytest.mark.parametrize("name", ["Reconstruct", "Segment", "Filter", "Optimise"])
def test_each_stage_action_has_its_services_fields(name):
    """The .action files repeat their service's fields (rosidl cannot include one in the other)."""
    import importlib

    stage_action = getattr(importlib.import_module("perch_interfaces.action"), name)
    service = getattr(importlib.import_module("perch_interfaces.srv"), name)
    assert stage_action.Goal.get_fields_and_field_types() == service.Request.get_fields_and_field_types()
    assert stage_action.Result.get_fields_and_field_types() == service.Response.get_fields_and_field_types()
    assert stage_action.Feedback.get_fields_and_field_types() == {"fraction": "float", "phase": "string"}
