"""Noticing that a mission's client is gone (killed, crashed, disconnected) so the mission can end.

An action client subscribes to the action's feedback topic; the coordinator remembers which
feedback readers existed while the goal started and treats the client as gone once all of them
have left the graph for `grace` seconds (Fast DDS drops a killed process after its lease, 3 s with
config/fastdds.xml).
"""

from __future__ import annotations

import time

from perch_common.conventions import MISSION_FEEDBACK_TOPIC

ADOPT_SECONDS = 5.0   # readers discovered this soon after the goal started count as its client
CHECK_PERIOD = 0.5    # s between graph queries


class GoalWatch:
    """`gone()` turns True when the feedback readers present at the goal's start have all vanished."""

    def __init__(self, node, grace: float, topic: str = MISSION_FEEDBACK_TOPIC):
        self.node = node
        self.grace = grace
        self.topic = node.resolve_topic_name(topic)
        self.started = time.monotonic()
        self.readers: set[bytes] = set()
        self._absent_since: float | None = None
        self._checked = 0.0
        self._gone = False
        self._look()

    def _current(self) -> set[bytes]:
        return {bytes(info.endpoint_gid) for info in self.node.get_subscriptions_info_by_topic(self.topic)}

    def _look(self) -> None:
        now = time.monotonic()
        current = self._current()
        if now - self.started < ADOPT_SECONDS:
            self.readers |= current
        if not self.readers or self.readers & current:
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
        return (f"the mission's client left the graph (no feedback reader for {self.grace:g} s; killed or "
                "disconnected); mission aborted so the graph is free for the next one")
