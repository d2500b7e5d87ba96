"""A mission client's presence in the graph: what the coordinator watches to notice that it is gone."""

from __future__ import annotations

import threading

from unique_identifier_msgs.msg import UUID

from perch_common.conventions import MISSION_OBSERVER_TOPIC, mission_client_topic
from perch_common.ros.spinning import destroyable_publisher


def observer_writer(node):
    """A writer on MISSION_OBSERVER_TOPIC: `node` is a Perch tool that reads every mission's feedback
    without being every mission's client (a console, a commander, a recorder). For a plain ROS client's
    goal, whose client has no presence writer, the coordinator then leaves this node's feedback readers
    out when it watches for the client. Nothing is published on it; destroy it with the reader (from any
    thread: a user's node may spin with rclpy's own executor)."""
    return destroyable_publisher(node, UUID, MISSION_OBSERVER_TOPIC, 1)


class ClientPresence:
    """One client's presence for its running goal: a writer on the goal's own presence topic
    (`conventions.mission_client_topic`), made before the goal is sent and withdrawn once the goal has
    ended. Nothing is published on it: the coordinator takes this writer as the goal's client, so a
    console, a commander or a recorder that also reads the mission's feedback cannot keep a killed
    client's mission alive. When the client's process dies its writer leaves the graph with it (the
    DDS lease), and the mission is aborted after `client_grace`. Between its own goals the node reads
    other clients' feedback as an observer (`observer_writer`, kept until `close`). Safe from any thread."""

    def __init__(self, node) -> None:
        self.node = node
        self._lock = threading.Lock()
        self._writer = None
        self._observer = observer_writer(node)

    def announce(self, goal_id) -> None:
        """Be goal `goal_id`'s client (16 bytes, or a UUID message's list); an earlier goal's writer goes."""
        writer = destroyable_publisher(self.node, UUID, mission_client_topic(goal_id), 1)
        with self._lock:
            earlier, self._writer = self._writer, writer
        if earlier is not None:
            self.node.destroy_publisher(earlier)

    def withdraw(self) -> None:
        """Leave the graph (the goal has ended, or will not be sent); nothing when not announced."""
        with self._lock:
            writer, self._writer = self._writer, None
        if writer is not None:
            self.node.destroy_publisher(writer)

    def close(self) -> None:
        """Withdraw, and stop being an observer (the node no longer reads missions' feedback)."""
        self.withdraw()
        with self._lock:
            observer, self._observer = self._observer, None
        if observer is not None:
            self.node.destroy_publisher(observer)
