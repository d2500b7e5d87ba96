"""`perch plan` as a user runs it: identical results in both graph modes, its own graph on the user's
domain beside other nodes (never moved to another domain), and SIGTERM/SIGHUP stopping the nodes it started."""

from __future__ import annotations

import signal
import subprocess
import sys
import time

import pytest
import yaml

pytestmark = pytest.mark.ros

PERCH = [sys.executable, "-m", "perch_common.cli"]
PLAN = ["plan", "--scene", "3", "--kind", "room", "--cameras", "2", "--auto-accept", "--quiet"]


def _env():
    from perch_common.ros.testing import isolated_ros_env

    return isolated_ros_env()


def _plan(out, *extra, env=None, timeout=600):
    return subprocess.run(PERCH + PLAN + ["-o", str(out), *extra], env=env or _env(), capture_output=True,
                          text=True, timeout=timeout)


@pytest.fixture(scope="module")
def per_node_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("per_node")
    done = _plan(out, "--graph-mode", "per-node")
    assert done.returncode == 0, done.stderr[-3000:]
    return out


def test_one_process_graph_gives_the_same_perches_as_node_processes(per_node_run, tmp_path):
    import numpy as np

    done = _plan(tmp_path, "--graph-mode", "one-process")
    assert done.returncode == 0, done.stderr[-3000:]
    ours = yaml.safe_load((tmp_path / "waypoints.yaml").read_text())["waypoints"]
    theirs = yaml.safe_load((per_node_run / "waypoints.yaml").read_text())["waypoints"]
    assert len(ours) == len(theirs) == 2
    for a, b in zip(ours, theirs):
        assert a["drone_index"] == b["drone_index"]
        np.testing.assert_allclose(a["position"], b["position"], atol=1e-6)
        np.testing.assert_allclose(a["orientation_xyzw"], b["orientation_xyzw"], atol=1e-6)
    for name in ("run.mcap", "run.rrd", "report.html"):
        assert (tmp_path / name).stat().st_size > 0
    # The recording of the one-process mission replays (each mesh recorded once, later named by id).
    from perch_operator.outputs.runfile import stage_calls

    calls = stage_calls(tmp_path / "run.mcap")
    assert [c.stage for c in calls] == ["clean", "crop", "segment", "filter", "optimise"]
    assert all(len(c.request.mesh.triangles) for c in calls), "an id-only mesh was not resolved from the recording"


def test_plan_starts_its_own_graph_on_the_users_domain_beside_other_nodes(tmp_path):
    """Nodes that are no mission graph run on this domain: plan starts its own graph beside them, on
    the same domain (a viewer there sees the mission), and does not disturb them. (A Perch mission
    graph already there is used: test/test_ros_citizen.py.)"""
    from perch_common.launch import current_domain

    env = _env()
    config = tmp_path / "p.yaml"
    config.write_text("perch_mesh_tools:\n  ros__parameters:\n    service_name: /perch/inspect_mesh\n")
    running = subprocess.Popen(PERCH + ["launch", "--config", str(config), "--log-dir", str(tmp_path / "logs")],
                               env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 60
        log = tmp_path / "logs" / "perch_mesh_tools.log"
        while not (log.is_file() and "serving" in log.read_text()) and time.monotonic() < deadline:
            time.sleep(0.2)
        done = _plan(tmp_path / "out", env=env)
        assert done.returncode == 0, done.stderr[-3000:]
        domain = current_domain(env)
        assert "free domain" not in done.stderr and f"domain {domain}" not in done.stderr, done.stderr[-2000:]
        # --no-launch uses the running graph, which has no coordinator: a clear error, no nodes started.
        refused = _plan(tmp_path / "out2", "--no-launch", env=env, timeout=120)
        assert refused.returncode == 1 and "no mission coordinator" in refused.stderr, refused.stderr[-2000:]
        assert running.poll() is None, "the running graph was disturbed"
    finally:
        running.send_signal(signal.SIGINT)
        running.communicate(timeout=30)


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGHUP])
def test_sigterm_and_sighup_stop_the_nodes_plan_started(tmp_path, signum):
    import psutil

    proc = subprocess.Popen(PERCH + PLAN + ["-o", str(tmp_path), "--graph-mode", "per-node"], env=_env(),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 120
        children = []
        while len(children) < 5 and time.monotonic() < deadline:
            children = psutil.Process(proc.pid).children()
            time.sleep(0.2)
        assert len(children) == 5, f"perch plan started {len(children)} node processes"
        time.sleep(2.0)
        proc.send_signal(signum)
        out, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode != 0
    gone, alive = psutil.wait_procs(children, timeout=15)
    assert not alive, f"{len(alive)} node process(es) outlived perch plan after {signal.Signals(signum).name}"
    assert "Traceback" not in err, err[-3000:]
