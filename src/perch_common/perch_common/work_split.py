"""One call's work split over two processes: a forked child takes one share, the caller the other.

The stages' per-item work (a filter's surfaces) is numpy, OpenCV and Embree called from Python:
two threads of one process share the GIL and gain ~20 % on two cores, two processes ~2x. A forked
child inherits what the caller built (the mesh, its ray scene, the flight grid) without a copy, so
only the child's results cross the pipe.

The answer never depends on the child. The caller runs its own share, then waits for the child's;
if the child cannot start (a daemonic process, no memory), fails, dies or outlives its patience,
the caller computes that share itself, so a call gives the same result in one process or two and a
real error is raised by the caller, with its own traceback. A cancel or an error in the caller
kills the child.

What a child may do: it runs in a fresh context (no cancel token or progress of the caller's
request: perch_common.work's calls are no-ops in it) on one thread, and must not build anything
that starts thread pools in a library (an Embree BVH, Open3D's OpenMP queries): the caller builds
those before the split. It never touches ROS; it ends with os._exit (multiprocessing's fork child).
"""

from __future__ import annotations

import contextvars
import mmap
import multiprocessing
import os
import signal
import sys
import time
import traceback
import warnings
from dataclasses import dataclass
from typing import Callable, Generic, Iterator, Sequence, TypeVar

import numpy as np

from perch_common.cancellation import checkpoint
from perch_common.processes import signal_at_parent_death
from perch_common.threads import one_thread, work_threads

T = TypeVar("T")

WAIT_SLICE = 0.1   # s between cancel checks while the caller waits for the child
REAP_WAIT = 5.0    # s a child that closed its pipe without an answer gets to exit (then it is killed)


@dataclass
class SplitRun(Generic[T]):
    """Both shares' results, and how they were computed."""

    mine: T
    theirs: T
    child: str          # "done" (the child's share came from the child) or why the caller computed it


def _child_main(run: Callable, share, send: Callable | None, conn, caller: int) -> None:
    """The child's side: run its share in a fresh context on one thread and send the result (or why not)."""
    # A node killed mid-call (a fault, a launcher's SIGKILL) takes its helper with it, at once.
    signal_at_parent_death(signal.SIGKILL)
    if os.getppid() != caller:
        os._exit(1)
    # What the caller had buffered for stdout and stderr when it forked is the caller's to write: the
    # child flushes its streams as it exits (multiprocessing flushes the caller's before the fork, but
    # another thread of the caller may have written in between), which would write it twice.
    sys.stdout = sys.stderr = open(os.devnull, "w")  # noqa: SIM115 - the child ends with os._exit

    def work():
        with one_thread():
            result = run(share)
            return send(result) if send is not None else result
    try:
        result = contextvars.Context().run(work)
        conn.send(("done", result))
    except BaseException as error:  # the caller recomputes the share and raises the error itself
        conn.send(("failed", f"{type(error).__name__}: {error}\n{traceback.format_exc(limit=3)}"))
    finally:
        conn.close()


def _exit_status(child) -> str:
    """How a child that sent no answer ended (it closed its pipe: it is exiting)."""
    child.join(REAP_WAIT)
    return f"exit code {child.exitcode}" if child.exitcode is not None else "closed its pipe without exiting"


def in_two_processes(run: Callable[[object], T], mine, theirs, patience: Callable[[float], float],
                     send: Callable | None = None, run_theirs: Callable | None = None,
                     lost: Callable[[], object] | None = None) -> SplitRun[T]:
    """`run(mine)` here and `run(theirs)` in a forked child, at the same time, each on one thread.

    `patience(s)` is how long the caller waits for the child once its own share took `s` seconds;
    past it the child is killed and its share computed here. `send(result)` is what the child sends
    of its result (all of it by default): `theirs` is that when `child` is "done", else run(theirs).
    `run_theirs`, when given, runs the child's share instead of `run` (in the child, or here in its place).
    `lost()`, when given, is the share computed here in place of a child's that never came (default `theirs`).
    """
    theirs_run = run_theirs if run_theirs is not None else run
    if work_threads() < 2:  # one core: the child would only take turns with the caller
        with one_thread():
            return SplitRun(run(mine), theirs_run(theirs), "one thread allowed")
    context = multiprocessing.get_context("fork")
    receiver, sender = context.Pipe(duplex=False)
    child = None
    try:
        try:
            child = context.Process(target=_child_main, args=(theirs_run, theirs, send, sender, os.getpid()),
                                    daemon=True, name="perch-share")
            with warnings.catch_warnings():  # Python >= 3.12 warns on any fork of a threaded process
                warnings.filterwarnings("ignore", message=".*fork.*", category=DeprecationWarning)
                child.start()
        except (AssertionError, OSError) as error:  # a daemonic caller may not have children; no memory
            child = None
            reason = f"no child process: {error}"
        finally:
            sender.close()
        started = time.monotonic()
        with one_thread():
            result = run(mine)
        if child is None:
            with one_thread():
                return SplitRun(result, theirs_run(theirs), reason)
        deadline = time.monotonic() + max(0.0, patience(time.monotonic() - started))
        status, payload = "", None
        while True:
            checkpoint("the second process's share")
            if receiver.poll(min(WAIT_SLICE, max(0.0, deadline - time.monotonic()))):
                try:
                    status, payload = receiver.recv()
                except (EOFError, OSError):
                    status, payload = "died", _exit_status(child)
                break
            if not child.is_alive() and not receiver.poll(0):
                status, payload = "died", _exit_status(child)
                break
            if time.monotonic() >= deadline:
                status, payload = "late", f"no answer {deadline - started:.1f} s after the split"
                break
        if status == "done":
            return SplitRun(result, payload, "done")
        with one_thread():
            return SplitRun(result, theirs_run(lost() if lost is not None else theirs), f"{status}: {payload}".strip())
    finally:
        receiver.close()
        if child is not None:
            if child.is_alive():
                child.kill()
            child.join()


class Claims:
    """Items taken from both ends of one order by two processes, each item as a process is ready for it:
    the caller from the front, a forked child from the back, until they meet. Each share then ends
    when the other's does, however fast either runs (a first call's imports, a busy core).

    Each process writes only its own count (one aligned 8-byte store, in a page shared across the
    fork) and reads the other's: neither ever waits for the other, and a child that dies mid-way
    holds nothing up. Two processes reading at once may both take the item they meet on (the same
    answer, computed twice); none is left out, as the counts only grow."""

    def __init__(self, order: Sequence[int]):
        self.order = list(order)
        self._counts = np.frombuffer(mmap.mmap(-1, 16), np.int64)  # anonymous mmap: MAP_SHARED

    def end(self, side: int) -> "ClaimEnd":
        """The front (0, the caller's) or the back (1, the child's)."""
        return ClaimEnd(self, side)

    def left(self, taken: Sequence[int]) -> list[int]:
        """The items of the order not in `taken`: the child's share, when the caller computes it."""
        done = set(taken)
        return [item for item in self.order if item not in done]

    def _take(self, side: int) -> Iterator[int]:
        total, counts = len(self.order), self._counts
        while True:
            own = int(counts[side])
            if own + int(counts[1 - side]) >= total:
                return
            counts[side] = own + 1
            yield self.order[own if side == 0 else total - 1 - own]


class ClaimEnd:
    """One end of Claims: iterating takes its items one by one and records them in `taken`. Its length is
    the whole order's (what progress counts against: a share's size is known when it ends)."""

    def __init__(self, claims: Claims, side: int):
        self.claims, self.side = claims, side
        self.taken: list[int] = []

    def __len__(self) -> int:
        return len(self.claims.order)

    def __iter__(self) -> Iterator[int]:
        for item in self.claims._take(self.side):
            self.taken.append(item)
            yield item


def claimed_in_two_processes(run: Callable[[object], list], order: Sequence[int], patience: Callable[[float], float],
                             run_theirs: Callable | None = None, send: Callable | None = None) -> SplitRun[dict]:
    """in_two_processes over the items of `order` claimed from both its ends (Claims): `run(items)`
    takes an iterable of items (sized by the whole order) and returns one result per item it took,
    in its order. `mine` and `theirs` of the answer map each item to its result; a lost child's items
    are computed here. `send(result)` is what the child sends of one item's result."""
    claims = Claims(order)
    front, back = claims.end(0), claims.end(1)
    theirs_run = run_theirs if run_theirs is not None else run

    def recorded(function: Callable) -> Callable[[object], dict]:
        def by_item(items) -> dict:
            results = function(items)
            taken = items.taken if isinstance(items, ClaimEnd) else list(items)
            return dict(zip(taken, results))
        return by_item

    return in_two_processes(recorded(run), front, back, patience, run_theirs=recorded(theirs_run),
                            send=None if send is None else lambda by_item: {k: send(v) for k, v in by_item.items()},
                            lost=lambda: claims.left(front.taken))
