"""Lap timing for stage reports (seconds per step), and ROS time stamps in nanoseconds."""

from __future__ import annotations

import time

from perch_common.cancellation import checkpoint


class Laps:
    """Call lap(name) after each step; laps maps step name to its seconds.

    Each lap is also a cancellation checkpoint: work cancelled by its client stops there.
    """

    def __init__(self) -> None:
        self.laps: dict[str, float] = {}
        self._start = self._last = time.perf_counter()

    def lap(self, name: str) -> float:
        """Add the seconds since the previous lap to lap `name`; returns that lap's total."""
        now = time.perf_counter()
        self.laps[name] = self.laps.get(name, 0.0) + now - self._last
        self._last = now
        checkpoint(f"the step after {name}")
        return self.laps[name]

    @property
    def total(self) -> float:
        """Seconds since the timer started."""
        return time.perf_counter() - self._start


def time_ns(stamp) -> int:
    """A builtin_interfaces/Time (rclpy's, or one decoded from a bag or recording) in nanoseconds."""
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)
