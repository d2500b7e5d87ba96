"""`perch launch`: start the graph's node processes from config/perch.yaml, stop them on Ctrl-C.

A node runs when it is listed in the parameter file AND its package registers it in the
entry-point group `perch.nodes` (name = node name = package name). Each node is its own
process: `python -m <module> --ros-args --params-file FILE [-r __ns:=/N] [-p name:=value ...]`.
With a namespace every node (and its relative `perch/...` names) lives under /N, so two graphs
run side by side on one domain.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from importlib.metadata import entry_points
from pathlib import Path

from perch_common import namespace as ros_namespace
from perch_common.config import ConfigError, default_config_path, node_names
from perch_common.data import repo_root
from perch_common.processes import stop_process


def fast_liveliness_profile() -> Path:
    """config/fastdds.xml: a process that dies unannounced leaves the graph in ~3 s, not ~20 s."""
    return repo_root() / "config" / "fastdds.xml"


def use_fast_liveliness(env: dict | None = None) -> dict:
    """Apply the Fast DDS profile to `env` (default: this process; call before rclpy.init).

    A FASTRTPS_DEFAULT_PROFILES_FILE the user already set is kept.
    """
    target = os.environ if env is None else env
    if fast_liveliness_profile().is_file():
        target.setdefault("FASTRTPS_DEFAULT_PROFILES_FILE", str(fast_liveliness_profile()))
    return target


def available_nodes() -> dict[str, str]:
    """Registered node name -> module to run with `python -m`."""
    return {ep.name: ep.value.split(":")[0] for ep in entry_points(group="perch.nodes")}


@dataclass(frozen=True)
class GraphNode:
    """One node of the graph as `ros2 launch` starts it: package, executable and node name."""

    package: str
    executable: str
    name: str


def graph_nodes(config: Path | str | None = None) -> list[GraphNode]:
    """The nodes `perch launch` starts for a parameter file (listed there and installed), in file order.

    Used by launch/perch.launch.py; a node's executable is the console script `<node>_node` of
    the package that registers it.
    """
    registered = available_nodes()
    return [GraphNode(registered[name].split(".")[0], f"{name}_node", name)
            for name in node_names(Path(config) if config else default_config_path()) if name in registered]


def parse_overrides(overrides: list[str] | tuple[str, ...]) -> dict[str, list[str]]:
    """`node:param:=value` (or `param:=value` for every node) into per-node `-p` arguments."""
    per_node: dict[str, list[str]] = {}
    for item in overrides:
        if ":=" not in item:
            raise ConfigError(f"override '{item}': use node:param:=value or param:=value")
        lhs, value = item.split(":=", 1)
        node, _, param = lhs.rpartition(":")
        per_node.setdefault(node or "*", []).append(f"{param}:={value}")
    return per_node


class GraphProcesses:
    """The node processes of one graph; a context manager that stops them all on exit."""

    def __init__(self, config: Path | None = None, nodes: list[str] | None = None,
                 overrides: list[str] | tuple[str, ...] = (), log_dir: Path | None = None,
                 env: dict[str, str] | None = None, namespace: str | None = None):
        self.config = Path(config) if config else default_config_path()
        registered = available_nodes()
        listed = [n for n in node_names(self.config) if n in registered]
        if nodes is not None:
            unknown = [n for n in nodes if n not in registered]
            if unknown:
                raise ConfigError(f"unknown node(s) {', '.join(unknown)}; installed: {', '.join(sorted(registered))}")
            listed = [n for n in nodes]
        self.nodes = listed
        self.modules = {n: registered[n] for n in listed}
        self.overrides = parse_overrides(overrides)
        self.log_dir = Path(log_dir) if log_dir else None
        self.env = dict(os.environ if env is None else env)
        self.env.setdefault("OMP_NUM_THREADS", "2")
        self.env.setdefault("OPENBLAS_NUM_THREADS", "1")
        use_fast_liveliness(self.env)
        self.namespace = ros_namespace.current(self.env) if namespace is None else ros_namespace.normalise(namespace)
        if self.namespace:
            self.env[ros_namespace.NAMESPACE_ENV] = self.namespace
        self.processes: dict[str, subprocess.Popen] = {}

    def command(self, name: str) -> list[str]:
        cmd = [sys.executable, "-m", self.modules[name], "--ros-args", "--params-file", str(self.config),
               *ros_namespace.ros_arguments(self.namespace)]
        # `-p param:=v` applies to every node and loses to the node's own section of the
        # parameter file; `-p node:param:=v` is node-specific and wins.
        for param in self.overrides.get("*", []) + self.overrides.get(name, []):
            cmd += ["-p", f"{name}:{param}"]
        return cmd

    def start_node(self, name: str) -> subprocess.Popen:
        out = subprocess.DEVNULL
        if self.log_dir:
            self.log_dir.mkdir(parents=True, exist_ok=True)
            out = open(self.log_dir / f"{name}.log", "ab")
        proc = subprocess.Popen(self.command(name), env=self.env, stdout=out,
                                stderr=subprocess.STDOUT if self.log_dir else None)
        self.processes[name] = proc
        return proc

    def start(self) -> "GraphProcesses":
        for name in self.nodes:
            self.start_node(name)
        return self

    def alive(self) -> dict[str, bool]:
        return {name: proc.poll() is None for name, proc in self.processes.items()}

    def stop_node(self, name: str, timeout: float = 10.0) -> None:
        proc = self.processes.get(name)
        if proc is not None:
            stop_process(proc, timeout)

    def restart(self, name: str) -> subprocess.Popen:
        self.stop_node(name)
        return self.start_node(name)

    def stop(self) -> None:
        for name in list(self.processes):
            proc = self.processes[name]
            if proc.poll() is None:
                proc.send_signal(signal.SIGINT)
        deadline = time.monotonic() + 10
        for proc in self.processes.values():
            try:
                proc.wait(max(0.1, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()

    def wait_for_services(self, node, names: list[str], timeout: float = 30.0) -> list[str]:
        """Wait until every service name is offered (by any process); return those still missing."""
        deadline = time.monotonic() + timeout
        missing = list(names)
        while missing and time.monotonic() < deadline:
            offered = {n for n, _ in node.get_service_names_and_types()}
            missing = [n for n in missing if n not in offered]
            if missing:
                dead = [n for n, ok in self.alive().items() if not ok]
                if dead:
                    raise RuntimeError(f"node process(es) exited during start-up: {', '.join(dead)}")
                time.sleep(0.2)
        return missing

    def __enter__(self) -> "GraphProcesses":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()


def register(sub) -> None:
    p = sub.add_parser("launch", help="start the Perch node graph (Ctrl-C stops it)")
    p.add_argument("--config", type=Path, help="parameter file (default: config/perch.yaml)")
    p.add_argument("--nodes", help="comma-separated subset of nodes to start")
    p.add_argument("-p", "--param", action="append", default=[], metavar="NODE:PARAM:=VALUE",
                   help="override a parameter (repeatable); omit NODE: for all nodes")
    p.add_argument("--log-dir", type=Path, help="write each node's output to LOG_DIR/NODE.log")
    p.add_argument("--namespace", dest="launch_namespace", metavar="NS",
                   help="run the graph in ROS namespace NS (its names become /NS/perch/...); clients then "
                        "need `perch --namespace NS ...`")
    p.add_argument("--list", action="store_true", help="list the nodes that would start and exit")
    p.add_argument("--up", default=None, metavar="AXIS",
                   help="up axis of meshes given to missions that name none: auto, +z, -y, 'X Y Z' "
                        "(perch_operator input_up_axis; default from the config: auto)")
    p.set_defaults(func=_run)


def _run(args) -> int:
    overrides = list(args.param)
    if args.up is not None:
        from perch_common.transforms import parse_up_axis

        if args.up.strip().lower() != "auto":
            parse_up_axis(args.up)  # a malformed axis fails before anything starts
        overrides.append(f"perch_operator:input_up_axis:={args.up}")
    graph = GraphProcesses(args.config, args.nodes.split(",") if args.nodes else None, overrides, args.log_dir,
                           namespace=args.launch_namespace)
    if args.list or not graph.nodes:
        for name in graph.nodes:
            print(f"{name}: {' '.join(graph.command(name))}")
        if not graph.nodes:
            print(f"no installed node is listed in {graph.config}")
        return 0
    where = f" in namespace {graph.namespace}" if graph.namespace else ""
    print(f"perch launch: starting {', '.join(graph.nodes)}{where} (Ctrl-C to stop)")
    stopping = False

    def on_signal(signum, frame):
        nonlocal stopping
        stopping = True

    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGTERM, on_signal)
    with graph:
        while not stopping:
            dead = [n for n, ok in graph.alive().items() if not ok]
            if dead:
                print(f"perch launch: node(s) exited: {', '.join(dead)}; stopping the graph", file=sys.stderr)
                return 1
            time.sleep(0.5)
    print("perch launch: stopped")
    return 0
