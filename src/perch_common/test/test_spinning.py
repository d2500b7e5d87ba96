"""keep_spinning: an entity destroyed while the executor builds its wait set does not stop the spinning.

The race is made deterministic: a subscription is destroyed just after the executor listed one of its
event handlers (waitables) for its wait set, the moment another thread's destroy hits it
in the wild (test_stage_calls' spin thread died of it under load, and every later call waited 300 s)."""

from __future__ import annotations

import threading
import time

import pytest

pytestmark = pytest.mark.ros

WAIT = 30.0


@pytest.fixture
def node():
    import rclpy

    from perch_common.ros.testing import use_isolated_ros_env

    use_isolated_ros_env()
    context = rclpy.Context()
    rclpy.init(context=context)
    node = rclpy.create_node("spinning_test", context=context)
    try:
        yield node
    finally:
        node.destroy_node()
        rclpy.shutdown(context=context)


class Race:
    """Destroys `doomed` (a subscription) once the executor has listed it or one of its event handlers
    (waitables) for its next wait set: the executor asks `can_execute` of each entity as it lists it."""

    def __init__(self, executor, node):
        self.node, self.doomed = node, None
        allowed = executor.can_execute

        def can_execute(entity) -> bool:
            doomed = self.doomed
            # its first event handler if it has any (listed last, after every subscription), else itself
            if doomed is not None and entity is (doomed.event_handlers or [doomed])[0]:
                self.doomed = None
                self.node.destroy_subscription(doomed)   # as another thread would, just then
            return allowed(entity)

        executor.can_execute = can_execute

    def arm(self, destroyable: bool = False) -> None:
        from std_msgs.msg import Empty

        from perch_common.ros.spinning import destroyable_subscription

        make = destroyable_subscription if destroyable else type(self.node).create_subscription
        doomed = make(self.node, Empty, "spinning_test_doomed", lambda _: None, 10)
        assert bool(doomed.event_handlers) != destroyable
        self.doomed = doomed


def test_rclpys_own_spin_dies_of_the_race(node):
    """The race is real in this rclpy (if this fails, rclpy fixed it and keep_spinning may go)."""
    from rclpy.exceptions import InvalidHandle
    from rclpy.executors import SingleThreadedExecutor

    executor = SingleThreadedExecutor(context=node.context)
    executor.add_node(node)
    Race(executor, node).arm()
    with pytest.raises(InvalidHandle):
        executor.spin_once(timeout_sec=0.1)
    executor.shutdown()


class Spinning:
    """`spin(executor)` in a thread for the block; `died` holds what ended it early. Leaving the block shuts
    the executor down, which must end the thread without an error."""

    def __init__(self, executor, spin):
        self.executor, self.died = executor, []

        def run() -> None:
            try:
                spin(executor)
            except BaseException as error:  # the outcome under test
                self.died.append(error)

        self.thread = threading.Thread(target=run, daemon=True)

    def __enter__(self) -> "Spinning":
        self.thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self.executor.shutdown()
        self.thread.join(10)
        assert not self.thread.is_alive() and not self.died, self.died

    def race(self, race: Race, times: int = 3, destroyable: bool = False) -> None:
        """The race, `times` over; each time the spinning lives on."""
        from perch_common.ros.testing import poll_until

        for _ in range(times):
            race.arm(destroyable)
            self.executor.wake()   # it lists the node's entities again
            poll_until(lambda: race.doomed is None or self.died, WAIT, "the executor listed the node again")
            assert not self.died, f"the spinning died: {self.died[0]!r}"


@pytest.mark.parametrize("threads", [1, 4])
def test_keep_spinning_survives_the_race_and_still_delivers(node, threads):
    from std_msgs.msg import Empty

    from perch_common.ros.node_main import make_executor
    from perch_common.ros.spinning import keep_spinning
    from perch_common.ros.testing import poll_until

    received = []
    node.create_subscription(Empty, "spinning_test_alive", received.append, 10)
    publisher = node.create_publisher(Empty, "spinning_test_alive", 10)
    executor = make_executor(threads, node.context)
    executor.add_node(node)
    race = Race(executor, node)
    with Spinning(executor, keep_spinning) as spinning:
        spinning.race(race)
        poll_until(lambda: publisher.get_subscription_count() >= 1, WAIT, "the live subscription matched")
        deadline = time.monotonic() + WAIT
        while not received:
            assert not spinning.died, f"the spinning died: {spinning.died[0]!r}"
            assert time.monotonic() < deadline, "the live subscription got nothing"
            publisher.publish(Empty())
            time.sleep(0.05)


def test_an_entity_destroyed_behind_its_nodes_back_is_still_raised(node):
    """A handle freed while its node still lists it fails every turn: raised, not spun on for ever."""
    from rclpy.exceptions import InvalidHandle
    from rclpy.executors import SingleThreadedExecutor
    from std_msgs.msg import Empty

    from perch_common.ros.spinning import keep_spinning

    doomed = node.create_subscription(Empty, "spinning_test_doomed", lambda _: None, 10)
    doomed.event_handlers[0].destroy()   # the node still lists it
    executor = SingleThreadedExecutor(context=node.context)
    executor.add_node(node)
    with pytest.raises(InvalidHandle):
        keep_spinning(executor)
    executor.shutdown()


@pytest.mark.parametrize("threads", [1, 4])
def test_a_callbacks_own_invalid_handle_is_still_raised(node, threads):
    """Only the wait set's race is spun through: a callback that used something destroyed fails its node,
    as with rclpy's own spin."""
    from rclpy.exceptions import InvalidHandle

    from perch_common.ros.node_main import make_executor
    from perch_common.ros.spinning import STALE_TURNS, keep_spinning

    calls = []

    def callback() -> None:
        calls.append(1)
        raise InvalidHandle("a callback's own")

    node.create_timer(0.01, callback)
    executor = make_executor(threads, node.context)
    executor.add_node(node)
    with pytest.raises(InvalidHandle, match="a callback's own"):
        keep_spinning(executor)
    executor.shutdown()
    # At its first failure (the next turn on 4 threads), not after STALE_TURNS failed turns in a row.
    assert len(calls) < STALE_TURNS // 2, len(calls)


@pytest.mark.parametrize("threads", [1, 4])
def test_destroyable_entities_survive_rclpys_own_spin(node, threads):
    """What Perch destroys on a user's node (PerchCommander's) has no event handlers: rclpy's own spin
    leaves a destroyed subscription out of its wait set, and a publisher is in none."""
    from std_msgs.msg import Empty

    from perch_common.ros.node_main import make_executor
    from perch_common.ros.spinning import destroyable_publisher

    executor = make_executor(threads, node.context)
    executor.add_node(node)
    race = Race(executor, node)
    with Spinning(executor, lambda e: e.spin()) as spinning:
        spinning.race(race, destroyable=True)
        for _ in range(3):
            publisher = destroyable_publisher(node, Empty, "spinning_test_writer", 1)
            assert not publisher.event_handlers
            node.destroy_publisher(publisher)
