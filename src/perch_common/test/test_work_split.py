"""in_two_processes: the caller's share here, the other in a forked child, and the same answer
whatever happens to the child (it fails, dies, hangs, or cannot start)."""

import multiprocessing
import os
import threading

import pytest

from perch_common.cancellation import Cancelled, CancelToken, cancellable, current_token
from perch_common.threads import one_thread, work_threads
from perch_common.work_split import Claims, claimed_in_two_processes, in_two_processes

CALLER = os.getpid()


def squares(share):
    """The share's squares, with the process and the threads it was computed with."""
    return [x * x for x in share], os.getpid(), work_threads(), current_token() is None


def patient(own):
    return 60.0


@pytest.fixture(autouse=True)
def two_threads(monkeypatch):
    monkeypatch.setenv("OMP_NUM_THREADS", "2")
    yield
    assert not multiprocessing.active_children()  # no child outlives its call


def test_each_share_is_computed_once_the_other_in_a_child_on_one_thread():
    with cancellable(CancelToken()):
        split = in_two_processes(squares, [1, 2], [3, 4], patient)
    assert split.child == "done"
    assert split.mine == ([1, 4], CALLER, 1, False)
    values, pid, threads, no_token = split.theirs
    assert values == [9, 16] and pid != CALLER and threads == 1 and no_token  # the child has no request context
    assert work_threads() == 2  # the caller's own setting is back


def run_failing_in_the_child(share):
    if os.getpid() != CALLER:
        raise RuntimeError("only in the child")
    return squares(share)


def exit_in_the_child(share):
    if os.getpid() != CALLER:
        os._exit(3)
    return squares(share)


def hang_in_the_child(share):
    if os.getpid() != CALLER:
        threading.Event().wait()
    return squares(share)


@pytest.mark.parametrize("run, status, patience", [
    (run_failing_in_the_child, "failed: RuntimeError: only in the child", patient),
    (exit_in_the_child, "died: exit code 3", patient),
    (hang_in_the_child, "late: no answer", lambda own: 0.5),
])
def test_a_lost_child_share_is_computed_by_the_caller(run, status, patience):
    split = in_two_processes(run, [1, 2], [3, 4], patience)
    assert split.child.startswith(status)
    assert split.mine == ([1, 4], CALLER, 1, True) and split.theirs == ([9, 16], CALLER, 1, True)


def cubes(share):
    return [x ** 3 for x in share], os.getpid()


def cubes_failing_in_the_child(share):
    if os.getpid() != CALLER:
        raise RuntimeError("only in the child")
    return cubes(share)


@pytest.mark.parametrize("theirs_run, status", [(cubes, "done"), (cubes_failing_in_the_child, "failed")])
def test_the_childs_share_runs_its_own_function_there_or_here(theirs_run, status):
    split = in_two_processes(squares, [1, 2], [3, 4], patient, run_theirs=theirs_run)
    assert split.child.startswith(status)
    assert split.mine == ([1, 4], CALLER, 1, True)
    values, pid = split.theirs
    assert values == [27, 64] and (pid != CALLER) == (status == "done")


def test_an_error_in_the_callers_share_is_raised_and_the_child_killed():
    def failing_here(share):
        if os.getpid() == CALLER:
            raise ValueError("the caller's share")
        threading.Event().wait()  # would never answer: the caller must not wait for it

    with pytest.raises(ValueError, match="the caller's share"):
        in_two_processes(failing_here, [1], [2], patient)


def test_a_cancel_while_waiting_for_the_child_stops_the_call_and_kills_the_child():
    token = CancelToken()

    def cancelled_after_the_callers_share(share):
        if os.getpid() == CALLER:
            token.cancel("mission cancelled")
            return share
        threading.Event().wait()

    with cancellable(token), pytest.raises(Cancelled, match="mission cancelled"):
        in_two_processes(cancelled_after_the_callers_share, [1], [2], patient)


def test_one_allowed_thread_computes_both_shares_here():
    with one_thread():
        split = in_two_processes(squares, [1], [2], patient)
    assert split.child == "one thread allowed" and split.theirs == ([4], CALLER, 1, True)


def test_a_daemonic_caller_computes_both_shares_itself():
    """A process that may not have children (a daemonic worker of a process pool) still answers."""
    context = multiprocessing.get_context("fork")
    receiver, sender = context.Pipe(duplex=False)

    def in_a_daemon():
        split = in_two_processes(squares, [1], [2], patient)
        sender.send((split.child, split.mine[0], split.theirs[0], split.theirs[1] == os.getpid()))

    worker = context.Process(target=in_a_daemon, daemon=True)
    worker.start()
    assert receiver.poll(60)
    child, mine, theirs, here = receiver.recv()
    worker.join()
    assert child.startswith("no child process:") and "daemonic" in child
    assert (mine, theirs, here) == ([1], [4], True)


def test_output_the_caller_buffered_before_the_fork_is_written_once(tmp_path):
    """A command whose stdout is a file (block-buffered) must not see its lines twice: the child
    inherits the caller's unwritten buffer and would flush it as it exits."""
    import subprocess
    import sys

    out = tmp_path / "out.txt"
    script = ("import sys\nfrom perch_common.work_split import Claims, claimed_in_two_processes, in_two_processes\n"
              "print('written before the split')\n"
              "split = in_two_processes(lambda share: share, [1], [2], lambda own: 60.0)\n"
              "print('after', split.child)\n")
    with out.open("w") as stdout:
        subprocess.run([sys.executable, "-c", script], stdout=stdout, check=True, timeout=120,
                       env={**__import__("os").environ, "OMP_NUM_THREADS": "2"})
    assert out.read_text() == "written before the split\nafter done\n"


def test_the_child_dies_with_a_caller_that_is_killed(tmp_path):
    """A node killed mid-call (a fault soak's SIGKILL) leaves no helper computing on."""
    import subprocess
    import sys

    import psutil

    pid_file = tmp_path / "child.pid"
    script = f"""
import os, pathlib, threading, time
from perch_common.work_split import Claims, claimed_in_two_processes, in_two_processes
pid_file = pathlib.Path({str(pid_file)!r})
def run(share):
    if share == [2]:  # the child: say who it is, then compute forever
        pid_file.with_suffix(".tmp").write_text(str(os.getpid()))
        pid_file.with_suffix(".tmp").rename(pid_file)
        threading.Event().wait()
    while not pid_file.exists():  # the caller: killed once the child runs
        time.sleep(0.01)
    os.kill(os.getpid(), 9)
in_two_processes(run, [1], [2], lambda own: 60.0)
"""
    caller = subprocess.run([sys.executable, "-c", script], timeout=120,
                            env={**__import__("os").environ, "OMP_NUM_THREADS": "2"})
    assert caller.returncode == -9
    child = psutil.Process(int(pid_file.read_text()))
    gone, alive = psutil.wait_procs([child], timeout=30)
    assert not alive, "the child outlived its killed caller"


def test_claims_hand_out_every_item_once_from_both_ends():
    claims = Claims([5, 3, 8, 1, 9, 2])
    front, back = claims.end(0), claims.end(1)
    taking_front, taking_back = iter(front), iter(back)
    assert [next(taking_front), next(taking_back), next(taking_back), next(taking_front)] == [5, 2, 9, 3]
    assert list(taking_back) == [1, 8] and list(taking_front) == []   # the back went on to meet the front
    assert len(front) == len(back) == 6   # progress counts against the whole order
    assert front.taken == [5, 3] and back.taken == [2, 9, 1, 8]
    assert claims.left(front.taken) == [8, 1, 9, 2]


def squares_claimed(items):
    return [(x * x, os.getpid()) for x in items]


def test_claimed_items_go_to_whichever_process_takes_them_each_computed_once():
    """The child takes its first two items from the back and waits; the caller then takes all the rest
    from the front (the child, faster or slower, would have taken more or fewer)."""
    context = multiprocessing.get_context("fork")
    child_took, caller_done = context.Event(), context.Event()

    def run(items):
        if os.getpid() == CALLER:
            assert child_took.wait(60)
            out = squares_claimed(items)
            caller_done.set()
            return out
        out = []
        for x in items:
            out.append((x * x, os.getpid()))
            if len(out) == 2:
                child_took.set()
                assert caller_done.wait(60)   # nothing is left once the caller is done
        return out

    split = claimed_in_two_processes(run, [1, 2, 3, 4, 5, 6, 7], patient)
    assert split.child == "done"
    assert {x: value for x, (value, _) in (split.mine | split.theirs).items()} == {x: x * x for x in range(1, 8)}
    assert sorted(split.theirs) == [6, 7] and sorted(split.mine) == [1, 2, 3, 4, 5]
    assert {pid for _, pid in split.mine.values()} == {CALLER} and CALLER not in {pid for _, pid in split.theirs.values()}


def test_the_items_a_lost_child_took_are_computed_by_the_caller():
    """A child that dies after taking items computed nothing the caller can use: the caller computes
    them, and every other item (taken by itself) once."""
    context = multiprocessing.get_context("fork")
    child_took = context.Event()

    def run(items):
        if os.getpid() != CALLER:
            for count, _ in enumerate(items, 1):
                if count == 3:
                    child_took.set()
                    os._exit(4)
        assert child_took.wait(60)
        return squares_claimed(items)

    split = claimed_in_two_processes(run, list(range(10)), patient)
    assert split.child.startswith("died: exit code 4")
    assert sorted(split.mine) == list(range(7)) and sorted(split.theirs) == [7, 8, 9]
    assert {x: value for x, (value, pid) in (split.mine | split.theirs).items() if pid == CALLER} == \
        {x: x * x for x in range(10)}


def test_one_allowed_thread_takes_every_claimed_item_here():
    with one_thread():
        split = claimed_in_two_processes(squares_claimed, [3, 1, 2], patient)
    assert split.child == "one thread allowed" and split.theirs == {}
    assert split.mine == {3: (9, CALLER), 1: (1, CALLER), 2: (4, CALLER)}
