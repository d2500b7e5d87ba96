"""A mission goal whose request was lost on its way to a young coordinator is sent again under its own
id; the coordinator's refusal of such a resend (it holds the goal) is not taken for the answer."""

from __future__ import annotations

import time
from types import SimpleNamespace

import pytest
from rclpy.task import Future
from unique_identifier_msgs.msg import UUID

from perch_interfaces.action import PlanPerches
from perch_operator.api import client

GOAL_ID = UUID(uuid=list(range(16)))
Answer = PlanPerches.Impl.SendGoalService.Response


class _Node:
    def __init__(self):
        self.warnings: list[str] = []

    def get_logger(self):
        return SimpleNamespace(warning=self.warnings.append)


class _Coordinator:
    """Answers the n-th sending of the goal as `answers[n]` (None: the request is lost)."""

    def __init__(self, monkeypatch, answers: list, listed_after: int | None = None):
        self.answers, self.sent = answers, []
        self.listed_after = listed_after   # the status list shows the goal once this many were sent
        self.statuses = SimpleNamespace(accepted={})
        monkeypatch.setattr(client, "GOAL_RESEND_AFTER", 0.2)
        monkeypatch.setattr(client, "_spin_briefly", lambda node, future=None: time.sleep(0.01))

    def send(self) -> Future:
        future = Future()
        answer = self.answers[len(self.sent)]
        self.sent.append(future)
        if answer is not None:
            future.set_result(Answer(accepted=answer))
        if self.listed_after is not None and len(self.sent) >= self.listed_after:
            self.statuses.accepted[bytes(GOAL_ID.uuid)] = Answer().stamp
        return future

    def handle(self, node=None):
        return client._goal_handle(node or _Node(), None, self.send, GOAL_ID, self.statuses,
                                   time.monotonic() + 10, 10)


def test_a_lost_goal_is_sent_again_and_its_resend_answers(monkeypatch):
    coordinator, node = _Coordinator(monkeypatch, [None, True]), _Node()
    started = time.monotonic()
    assert coordinator.handle(node).accepted
    assert len(coordinator.sent) == 2 and 0.2 <= time.monotonic() - started < 5
    assert "sending it again" in node.warnings[0]


def test_a_resend_refused_because_the_goal_runs_follows_the_running_goal(monkeypatch):
    # The first arrived (accepted, its answer lost); the resend is refused: the goal id is taken.
    coordinator = _Coordinator(monkeypatch, [None, False], listed_after=2)
    handle = coordinator.handle()
    assert handle.accepted and bytes(handle.goal_id.uuid) == bytes(GOAL_ID.uuid)


def test_a_refusal_of_a_goal_sent_once_is_the_answer(monkeypatch):
    coordinator = _Coordinator(monkeypatch, [False])
    assert not coordinator.handle().accepted and len(coordinator.sent) == 1


def test_a_refused_resend_of_a_lost_goal_is_the_answer_when_nothing_runs(monkeypatch):
    # Another mission runs: the resend is refused, and the lost first is never listed.
    coordinator = _Coordinator(monkeypatch, [None, False])
    started = time.monotonic()
    assert not coordinator.handle().accepted
    assert client.LOST_ANSWER_GRACE + 1.0 <= time.monotonic() - started < 8


def test_no_answer_at_all_is_a_timeout(monkeypatch):
    coordinator = _Coordinator(monkeypatch, [None] * 10)
    with pytest.raises(TimeoutError, match="did not answer the goal"):
        client._goal_handle(_Node(), None, coordinator.send, GOAL_ID, coordinator.statuses, time.monotonic() + 1.0, 1)
    assert 2 <= len(coordinator.sent) <= 3   # after 0.2 s, then 0.4 s more
