"""Noticing that a mission's client is gone (killed, crashed, disconnected) so the mission can end.

The client is followed as a DDS participant, not as one endpoint: an action client is a
participant (the GUID prefix, the first 12 bytes of every endpoint GID it owns) with a writer of
the action's get_result requests and a reader of its feedback. The coordinator adopts the action
clients listed when the goal starts and, across hosts where discovery lags, those listed in the
ADOPT_SECONDS after the first one appears (never none: it keeps looking until one is listed). A
plain reader of the feedback topic (a recorder, `ros2 topic echo`) is not an action client and
does not keep a mission alive. The client is gone once none of its participants has any of those
endpoints listed for `grace` seconds: Fast DDS removes a participant's endpoints when its lease
runs out (3 s with config/fastdds.xml and fastdds_network.xml; measured across two network
namespaces: listed until 3.4 s after a SIGKILL, then never again).

What it cannot tell: which of several action clients of one action sent the goal (rclpy does not
expose a request's writer GUID), so a second live client (a console, a PerchCommander) keeps every
mission alive while it lives.
"""

from __future__ import annotations

import time
from typing import Callable

from perch_common.conventions import MISSION_ACTION

ADOPT_SECONDS = 5.0   # clients listed this soon after the first one count as the goal's client
NEVER_LISTED = 30.0   # s with no action client listed at all after the goal started: the client is gone
CHECK_PERIOD = 0.5    # s between graph queries
PREFIX_BYTES = 12     # a DDS GUID's participant prefix


def _participant(gid) -> bytes:
    return bytes(gid)[:PREFIX_BYTES]


class GoalWatch:
    """`gone()` turns True when the action clients present as the goal started have all left the graph."""

    def __init__(self, node, grace: float, action: str = MISSION_ACTION,
                 clock: Callable[[], float] = time.monotonic):
        self.node = node
        self.grace = grace
        self.clock = clock
        base = node.resolve_topic_name(action)
        self.feedback_topic = f"{base}/_action/feedback"
        self.result_topic = f"rq{base}/_action/get_resultRequest"   # DDS name: the result requests' writers
        self.started = clock()
        self.clients: set[bytes] = set()       # participant prefixes of the adopted action clients
        self._first_seen: float | None = None
        self._absent_since: float | None = None
        self._checked = self.started
        self._gone = False
        self._look()

    def action_clients(self) -> set[bytes]:
        """Participants in the graph now with a get_result request writer and a feedback reader of the action."""
        results = {_participant(i.endpoint_gid)
                   for i in self.node.get_publishers_info_by_topic(self.result_topic, no_mangle=True)}
        feedback = {_participant(i.endpoint_gid) for i in self.node.get_subscriptions_info_by_topic(self.feedback_topic)}
        return results & feedback

    def _look(self) -> None:
        now = self.clock()
        current = self.action_clients()
        if current and self._first_seen is None:
            self._first_seen = now
        if self._first_seen is not None and now - self._first_seen <= ADOPT_SECONDS:
            self.clients |= current
        if self.clients & current:
            self._absent_since = None
            return
        if not self.clients and now - self.started <= NEVER_LISTED:
            return   # not listed yet (discovery across hosts lags): keep looking
        if self._absent_since is None:
            self._absent_since = now
        elif now - self._absent_since > self.grace:
            self._gone = True

    def gone(self) -> bool:
        """True once the goal's client has been absent for longer than the grace period."""
        if self._gone or self.grace <= 0:
            return self._gone
        now = self.clock()
        if now - self._checked >= CHECK_PERIOD:
            self._checked = now
            self._look()
        return self._gone

    def describe(self) -> str:
        """Why the mission ends, for its result message and the log."""
        if not self.clients:
            return (f"the mission's client never appeared in the graph ({NEVER_LISTED:g} s without an action client "
                    "of the mission listed); mission aborted so the graph is free for the next one")
        return (f"the mission's client left the graph (its participant gone for {self.grace:g} s; killed or "
                "disconnected); mission aborted so the graph is free for the next one")
