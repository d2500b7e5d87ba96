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
        self.infos: list[str] = []

    def warning(self, text: str) -> None:
        self.warnings.append(text)

    def info(self, text: str) -> None:
        self.infos.append(text)


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


def test_a_cancel_refused_because_the_mission_had_ended_says_so_without_a_warning():
    node = _Node()
    client._cancel_or_say_why_not(node, _Handle(_answered(0)), ended=lambda: True)
    assert node.logger.warnings == []
    assert len(node.logger.infos) == 1 and "already ended" in node.logger.infos[0]


def test_an_unanswered_cancel_is_said_not_raised(monkeypatch):
    monkeypatch.setattr(client, "CANCEL_WAIT", 0.0)
    node = _Node()
    client._cancel_or_say_why_not(node, _Handle(Future()))   # never answered
    assert len(node.logger.warnings) == 1 and "did not answer the cancel" in node.logger.warnings[0]


class _Clock:
    def __init__(self):
        self.now = 0.0

    def monotonic(self) -> float:
        return self.now


def test_the_signed_cancel_is_resent_with_a_fresh_token_each_second_until_the_goal_is_cancelling(monkeypatch):
    from action_msgs.msg import GoalStatus
    from unique_identifier_msgs.msg import UUID

    clock = _Clock()
    monkeypatch.setattr(client.time, "monotonic", clock.monotonic)
    canceller = client.MissionCanceller.__new__(client.MissionCanceller)   # no node: record what it would send
    sent: list[float] = []
    canceller.send = lambda goal_id, reason: sent.append(clock.now)
    status = {"now": GoalStatus.STATUS_EXECUTING}

    def step() -> None:   # 0.25 s pass; the coordinator lists the goal as cancelling at 2.6 s
        clock.now += 0.25
        if clock.now >= 2.6:
            status["now"] = GoalStatus.STATUS_CANCELING

    assert canceller.cancel(UUID(), "test", lambda: status["now"], wait=10.0, step=step)
    assert sent == [0.0, 1.0, 2.0]
    status["now"], clock.now, sent[:] = GoalStatus.STATUS_EXECUTING, 0.0, []
    assert not canceller.cancel(UUID(), "test", lambda: status["now"], wait=1.6, step=lambda: setattr(
        clock, "now", clock.now + 0.25))   # never taken: False after `wait`
    assert sent == [0.0, 1.0]


def test_a_signed_cancel_not_taken_is_said_not_raised():
    class _Signed:
        def cancel(self, goal_id, reason, status, wait=0.0, step=None) -> bool:
            return False

    node, handle = _Node(), _Handle(Future())
    handle.goal_id, handle.status = None, 2
    client._cancel_or_say_why_not(node, handle, _Signed(), "perch plan: interrupted (Ctrl-C)")
    assert len(node.logger.warnings) == 1
    assert "did not take the signed cancel" in node.logger.warnings[0] and "client_grace" in node.logger.warnings[0]
