"""A mission client's presence in the graph: what the coordinator watches to notice that it is gone."""

from __future__ import annotations

from unique_identifier_msgs.msg import UUID

from perch_common.conventions import mission_client_topic


class ClientPresence:
    """A writer on the goal's own presence topic (`conventions.mission_client_topic`), made before the
    goal is sent and withdrawn once the goal has ended. Nothing is published on it: the coordinator
    takes this writer as the goal's client, so a console, a commander or a recorder that also reads the
    mission's feedback cannot keep a killed client's mission alive. When the client's process dies its
    writer leaves the graph with it (the DDS lease), and the mission is aborted after `client_grace`."""

    def __init__(self, node, goal_id) -> None:
        self.node = node
        self._writer = node.create_publisher(UUID, mission_client_topic(goal_id), 1)

    def withdraw(self) -> None:
        """Leave the graph (the goal has ended, or will not be sent); a second call does nothing."""
        writer, self._writer = self._writer, None
        if writer is not None:
            self.node.destroy_publisher(writer)
