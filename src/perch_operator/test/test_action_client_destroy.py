"""RegisteringActionClient.destroy, and a PerchCommander's, while an executor spins the node in another thread.

rclpy Jazzy's ActionClient.destroy frees its handle before taking the client off the node: an
executor that listed the node's clients in between adds the freed handle to its wait set and its spin
thread dies (RCLError "action client pointer is invalid"). The coordinator destroys a stage's client
when it renews it; a CI rehearsal's test_stage_calls lost its executor this way and its next two calls
waited out their 300 s.
"""

from __future__ import annotations

import threading
import time

import pytest

pytestmark = pytest.mark.ros

CHURN_SECONDS = 10.0   # rclpy's own destroy killed the spin thread here within 0.4-2 s (or aborted the process)


@pytest.fixture
def spun_node():
    """A node spun by a MultiThreadedExecutor in a thread; yields (node, errors of the spin thread)."""
    import rclpy
    from rclpy.executors import MultiThreadedExecutor

    from perch_common.ros.testing import use_isolated_ros_env

    use_isolated_ros_env()
    context = rclpy.Context()
    rclpy.init(context=context)
    node = rclpy.create_node("action_client_destroy_test", context=context)
    executor = MultiThreadedExecutor(num_threads=2, context=context)
    executor.add_node(node)
    errors: list = []

    def spin() -> None:
        try:
            executor.spin()
        except Exception as exc:  # the failure under test
            errors.append(exc)

    thread = threading.Thread(target=spin, daemon=True)
    thread.start()
    try:
        yield node, errors, thread
    finally:
        executor.shutdown()
        thread.join(5)
        node.destroy_node()
        rclpy.try_shutdown(context=context)


def _handle_freed(client) -> bool:
    try:
        client._client_handle.__enter__()
    except Exception:   # InvalidHandle: destroyed
        return True
    client._client_handle.__exit__(None, None, None)
    return False


def test_a_client_destroyed_after_its_executor_shut_down_leaves_the_graph_at_once(spun_node):
    """The console shuts its executor down, then destroys its mission client: the client was left with
    a timer no executor would run, its feedback reader stayed in the graph (a coordinator took it for a
    killed mission's client and never freed the graph), and the send_goal client too."""
    from perch_interfaces.action import Segment
    from perch_operator.coordinator.action_client import RegisteringActionClient

    node, errors, thread = spun_node
    client = RegisteringActionClient(node, Segment, "perch/segment")
    feedback = node.resolve_topic_name("perch/segment/_action/feedback")
    assert len(node.get_subscriptions_info_by_topic(feedback)) == 1
    node.executor.shutdown()
    thread.join(5)
    client.destroy()
    assert _handle_freed(client) and not list(node.timers)
    assert node.get_subscriptions_info_by_topic(feedback) == []


def test_destroying_clients_while_the_node_spins_leaves_the_executor_running(spun_node):
    from perch_interfaces.action import Segment
    from perch_operator.coordinator.action_client import RegisteringActionClient

    node, errors, thread = spun_node
    made, last = 0, None
    deadline = time.monotonic() + CHURN_SECONDS
    while time.monotonic() < deadline and thread.is_alive():
        last = RegisteringActionClient(node, Segment, "perch/segment")
        time.sleep(0)   # let the spin thread run between the two
        last.destroy()
        made += 1
    assert thread.is_alive() and not errors, f"the spin thread died after {made} clients: {errors[:1]}"
    # Every client left the node, and the last one's handle is freed once the executor has passed.
    assert not any(isinstance(w, RegisteringActionClient) for w in node.waitables)
    # The one-shot timers that freed the handles go too; the executor runs them in no set order (one seen
    # run the last client's before earlier ones'), so this waits for all of them.
    deadline = time.monotonic() + 10
    while not _handle_freed(last) or list(node.timers):
        assert time.monotonic() < deadline, (f"the last client's handle freed: {_handle_freed(last)}; "
                                             f"{len(list(node.timers))} freeing timers left")
        time.sleep(0.05)


def test_a_commander_made_and_destroyed_while_its_users_executor_spins_leaves_it_running(spun_node):
    """PerchCommander lives on a user's node, spun by rclpy's own executor (no keep_spinning there): what
    it destroys from the user's thread (its presence writers, proposal reader, cancel writer) has no
    event handlers, which rclpy 7.1 lists in a wait set without checking that they still exist."""
    import uuid

    from perch_operator.api.client import MissionCanceller
    from perch_operator.api.commander import PerchCommander

    node, errors, thread = spun_node
    made = 0
    deadline = time.monotonic() + CHURN_SECONDS / 2
    while time.monotonic() < deadline and thread.is_alive():
        commander = PerchCommander(node)
        commander._presence.announce(uuid.uuid4().bytes)
        canceller = MissionCanceller(node)
        destroyed = [commander._proposal_sub, commander._presence._writer, commander._presence._observer,
                     canceller.publisher]
        assert not any(entity.event_handlers for entity in destroyed)
        time.sleep(0)
        canceller.destroy()
        commander.destroy()
        made += 1
    assert thread.is_alive() and not errors, f"the spin thread died after {made} commanders: {errors[:1]}"
