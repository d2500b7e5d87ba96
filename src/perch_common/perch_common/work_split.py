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
import multiprocessing
import os
import signal
import sys
import time
import traceback
import warnings
from dataclasses import dataclass
from typing import Callable, Generic, TypeVar

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
                     send: Callable | None = None, run_theirs: Callable | None = None) -> SplitRun[T]:
    """`run(mine)` here and `run(theirs)` in a forked child, at the same time, each on one thread.

    `patience(s)` is how long the caller waits for the child once its own share took `s` seconds;
    past it the child is killed and its share computed here. `send(result)` is what the child sends
    of its result (all of it by default): `theirs` is that when `child` is "done", else run(theirs).
    `run_theirs`, when given, runs the child's share instead of `run` (in the child, or here in its place).
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
            return SplitRun(result, theirs_run(theirs), f"{status}: {payload}".strip())
    finally:
        receiver.close()
        if child is not None:
            if child.is_alive():
                child.kill()
            child.join()
