"""`perch bench mission --repeat N`: fresh processes, medians of every figure, a clean exit."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from perch_common.ros import testing

pytestmark = pytest.mark.ros


def test_repeated_bench_reports_medians_and_exits_cleanly(graph_parts):
    if graph_parts.missing:
        pytest.skip(f"stage node(s) not installed yet: {', '.join(graph_parts.missing)}")
    done = subprocess.run([sys.executable, "-m", "perch_common.cli", "bench", "mission", "--scene", "2", "--kind",
                           "room", "--cameras", "2", "--repeat", "2", "--json"],
                          capture_output=True, text=True, env=testing.isolated_ros_env(), timeout=600)
    # A native library corrupting the heap at interpreter exit shows here as exit 134 (SIGABRT).
    assert done.returncode == 0, done.stderr[-3000:]
    assert "malloc" not in done.stderr
    result = json.loads(done.stdout)
    assert result["repeat"] == 2 and len(result["runs"]) == 2 and len(result["load_average_1min"]) == 2
    median = result["median"]
    for figure in ("wall_s", "input_s", "startup_s", "mission_s", "transport_s", "peak_rss_mb"):
        values = sorted(r[figure] for r in result["runs"])
        assert median[figure] == pytest.approx(sum(values) / 2, abs=1e-3)   # the median of two
    assert set(median["stages"]) == {"clean", "crop", "segment", "filter", "optimise", "confirm"}
    assert median["wall_s"] > median["mission_s"] > median["stages"]["segment"] > 0 and median["startup_s"] > 0
    assert 0 < median["input_s"] < median["wall_s"] - median["mission_s"]   # the scene is made before the mission
    # Seeded: both runs plan the same cameras.
    fitness = [r["fitness"] for r in result["runs"]]
    # Each run in a namespace of its own on the user's domain (never beside or inside another graph).
    namespaces = [r["namespace"] for r in result["runs"]]
    assert all(ns.startswith("/perch_bench_") for ns in namespaces) and namespaces[0] != namespaces[1]
    assert median["cameras"] == 2 and fitness[0] == fitness[1] and median["fitness"] == pytest.approx(fitness[0], abs=1e-3)


def test_recorded_bench_times_the_waypoints_and_then_every_output(graph_parts):
    """--record runs the mission as `perch plan` does: waypoints.yaml is written when the result
    comes in (wall_s), the recording, report and rerun file after it (outputs_s)."""
    from pathlib import Path

    if graph_parts.missing:
        pytest.skip(f"stage node(s) not installed yet: {', '.join(graph_parts.missing)}")
    done = subprocess.run([sys.executable, "-m", "perch_common.cli", "bench", "mission", "--scene", "2", "--kind",
                           "room", "--cameras", "2", "--record", "--json"],
                          capture_output=True, text=True, env=testing.isolated_ros_env(), timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    result = json.loads(done.stdout)
    assert result["recorded"] and not result["failures"] and result["cameras"] == 2
    assert result["outputs_s"] > result["wall_s"] > result["mission_s"] > result["stages"]["segment"] > 0
    folder = Path(result["waypoints"]).parent
    assert {"waypoints.yaml", "run.mcap", "run.rrd", "report.html"} <= {p.name for p in folder.iterdir()}
