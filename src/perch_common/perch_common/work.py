"""One stage call's work context: progress, cancel and a work budget, without ROS.

The serving node runs each call under a `WorkContext` (a CancelToken, so `checkpoint()` in the cores
keeps working) and the pure cores, which never see ROS, call the module functions at their existing
loop points:

  report(fraction, phase)        the share of the call's work done (0..1) and what it is doing now;
  steps(items, phase, lo, hi)    iterate `items`, reporting lo..hi of the call as they go;
  checkpoint(step)               stop here when the call was cancelled or ran out of its budget;
  with span(lo, hi): ...         reports inside the block (0..1 of its own work) become lo..hi of the call,
                                 so a helper reports its own share without knowing its caller's phases.

All four are no-ops outside a context (a core used from a script or a unit test). The context is
per thread (a contextvar), like the cancel token it extends, so no core signature changes.

Work budget (issue 22): a call may work at most `base + rate x size` CPU seconds of its process (a
loaded machine slows a call without refusing it), `size` being its input
(faces of the mesh; frames of a bag), set by the node once it knows the input (`set_budget`). Past
it, the next checkpoint or report raises BudgetExceeded with the stage, the budget, the size and a
hint: runaway work on a pathological input (a triangle soup) ends with its reason instead of running on
(the defaults allow several times a loaded normal run; they are a guard, not a fast soup detector).
"""

from __future__ import annotations

import contextlib
import math
import time
from typing import Callable, Iterable, Iterator, TypeVar

from perch_common.cancellation import Cancelled, CancelToken, current_token
from perch_common.errors import PerchError

T = TypeVar("T")

REPORT_INTERVAL = 0.25   # s between progress callbacks while the phase stays the same


class BudgetExceeded(PerchError):
    """A call worked longer than its work budget allows for its input."""


def work_budget(size: float, base: float, rate: float, per: float = 1000.0) -> float:
    """Seconds a call may work: `base + rate * size / per` (rate: seconds per `per` units of input)."""
    return float(base) + float(rate) * max(float(size), 0.0) / float(per)


class WorkContext(CancelToken):
    """A cancel token that also carries the call's progress callback and its deadline.

    on_progress(fraction, phase) is called from the working thread: on every phase change and at most
    every REPORT_INTERVAL s otherwise (a cheap loop may report every step). The budget is in CPU seconds
    of the process (time.process_time), the pacing in wall seconds; a test passes one `clock` for both.
    """

    def __init__(self, name: str = "the stage", on_progress: Callable[[float, str], None] | None = None,
                 clock: Callable[[], float] | None = None) -> None:
        super().__init__()
        self.name = name
        self.on_progress = on_progress
        # The budget counts the serving process's CPU seconds, not wall time: a loaded machine (a CI
        # runner, a laptop compiling beside it) slows a call down without making it more work.
        # Progress is paced in wall time. A test passes one clock for both.
        self.clock = clock or time.monotonic
        self.work_clock = clock or time.process_time
        self.started = self.work_clock()
        self.deadline = math.inf
        self.budget_reason = ""
        self.fraction = 0.0
        self.phase = ""
        self._sent_at = -math.inf
        self._spans: list[tuple[float, float]] = []   # nested (low, high) of the call a report maps into

    def set_budget(self, seconds: float, size: str, hint: str = "") -> None:
        """Allow `seconds` of CPU from the call's start for an input described by `size` ('122,000 faces')."""
        self.deadline = self.started + float(seconds)
        shown = f"{seconds:.0f}" if seconds >= 10 else f"{seconds:.2g}"
        self.budget_reason = (f"{self.name} exceeded its work budget of {shown} s for {size}"
                              + (f": {hint}" if hint else ""))

    def check(self, step: str = "") -> None:
        """Raise Cancelled when cancelled, BudgetExceeded when past the deadline."""
        super().check(step)
        if self.work_clock() > self.deadline:
            raise BudgetExceeded(self.budget_reason)

    def report(self, fraction: float, phase: str = "", detail: str = "") -> None:
        """Record progress (clipped to 0..1, never backwards), tell the callback when due, then check.

        `detail` ('12/40') is shown after the phase but a change of it alone is not a new phase."""
        for low, high in reversed(self._spans):
            fraction = low + (high - low) * min(max(float(fraction), 0.0), 1.0)
        fraction = min(max(float(fraction), self.fraction), 1.0)
        now = self.clock()
        changed = bool(phase) and phase != self.phase
        self.fraction = fraction
        if phase:
            self.phase = phase
        if self.on_progress is not None and (changed or now - self._sent_at >= REPORT_INTERVAL):
            self._sent_at = now
            self.on_progress(self.fraction, f"{self.phase} {detail}" if detail else self.phase)
        self.check(phase)


@contextlib.contextmanager
def span(low: float, high: float) -> Iterator[None]:
    """Within the block, a report of f (0..1) means low + (high - low) * f of the enclosing span."""
    context = current()
    if context is None:
        yield
        return
    context._spans.append((float(low), float(high)))
    try:
        yield
    finally:
        context._spans.pop()


SOUP_HINT = "the mesh is likely a triangle soup; run `perch mesh info`"   # what a budget refusal suggests first
CLI_BUDGET_ENV = "PERCH_WORK_BUDGET"   # seconds for a command-line stage run (perch segment/filter/optimise); 0: none


@contextlib.contextmanager
def command_budget(name: str, faces: int, hint: str = SOUP_HINT,
                   on_progress: Callable[[float, str], None] | None = None) -> Iterator[WorkContext]:
    """Run a command-line stage (`perch filter ...`) under the stage nodes' default work budget for `faces`
    (StageNodeConfig's work_budget_base and work_budget_rate), or PERCH_WORK_BUDGET seconds when set."""
    import dataclasses
    import os

    from perch_common.cancellation import cancellable
    from perch_common.config import StageNodeConfig

    defaults = {f.name: f.default for f in dataclasses.fields(StageNodeConfig)}
    given = os.environ.get(CLI_BUDGET_ENV, "").strip()
    try:
        seconds = float(given) if given else work_budget(faces, defaults["work_budget_base"],
                                                         defaults["work_budget_rate"])
    except ValueError:
        raise PerchError(f"{CLI_BUDGET_ENV}={given!r}: give the seconds a run may take (0: no budget)") from None
    context = WorkContext(name, on_progress)
    if seconds > 0:
        context.set_budget(seconds, f"{faces:,} faces",
                           f"{hint}; if the input is sound, run again with {CLI_BUDGET_ENV}={max(2 * seconds, 60):.0f} "
                           f"(0: no budget)")
    with cancellable(context):
        yield context


def current() -> WorkContext | None:
    """This thread's work context, None outside one (or under a bare CancelToken)."""
    token = current_token()
    return token if isinstance(token, WorkContext) else None


def report(fraction: float, phase: str = "") -> None:
    """Report the share of the current call's work done and its phase; a no-op outside a call."""
    context = current()
    if context is not None:
        context.report(fraction, phase)


def steps(items: Iterable[T], phase: str, low: float = 0.0, high: float = 1.0) -> Iterator[T]:
    """Yield `items`, reporting low..high of the call (phase 'PHASE i/n') before each one.

    Within a call's context every step is also a checkpoint (cancel, budget)."""
    items = list(items) if not hasattr(items, "__len__") else items
    total = len(items)
    context = current()
    for i, item in enumerate(items):
        if context is not None:
            context.report(low + (high - low) * i / max(total, 1), phase, f"{i + 1}/{total}")
        yield item
    if context is not None:
        context.report(high, phase, f"{total}/{total}")


__all__ = ["BudgetExceeded", "Cancelled", "WorkContext", "command_budget", "current", "report", "span", "steps",
           "work_budget"]
