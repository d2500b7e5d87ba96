"""A mission client interrupted (Ctrl-C, time limit) asks for a cancel; a refused or unanswered cancel
is said, never turned into a second error that hides the first (it was a TimeoutError traceback)."""

from __future__ import annotations

from action_msgs.msg import GoalInfo
from action_msgs.srv import CancelGoal
from rclpy.task import Future

from perch_operator.api import client


class _Logger:
    def __init__(self):
        self.warnings: list[str] = []

    def warning(self, text: str) -> None:
        self.warnings.append(text)


class _Node:
    def __init__(self):
        self.logger = _Logger()

    def get_logger(self) -> _Logger:
        return self.logger


class _Handle:
    def __init__(self, future: Future):
        self.future = future

    def cancel_goal_async(self) -> Future:
        return self.future


def _answered(goals: int) -> Future:
    future = Future()
    future.set_result(CancelGoal.Response(goals_canceling=[GoalInfo() for _ in range(goals)]))
    return future


def test_an_accepted_cancel_says_nothing():
    node = _Node()
    client._cancel_or_say_why_not(node, _Handle(_answered(1)))
    assert node.logger.warnings == []


def test_a_refused_cancel_says_the_mission_ends_when_its_client_leaves():
    node = _Node()
    client._cancel_or_say_why_not(node, _Handle(_answered(0)))
    assert len(node.logger.warnings) == 1
    assert "refused the cancel" in node.logger.warnings[0] and "client_grace" in node.logger.warnings[0]


def test_an_unanswered_cancel_is_said_not_raised(monkeypatch):
    monkeypatch.setattr(client, "CANCEL_WAIT", 0.0)
    node = _Node()
    client._cancel_or_say_why_not(node, _Handle(Future()))   # never answered
    assert len(node.logger.warnings) == 1 and "did not answer the cancel" in node.logger.warnings[0]
