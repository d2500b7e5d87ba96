"""Stopping a stage's work part-way: the serving node sets a token, the pure core polls `checkpoint()`.

The token is per thread (a contextvar), so a core function needs no extra argument and stays
free of ROS: the node runs each request under `cancellable(token)`, and a cancel message from the
coordinator (perch_common.ros.service) sets it; the next `checkpoint()` raises Cancelled.
"""

from __future__ import annotations

import contextlib
import contextvars
import threading
from typing import Iterator

from perch_common.errors import PerchError


class Cancelled(PerchError):
    """The work was cancelled by its client (the mission was cancelled or its client vanished)."""


class CancelToken:
    """A thread-safe flag with the reason it was set."""

    def __init__(self) -> None:
        self._event = threading.Event()
        self.reason = ""

    def cancel(self, reason: str = "cancelled") -> None:
        """Ask the work to stop at its next checkpoint."""
        self.reason = reason
        self._event.set()

    @property
    def cancelled(self) -> bool:
        """True once cancel() was called."""
        return self._event.is_set()

    def check(self, step: str = "") -> None:
        """Raise Cancelled once cancel() was called (perch_common.work's context also checks its budget)."""
        if self.cancelled:
            raise Cancelled(f"{self.reason}" + (f" (stopped before {step})" if step else ""))


_current: contextvars.ContextVar[CancelToken | None] = contextvars.ContextVar("perch_cancel_token", default=None)


@contextlib.contextmanager
def cancellable(token: CancelToken) -> Iterator[CancelToken]:
    """Run the block with `token` as this thread's cancellation token."""
    reset = _current.set(token)
    try:
        yield token
    finally:
        _current.reset(reset)


def current_token() -> CancelToken | None:
    """This thread's token (set by `cancellable`), None outside one."""
    return _current.get()


def checkpoint(step: str = "") -> None:
    """Raise Cancelled when this thread's work was cancelled (or, under a perch_common.work context, ran
    out of its work budget); a no-op outside `cancellable`."""
    token = _current.get()
    if token is not None:
        token.check(step)
