"""Noticing that a mission's client is gone (killed, crashed, disconnected) so the mission can end.

Perch's own clients (`perch plan`, PerchCommander, the console) keep a writer on the goal's presence
topic while they wait (`perch_operator.api.presence`): once it has been seen, the client is gone when
no writer is left on that topic for `grace` seconds (Fast DDS drops a killed process after its lease,
3 s with config/fastdds.xml). A plain ROS action client has no such writer; for its goal the
coordinator remembers which feedback readers existed while the goal started and treats the client as
gone once all of them have left. Only readers of nodes that are the mission's action clients (a client
of its send_goal service, which every ROS 2 action client has) count; of those, Perch's observers
(console, commander, recorder: nodes with a writer on MISSION_OBSERVER_TOPIC) are left out. So a tool
that only reads the feedback (Foxglove's bridge, `ros2 topic echo`, a bag recorder) does not keep a
killed client's mission; another action client of the mission open then (not Perch's) is taken for
the client too, and such a goal may outlive its killed client until `confirm_timeout` or a cancel.
"""

from __future__ import annotations

import time

from perch_common.conventions import (
    MISSION_FEEDBACK_TOPIC,
    MISSION_OBSERVER_TOPIC,
    MISSION_SEND_GOAL_SERVICE,
    mission_client_topic,
)
from perch_common.ros.servers import UNNAMED_NODE, endpoint_node

ADOPT_SECONDS = 5.0   # readers discovered this soon after the goal started count as its client
CHECK_PERIOD = 0.5    # s between graph queries


class GoalWatch:
    """`gone()` turns True when the goal's presence writer (or, for a client without one, the feedback
    readers present at the goal's start, observers' left out) has left the graph for longer than `grace`."""

    def __init__(self, node, grace: float, goal_id=None, topic: str = MISSION_FEEDBACK_TOPIC):
        self.node = node
        self.grace = grace
        self.topic = node.resolve_topic_name(topic)
        self.presence_topic = node.resolve_topic_name(mission_client_topic(goal_id)) if goal_id is not None else ""
        self.observer_topic = node.resolve_topic_name(MISSION_OBSERVER_TOPIC)
        self.send_goal = node.resolve_topic_name(MISSION_SEND_GOAL_SERVICE)   # services resolve as topics
        self.present = False   # the goal's presence writer has been seen: it alone tells
        self.started = time.monotonic()
        self.readers: dict[bytes, str] = {}   # feedback readers present while the goal started -> their node
        self.action_clients: set[str] = set()   # nodes seen with a send_goal client (kept once seen: a
        # killed client's node leaves the graph with its reader)
        self._absent_since: float | None = None
        self._checked = 0.0
        self._gone = False
        self._look()

    def _current(self) -> dict[bytes, str]:
        return {bytes(info.endpoint_gid): endpoint_node(info)
                for info in self.node.get_subscriptions_info_by_topic(self.topic)}

    def _observers(self) -> set[str]:
        """The nodes that read missions' feedback as observers (Perch's tools), now."""
        return {endpoint_node(info) for info in self.node.get_publishers_info_by_topic(self.observer_topic)} - {UNNAMED_NODE}

    def _is_action_client(self, node_name: str) -> bool:
        """Whether the node `node_name` is (or was seen to be) a client of the mission's send_goal service;
        True for a node not yet named (nothing tells yet)."""
        if node_name == UNNAMED_NODE or node_name in self.action_clients:
            return True
        namespace, _, name = node_name.rpartition("/")
        try:
            services = self.node.get_client_names_and_types_by_node(name, namespace or "/")
        except RuntimeError:   # rclpy's NodeNameNonExistentError: gone, or its node names not yet discovered
            return False
        if any(service == self.send_goal for service, _ in services):
            self.action_clients.add(node_name)
            return True
        return False

    def _client_here(self, now: float) -> bool:
        """Whether the goal's client is in the graph now (True while nothing tells who it is)."""
        if self.presence_topic and self.node.get_publishers_info_by_topic(self.presence_topic):
            self.present = True
            return True
        if self.present:
            return False
        current = self._current()
        if now - self.started < ADOPT_SECONDS:
            self.readers.update(current)
        else:   # an adopted reader's node may be named only later (discovered before its node names)
            self.readers.update({gid: node for gid, node in current.items() if gid in self.readers})
        observers = self._observers()   # looked at every time: an observer's writer may be discovered late
        client = {gid for gid, node in self.readers.items() if node not in observers and self._is_action_client(node)}
        return not client or not client.isdisjoint(current)

    def _look(self) -> None:
        now = time.monotonic()
        if self._client_here(now):
            self._absent_since = None
        elif self._absent_since is None:
            self._absent_since = now
        elif now - self._absent_since > self.grace:
            self._gone = True

    def gone(self) -> bool:
        """True once the goal's client has been absent for longer than the grace period."""
        if self._gone or self.grace <= 0:
            return self._gone
        now = time.monotonic()
        if now - self._checked >= CHECK_PERIOD:
            self._checked = now
            self._look()
        return self._gone

    def describe(self) -> str:
        """Why the mission ends, for its result message and the log."""
        what = "its presence writer gone" if self.present else "no feedback reader"
        return (f"the mission's client left the graph ({what} for {self.grace:g} s; killed or "
                "disconnected); mission aborted so the graph is free for the next one")

