"""Surface review before filtering: the operator approves or rejects the largest surfaces.

Pure Python (no rclpy): the node opens a review, publishes it, and a /perch/review_surfaces call
decides it; the mission thread waits on the decision.
"""

from __future__ import annotations

import threading
import time
from typing import Callable


class ReviewError(ValueError):
    """A decision that cannot be applied (unknown review, unknown surface, decided twice)."""


class ReviewDesk:
    """Open surface reviews and the operator's rejections, waited on by the mission."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._next_id = 1
        self._surfaces: dict[int, set[int]] = {}
        self._decisions: dict[int, set[int]] = {}
        self._decided = threading.Condition(self._lock)

    def open(self, surface_ids: list[int]) -> int:
        """A new review of these surfaces; returns its id."""
        with self._lock:
            review_id = self._next_id
            self._next_id += 1
            self._surfaces[review_id] = set(int(i) for i in surface_ids)
            return review_id

    def decide(self, review_id: int, rejected: list[int]) -> set[int]:
        """Record the decision: every reviewed surface not in `rejected` is approved."""
        with self._lock:
            if review_id not in self._surfaces:
                raise ReviewError(f"no surface review {review_id} is open")
            if review_id in self._decisions:
                raise ReviewError(f"surface review {review_id} was already decided")
            unknown = sorted(set(int(i) for i in rejected) - self._surfaces[review_id])
            if unknown:
                raise ReviewError(f"surface(s) {unknown} are not part of review {review_id} "
                                  f"(reviewed: {sorted(self._surfaces[review_id])})")
            self._decisions[review_id] = set(int(i) for i in rejected)
            self._decided.notify_all()
            return self._decisions[review_id]

    def wait(self, review_id: int, timeout: float, cancelled: Callable[[], bool]) -> set[int]:
        """The rejected surface ids once decided; TimeoutError after `timeout` s (0: no limit)."""
        started = time.monotonic()
        with self._lock:
            while review_id not in self._decisions:
                if cancelled():
                    raise TimeoutError(f"mission cancelled during surface review {review_id}")
                if timeout > 0 and time.monotonic() - started > timeout:
                    raise TimeoutError(f"no decision on surface review {review_id} within {timeout:g} s "
                                       "(perch operator review ID [--reject ...]; parameter confirm_timeout)")
                self._decided.wait(0.25)
            return self._decisions[review_id]
