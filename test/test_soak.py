"""A short soak (the 50-mission one is `perch bench soak --missions 50`): one of each kind of mission,
against `perch launch` with `perch plan --no-launch` clients."""

from __future__ import annotations

import pytest

pytestmark = pytest.mark.ros


def test_short_soak_with_a_kill_a_cancel_a_bad_goal_and_a_respawn(client_node, tmp_path):
    from perch_operator.bench.soak import Soak, launched

    graph = launched(tmp_path, client_node)
    try:
        # Interrupted once crop or segment runs: filter and optimise still lie ahead, so the signal lands
        # mid-mission however slow the machine. (From optimise a loaded machine's signal can arrive after
        # optimise has replied: the mission then finishes, which the soak counts as such.)
        soak = Soak(graph, client_node, tmp_path, seed=0, interrupt_at=("crop", "segment"))
        report = soak.run(5, kinds=["complete", "kill", "cancel", "bad_goal", "complete"])
        running = graph.pids()
    finally:
        graph.stop()
    summary = report.summary()
    assert not report.problems, summary
    assert report.completed >= 2 and report.failed_with_reason >= 2, summary
    # The kill and the interrupt landed while the mission ran (each waits for a stage to start).
    assert report.killed_mid_mission == 1 and report.cancelled_mid_mission == 1, summary
    assert report.bad_requests == 1 and "respawned by perch launch" in report.respawn, summary
    # The coordinator was free again soon after the killed client vanished (lease 3 s + client_grace 5 s).
    assert all(s < 20 for s in report.free_after_kill_s), summary
    assert {"perch_operator", "perch_segmentation", "perch_placement"} <= set(running)
