"""perch_common.work: progress reports, cancel and the work budget of one call, without ROS."""

from __future__ import annotations

import pytest

from perch_common.cancellation import Cancelled, cancellable, checkpoint
from perch_common.work import BudgetExceeded, WorkContext, report, span, steps, work_budget


class FakeClock:
    """A monotonic clock the test moves by hand."""

    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def test_outside_a_call_the_functions_do_nothing():
    report(0.5, "anything")
    assert list(steps([1, 2, 3], "items")) == [1, 2, 3]
    checkpoint("anything")


def test_steps_report_the_span_they_cover_and_every_phase_change():
    sent = []
    clock = FakeClock()
    context = WorkContext("perch/filter", lambda f, p: sent.append((round(f, 3), p)), clock)
    with cancellable(context):
        report(0.0, "grid")
        for _ in steps(["a", "b", "c", "d"], "surfaces", 0.2, 0.6):
            clock.now += 1.0   # each surface takes a second: every step is due
        report(0.9, "regions")
    assert sent == [(0.0, "grid"), (0.2, "surfaces 1/4"), (0.3, "surfaces 2/4"), (0.4, "surfaces 3/4"),
                    (0.5, "surfaces 4/4"), (0.6, "surfaces 4/4"), (0.9, "regions")]
    assert context.fraction == pytest.approx(0.9)


def test_quick_steps_are_throttled_and_progress_never_goes_back():
    sent = []
    clock = FakeClock()
    context = WorkContext("perch/segment", lambda f, p: sent.append(f), clock)
    with cancellable(context):
        for _ in steps(range(1000), "merge rounds", 0.0, 0.5):
            clock.now += 0.001   # 1 ms a step: one report every REPORT_INTERVAL (0.25 s)
        report(0.3, "merge rounds")   # behind what was reported: stays at 0.5
    assert 4 <= len(sent) <= 8
    assert sent == sorted(sent)
    assert context.fraction == pytest.approx(0.5)


def test_a_call_past_its_budget_stops_at_the_next_report_with_the_reason():
    clock = FakeClock()
    context = WorkContext("perch/filter", clock=clock)
    context.set_budget(work_budget(122_000, base=2.0, rate=0.01), "122,000 faces",
                       "the mesh is likely a triangle soup; run `perch mesh info`")
    assert context.deadline - context.started == pytest.approx(3.22)
    done = []
    with cancellable(context), pytest.raises(BudgetExceeded) as caught:
        for surface in steps(range(10), "surfaces"):
            clock.now += 1.0
            done.append(surface)
    assert done == [0, 1, 2, 3]   # stopped at the first step after 3.22 s
    assert str(caught.value) == ("perch/filter exceeded its work budget of 3.2 s for 122,000 faces: "
                                 "the mesh is likely a triangle soup; run `perch mesh info`")


def test_checkpoint_enforces_the_budget_and_the_cancel():
    clock = FakeClock()
    context = WorkContext("perch/segment", clock=clock)
    context.set_budget(5.0, "10 faces")
    with cancellable(context):
        clock.now += 4.9
        checkpoint("the next merge round")   # within the budget
        clock.now += 0.2
        with pytest.raises(BudgetExceeded, match="work budget of 5 s for 10 faces"):
            checkpoint("the next merge round")
    cancelled = WorkContext("perch/segment", clock=clock)
    cancelled.cancel("perch/segment: cancelled by its caller")
    with cancellable(cancelled), pytest.raises(Cancelled, match="stopped before grow"):
        report(0.1, "grow")


def test_the_budget_grows_with_the_input():
    assert work_budget(0, base=30.0, rate=0.2) == pytest.approx(30.0)
    assert work_budget(1_000_000, base=30.0, rate=0.2) == pytest.approx(230.0)
    assert work_budget(60, base=60.0, rate=5.0, per=1) == pytest.approx(360.0)


def test_a_span_maps_a_helpers_own_share_into_its_callers_phase():
    sent = []
    clock = FakeClock()
    context = WorkContext("perch/segment", lambda f, p: sent.append((round(f, 3), p)), clock)

    def helper():   # knows only its own work
        for _ in steps(range(2), "merge round"):
            clock.now += 1.0

    with cancellable(context):
        with span(0.2, 0.6):
            helper()
        report(0.7, "surfaces")
    assert sent == [(0.2, "merge round 1/2"), (0.4, "merge round 2/2"), (0.6, "merge round 2/2"), (0.7, "surfaces")]
    with span(0.1, 0.2):   # outside a call: nothing to map
        report(0.5)


def test_a_command_runs_under_the_nodes_default_budget_or_the_one_given(monkeypatch):
    from perch_common.work import command_budget

    monkeypatch.delenv("PERCH_WORK_BUDGET", raising=False)
    with command_budget("perch filter", 122_000) as context:
        assert context.deadline - context.started == pytest.approx(120.0 + 0.5 * 122)
        checkpoint("the work")   # well within it
    monkeypatch.setenv("PERCH_WORK_BUDGET", "0")
    with command_budget("perch filter", 122_000) as context:
        assert context.deadline == float("inf")
    monkeypatch.setenv("PERCH_WORK_BUDGET", "soon")
    with pytest.raises(Exception, match="PERCH_WORK_BUDGET='soon': give the seconds"):
        with command_budget("perch filter", 10):
            pass
