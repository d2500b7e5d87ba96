"""The whole node graph as separate processes, shared by the end-to-end tests of one module."""

from __future__ import annotations

import importlib.util
import threading
import time
from pathlib import Path
from types import SimpleNamespace

import pytest
import yaml

STAGE_NODES = ("perch_operator", "perch_reconstruction", "perch_segmentation", "perch_filtering", "perch_placement")
MAIN_SERVICES = {"perch_operator": "/perch/crop", "perch_reconstruction": "/perch/clean_mesh",
                 "perch_segmentation": "/perch/segment", "perch_filtering": "/perch/filter",
                 "perch_placement": "/perch/optimise"}


def missing_nodes() -> list[str]:
    """Stage nodes with no installed `perch.nodes` entry point (or whose module cannot be found)."""
    from importlib.metadata import entry_points

    installed = {e.name: e.value.split(":")[0] for e in entry_points(group="perch.nodes")}
    return [n for n in STAGE_NODES if n not in installed or importlib.util.find_spec(installed[n]) is None]


def write_config(path: Path, changes: dict[str, dict] | None = None) -> Path:
    """config/perch.yaml with per-node parameter changes {node: {param: value}} (dotted = nested)."""
    from perch_common.config import default_config_path

    data = yaml.safe_load(default_config_path().read_text())
    for node, params in (changes or {}).items():
        section = data.setdefault(node, {}).setdefault("ros__parameters", {})
        for key, value in params.items():
            *parents, leaf = key.split(".")
            target = section
            for p in parents:
                target = target.setdefault(p, {})
            target[leaf] = value
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


@pytest.fixture
def graph_parts():
    """What a test starting its own graphs needs: the stage nodes, what is missing, the config writer."""
    return SimpleNamespace(stage_nodes=STAGE_NODES, missing=missing_nodes(), write_config=write_config)


@pytest.fixture(scope="module")
def graph(tmp_path_factory, request):
    """Every stage node as its own process on an isolated domain, and a client node spun in a thread.
    A test module's GRAPH_CHANGES ({node: {param: value}}) are added to the graph's config."""
    missing = missing_nodes()
    if missing:
        pytest.skip(f"stage node(s) not installed yet: {', '.join(missing)}")
    from perch_common.ros import testing

    testing.use_isolated_ros_env()  # includes the Fast DDS profile: a killed stage leaves in ~3 s
    import rclpy

    from perch_common.launch import GraphProcesses

    tmp = tmp_path_factory.mktemp("graph")
    changes = {"perch_operator": {"service_wait": 3.0, "gone_grace": 1.0}}
    for node, params in getattr(request.module, "GRAPH_CHANGES", {}).items():
        changes.setdefault(node, {}).update(params)
    config = write_config(tmp / "perch.yaml", changes)
    rclpy.init()
    processes = GraphProcesses(config, list(STAGE_NODES), log_dir=tmp / "logs")
    processes.start()
    node = rclpy.create_node("e2e_client")
    try:
        missing_services = processes.wait_for_services(node, list(MAIN_SERVICES.values()), timeout=120)
        assert not missing_services, f"services did not start: {missing_services}; logs in {tmp / 'logs'}"
        yield SimpleNamespace(processes=processes, node=node, config=config, tmp=tmp, spinner=Spinner,
                              wait_back=lambda name: wait_gone_and_back(node, MAIN_SERVICES[name]))
    finally:
        processes.stop()
        node.destroy_node()
        rclpy.try_shutdown()


def wait_service(node, name: str, timeout: float = 60.0) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if name in {n for n, _ in node.get_service_names_and_types()}:
            return
        time.sleep(0.2)
    raise TimeoutError(f"{name} did not come back within {timeout:.0f} s")


class Spinner:
    """Spin a node in a background thread (for tests that block on other things meanwhile)."""

    def __init__(self, node):
        from rclpy.executors import SingleThreadedExecutor

        from perch_common.ros.spinning import keep_spinning

        self.executor = SingleThreadedExecutor()
        self.executor.add_node(node)
        self.thread = threading.Thread(target=keep_spinning, args=(self.executor,), daemon=True)

    def __enter__(self):
        self.thread.start()
        return self

    def __exit__(self, *exc):
        self.executor.shutdown()
        self.thread.join(5)


@pytest.fixture
def restart_with(graph, tmp_path):
    """`with restart_with(node, {param: value}):` runs that node with changed parameters, then the original."""
    import contextlib

    from perch_common.launch import GraphProcesses

    @contextlib.contextmanager
    def run(name: str, params: dict):
        config = write_config(tmp_path / f"{name}.yaml", {name: params})
        graph.processes.stop_node(name)
        changed = GraphProcesses(config, [name], log_dir=graph.tmp / "logs_changed")
        changed.start()
        try:
            wait_gone_and_back(graph.node, MAIN_SERVICES[name])
            yield changed
        finally:
            changed.stop()
            graph.processes.start_node(name)
            wait_gone_and_back(graph.node, MAIN_SERVICES[name])

    return run


def wait_gone_and_back(node, service: str, timeout: float = 60.0) -> None:
    """Wait until `service` is offered again, plus a moment for the graph to settle."""
    wait_service(node, service, timeout)
    time.sleep(0.5)


@pytest.fixture
def client_node(request):
    """An rclpy node on an isolated domain for a test that starts its own graph ("<module>_client",
    e.g. faults_client for test_faults); rclpy is shut down afterwards."""
    from perch_common.ros import testing

    testing.use_isolated_ros_env()
    import rclpy

    rclpy.init()
    node = rclpy.create_node(f"{request.module.__name__.rsplit('.', 1)[-1].removeprefix('test_')}_client")
    try:
        yield node
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


@pytest.fixture
def wait_for():
    """`wait_for(condition, timeout, what)`: testing.poll_until, for tests that wait on the graph."""
    from perch_common.ros.testing import poll_until

    return poll_until
