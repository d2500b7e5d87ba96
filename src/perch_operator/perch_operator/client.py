"""Client side of a mission: send a PlanPerches goal, show progress, wait for the result."""

from __future__ import annotations

import time
from typing import Callable

import rclpy
from rclpy.action import ActionClient

from perch_common.errors import PerchError
from perch_interfaces.action import PlanPerches

ACTION = "perch/plan_perches"


class GoalRejected(PerchError):
    """The coordinator refused the goal (another mission is running); nothing was started."""


def _spin_until(node, future, deadline: float, what: str) -> None:
    while not future.done():
        if time.monotonic() > deadline:
            raise TimeoutError(f"{what} did not finish in time")
        rclpy.spin_until_future_complete(node, future, timeout_sec=0.1)


def run_mission(node, goal: PlanPerches.Goal, timeout: float = 600.0, server_wait: float = 30.0,
                on_feedback: Callable[[PlanPerches.Feedback], None] | None = None) -> PlanPerches.Result:
    """Run one mission on the live graph and return its result (success or not)."""
    client = ActionClient(node, PlanPerches, ACTION)
    try:
        if not client.wait_for_server(timeout_sec=server_wait):
            raise PerchError(f"no mission coordinator: action {ACTION} did not appear within {server_wait:.0f} s; "
                             "start the graph with `perch launch` (or use `perch plan`, which launches it)")
        deadline = time.monotonic() + timeout
        sent = client.send_goal_async(
            goal, feedback_callback=(lambda m: on_feedback(m.feedback)) if on_feedback else None)
        # The coordinator answers a goal at once (accepted or refused); no answer means it never got it.
        try:
            _spin_until(node, sent, min(deadline, time.monotonic() + server_wait), "sending the goal")
        except TimeoutError:
            raise TimeoutError(f"the coordinator did not answer the goal within {server_wait:.0f} s (another "
                               "process on this ROS domain may serve the action without running it: "
                               "`ros2 action info` lists the servers, a restart of the graph clears it)") from None
        handle = sent.result()
        if not handle.accepted:
            raise GoalRejected("the coordinator rejected the goal: another mission is running (wait for it, "
                               "or cancel it with `perch operator cancel`); nothing was written")
        result = handle.get_result_async()
        try:
            _spin_until(node, result, deadline, f"the mission ({timeout:.0f} s limit)")
        except (TimeoutError, KeyboardInterrupt):
            cancel = handle.cancel_goal_async()
            _spin_until(node, cancel, time.monotonic() + 5, "cancelling the mission")
            raise
        return result.result().result
    finally:
        client.destroy()


class ProgressPrinter:
    """Prints a line when the stage changes and a progress bar in place on a terminal."""

    def __init__(self, stream=None, tty: bool | None = None):
        import sys

        self.stream = stream or sys.stderr
        self.tty = self.stream.isatty() if tty is None else tty
        self.stage = None
        self.started = time.monotonic()

    def __call__(self, feedback: PlanPerches.Feedback) -> None:
        """Print one feedback message (a new line per stage, updated in place on a terminal)."""
        elapsed = time.monotonic() - self.started
        if feedback.stage != self.stage:
            self.stage = feedback.stage
            if self.tty:
                self.stream.write("\n")
            self.stream.write(f"[{elapsed:5.1f} s] {feedback.stage}: {feedback.message}\n" if not self.tty else "")
        if self.tty:
            bar = "#" * int(30 * feedback.fraction)
            self.stream.write(f"\r[{bar:<30}] {100 * feedback.fraction:3.0f}%  {feedback.stage:<9} "
                              f"{elapsed:5.1f} s  {feedback.message[:60]:<60}")
        self.stream.flush()

    def close(self) -> None:
        """End the progress line."""
        if self.tty:
            self.stream.write("\n")
            self.stream.flush()
