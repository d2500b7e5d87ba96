"""rclpy's ActionClient with its send-then-register race closed, for the coordinator's stage calls."""

from __future__ import annotations

import threading

from rclpy.action import ActionClient


class RegisteringActionClient(ActionClient):
    """rclpy's ActionClient (Jazzy 7.1.5) sends a goal, cancel or result request first and registers the
    future its response completes afterwards. An executor thread that takes the response in between drops
    it ("Ignoring unexpected ... response") and the future never completes: the caller waits for its
    whole timeout (ros2/rclpy#1123, fixed upstream after this version). Here each send and its
    registration hold one lock, and the handling of taken responses waits for that lock."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        # Reentrant: a response's done callback may send the next request (the result after the goal).
        self._registering = threading.RLock()

    def send_goal_async(self, *args, **kwargs):
        """rclpy's send_goal_async, registered before its answer is handled."""
        with self._registering:
            return super().send_goal_async(*args, **kwargs)

    def _cancel_goal_async(self, goal_handle):
        with self._registering:
            return super()._cancel_goal_async(goal_handle)

    def _get_result_async(self, goal_handle):
        with self._registering:
            return super()._get_result_async(goal_handle)

    async def execute(self, taken_data):
        """rclpy's handling of taken responses, feedback and status, once no request is half registered."""
        with self._registering:   # a request sent but not yet registered is registered first
            pass
        await super().execute(taken_data)
