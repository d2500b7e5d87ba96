"""A mission client's presence in the graph: what the coordinator watches to notice that it is gone."""

from __future__ import annotations

import threading

from unique_identifier_msgs.msg import UUID

from perch_common.conventions import mission_client_topic


class ClientPresence:
    """One client's presence for its running goal: a writer on the goal's own presence topic
    (`conventions.mission_client_topic`), made before the goal is sent and withdrawn once the goal has
    ended. Nothing is published on it: the coordinator takes this writer as the goal's client, so a
    console, a commander or a recorder that also reads the mission's feedback cannot keep a killed
    client's mission alive. When the client's process dies its writer leaves the graph with it (the
    DDS lease), and the mission is aborted after `client_grace`. Safe from any thread."""

    def __init__(self, node) -> None:
        self.node = node
        self._lock = threading.Lock()
        self._writer = None

    def announce(self, goal_id) -> None:
        """Be goal `goal_id`'s client (16 bytes, or a UUID message's list); an earlier goal's writer goes."""
        writer = self.node.create_publisher(UUID, mission_client_topic(goal_id), 1)
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
