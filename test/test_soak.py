"""A short soak (the 50-mission one is `perch bench soak --missions 50`): one of each kind of mission."""

from __future__ import annotations

import pytest

pytestmark = pytest.mark.ros


def test_short_soak_with_a_kill_a_cancel_a_bad_goal_and_a_respawn(graph, tmp_path):
    from perch_operator.soak import Soak

    soak = Soak(graph.processes, graph.node, tmp_path, seed=0)
    report = soak.run(5, kinds=["complete", "kill", "cancel", "bad_goal", "complete"])
    summary = report.summary()
    assert not report.problems, summary
    assert report.completed >= 2 and report.failed_with_reason >= 1, summary
    assert report.bad_requests == 1 and "back in" in report.respawn, summary
    # The coordinator was free again soon after the killed client vanished (lease 3 s + client_grace 5 s).
    assert all(s < 20 for s in report.free_after_kill_s), summary
    assert all(graph.processes.alive().values())
