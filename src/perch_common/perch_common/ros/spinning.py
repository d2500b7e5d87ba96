"""Spinning an executor through rclpy's destroy race.

rclpy 7.1's executor lists a node's waitables (a subscription's or publisher's event handlers among
them), then adds each to the wait set. An entity destroyed by another thread in between (a test
dropping its subscription, the recorder leaving a topic, a callback on another thread of a
MultiThreadedExecutor) makes that add raise InvalidHandle out of `spin()`: the spin thread dies and
the node stops taking anything in, while the process lives on (a stage call then waits for its whole
timeout). rclpy catches the same race for subscriptions, clients, services and timers, not for
waitables. The next wait set is built from the node's current lists, without the destroyed entity,
so spinning on is safe.

Perch's own executors spin with `keep_spinning`. A user's node (PerchCommander's, say) spins with
whatever its owner chose, so what Perch creates and destroys on such a node while it spins has no
event handlers (`destroyable_publisher`, `destroyable_subscription`): rclpy's own checks then cover it.
"""

from __future__ import annotations

from rclpy.event_handler import PublisherEventCallbacks, SubscriptionEventCallbacks
from rclpy.exceptions import InvalidHandle

# Consecutive failed turns before the error is raised after all: an entity destroyed but still listed
# by its node (destroyed behind the node's back) would otherwise fail every turn, a busy loop.
STALE_TURNS = 100


def keep_spinning(executor) -> None:
    """`executor.spin()` (until its context ends or it is shut down) that survives an entity destroyed while
    the executor built its wait set; any other error (a callback's) ends it as it ends `spin()`."""
    failed_turns = 0
    while executor.context.ok() and not executor._is_shutdown:
        try:
            executor.spin_once()
        except InvalidHandle as error:
            failed_turns += 1
            # A callback's own InvalidHandle (it used something destroyed) is its node's error, as before.
            if failed_turns >= STALE_TURNS or not _building_the_wait_set(error):
                raise
            continue
        failed_turns = 0


def _building_the_wait_set(error: BaseException) -> bool:
    """The error came from the executor building its wait set (rclpy's generator of ready callbacks)."""
    frame = error.__traceback__
    while frame is not None:
        if frame.tb_frame.f_code.co_name == "_wait_for_ready_callbacks":
            return True
        frame = frame.tb_next
    return False


def destroyable_publisher(node, msg_type, topic: str, qos, **kwargs):
    """A publisher that any thread may destroy while any executor spins `node`: it has no event handlers
    (waitables), so no wait set lists it (rclpy's default ones only log an incompatible QoS)."""
    return node.create_publisher(msg_type, topic, qos,
                                 event_callbacks=PublisherEventCallbacks(use_default_callbacks=False), **kwargs)


def destroyable_subscription(node, msg_type, topic: str, callback, qos, **kwargs):
    """A subscription that any thread may destroy while any executor spins `node`: without event handlers
    only its own handle is in a wait set, and rclpy leaves out a destroyed one."""
    return node.create_subscription(msg_type, topic, callback, qos,
                                    event_callbacks=SubscriptionEventCallbacks(use_default_callbacks=False), **kwargs)
