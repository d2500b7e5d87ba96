"""Thirty missions on one graph: no stage crashes and none grows in memory once warm.

A stage's action server keeps each finished goal's result for action_server_result_timeout (60 s by
default) for a late get_result: over a minute of back-to-back missions a stage's RSS climbs by a
result a mission, then stays (seen over 150 room missions: segmentation +17 MB and filtering +13 MB
until mission ~50, flat after). That is retention, bounded by the parameter, not a leak; this graph
keeps results 5 s, so that the retained results are level before mission 10 and what the test sees
growing is growth. Not shorter: the coordinator asks for a result as its goal is accepted, and a
request delayed past the expiry on a loaded machine would fail the mission. (The goal's request,
its meshes, is dropped as soon as it has run: test_stage_action.py.)
"""

from __future__ import annotations

import numpy as np
import pytest

pytestmark = pytest.mark.ros

GRAPH_CHANGES = {node: {"action_server_result_timeout": 5.0}
                 for node in ("perch_reconstruction", "perch_segmentation", "perch_filtering", "perch_placement")}
MISSIONS = 30
# MB a mission, the typical (median) change of RSS from one mission to the next over missions 10-30: a leak
# of a mission's mesh or reply adds several MB every mission; the allocator's plateaus and swings do not
# (see the test).
MAX_RSS_STEP_MB = 1.0


@pytest.mark.slow
def test_thirty_missions_without_crashes_or_memory_growth(graph):
    import psutil

    from perch_common.scene_generator import generate_scene
    from perch_operator.api.client import run_mission, scene_goal

    goal = scene_goal(generate_scene(3, "room"), cameras=2)
    procs = {n: psutil.Process(p.pid) for n, p in graph.processes.processes.items()}
    rss: dict[str, list[float]] = {n: [] for n in procs}
    for i in range(MISSIONS):
        result = run_mission(graph.node, goal, timeout=300)
        assert result.success, f"mission {i}: {result.message}"
        for name, proc in procs.items():
            rss[name].append(proc.memory_info().rss / 2**20)
    assert all(graph.processes.alive().values()), graph.processes.alive()
    for name, values in rss.items():
        # No growth once warm. A stage's RSS after a mission sits on one of a few plateaus, tens of MB
        # apart, for several missions at a time (how much of its last peak the allocator kept: perch_placement
        # 234 MB for missions 2-13, then 274 MB, flat, in one run), so a slope or a peak over ten missions
        # reads one plateau change as a leak. A leak grows every mission: the median step between
        # consecutive missions is ~0 on plateaus whatever their jumps, and the leak's size with a leak.
        # A leak also accumulates. RSS that swings a few MB from mission to mission (the operator's, sigma
        # 2.8 MB, in one CI rehearsal) gives a median step >= 1 MB one run in eight by chance (that run:
        # +4.8 -7.8 +6.5 +1.6 -5.4 +5.1 -1.3 +0.4 +2.1 -1.8, flat over the ten). So a leak is growth both
        # ways: the median step and the Theil-Sen slope (median of all pairs' slopes, which a plateau
        # change moves but swings do not). Simulated on such swings: 0.03 % false alarms; a leak of 2 MB a
        # mission caught 87 % of the time, of 3 MB 99 %.
        # Swings can be larger and go up from a floor: RSS read before a node trimmed its heap after its
        # reply (0.2 s later, delayed on a loaded machine). perch_filtering swung 344-366 MB in one CI
        # rehearsal, flat over the twenty, and both statistics flagged it (2.33 and 1.30 MB). A leak lifts
        # the floor too, so growth must also show there: the least RSS of the last five missions above that of 10-14.
        # Simulated with such swings (up by an exponential of mean 7 MB in 60 % of the readings): false
        # alarms 0.6 % -> 0.01 %; a leak of 2 MB a mission still caught 88 % of the time, of 3 MB 96 %.
        # perch_filtering's swings are wider than that model: 303-342 MB after its heap's trim (sd 8 MB, up
        # to +22 MB; six runs of twenty missions, two without the filter's Open3D import at start-up, and a
        # CI rehearsal's 403-434, which failed all three statistics). Drawn from those readings, a window of
        # missions 10-20 raised 3.2 % false alarms and caught a 2 MB leak 55 % of the time; missions 10-30
        # raise 0.005 % and catch it 76 %, 3 MB 91 %.
        window = np.asarray(values[9:])
        steps = np.diff(window)
        first, second = np.triu_indices(len(window), 1)
        slope = float(np.median((window[second] - window[first]) / (second - first)))
        floor = float(window[-5:].min() - window[:5].min()) / (len(window) - 5)
        assert float(np.median(steps)) < MAX_RSS_STEP_MB or slope < MAX_RSS_STEP_MB or floor < MAX_RSS_STEP_MB, (
            f"{name}: RSS grows by a median {np.median(steps):.2f} MB a mission (slope {slope:.2f} MB, floor "
            f"{floor:.2f} MB) over missions 10-{MISSIONS} ({values})")
