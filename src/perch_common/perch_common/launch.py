"""`perch launch`: start the graph's nodes from config/perch.yaml, restart any that die, stop on Ctrl-C.

A node runs when it is listed in the parameter file AND its package registers it in the
entry-point group `perch.nodes` (name = node name = package name). Two ways to host them:

* per-node (the default of `perch launch`): each node is its own process,
  `python -m <module> --ros-args --params-file FILE [-r __ns:=/N] [-p node:name:=value ...]`,
  for distributed use;
* one-process (the default of `perch plan`/`demo`): every node in one process on one executor,
  the way a ROS 2 component container hosts components (`perch_common.ros.container`).

With a namespace every node (and its relative `perch/...` names) lives under /N, so two graphs
run side by side on one domain. Either way the graph talks on this host only (config/fastdds.xml)
unless `--network` or PERCH_NETWORK=1 opens it.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field
from importlib.metadata import entry_points
from pathlib import Path

from perch_common import namespace as ros_namespace
from perch_common.config import ConfigError, check_overrides, default_config_path, node_names
from perch_common.data import repo_root
from perch_common.processes import child_environment, clean_dead_shm, stop_process
from perch_common.ros.servers import server_endpoints
from perch_common.threads import thread_environment

NETWORK_ENV = "PERCH_NETWORK"          # 1/true/yes: let the graph use every network interface
USE_XML_QOS_ENV = "RMW_FASTRTPS_USE_QOS_FROM_XML"   # 1: rmw_fastrtps applies the XML profiles' memory policy
GRAPH_MODES = ("per-node", "one-process")
CONTAINER = "perch_container"           # process name of a one-process graph
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
# The coordinator lives for many missions: with pymalloc its RSS crept ~0.4 MB a mission in 1 MiB
# arenas that a few surviving objects keep (Python's live objects stayed flat); glibc's malloc gives
# the memory back at each release_memory. A PYTHONMALLOC the user set is kept.
NODE_ENVIRONMENT = {"perch_operator": {"PYTHONMALLOC": "malloc"}}


def dds_profile(network: bool = False) -> Path:
    """config/fastdds.xml (loopback UDP) or config/fastdds_network.xml (UDP on all interfaces), from
    the source tree or the installation's share/perch_operator/config."""
    from perch_common.config import config_file

    name = "fastdds_network.xml" if network else "fastdds.xml"
    return config_file(name) or repo_root() / "config" / name


def network_requested(env: dict | None = None) -> bool:
    """True when PERCH_NETWORK asks for a graph reachable from other hosts."""
    value = (os.environ if env is None else env).get(NETWORK_ENV, "")
    return value.strip().lower() in ("1", "true", "yes", "on")


def use_perch_dds(env: dict | None = None, network: bool | None = None) -> dict:
    """Apply Perch's Fast DDS settings to `env` (default: this process; call before rclpy.init).

    Local (default): config/fastdds.xml (loopback UDP, no shared memory, unicast peers on 127.0.0.1)
    with ROS_AUTOMATIC_DISCOVERY_RANGE=SYSTEM_DEFAULT, because rmw_fastrtps's LOCALHOST range would
    replace the profile's transports with ones bound to every interface. A profile of the user's
    own (FASTRTPS_DEFAULT_PROFILES_FILE already set) is kept, with the user's range (else LOCALHOST).
    Network (`network=True` or PERCH_NETWORK=1): config/fastdds_network.xml, discovery range left
    to the user. Both profiles drop a process that died unannounced after ~3 s, not ~20 s, and free
    each message's buffers with it (RMW_FASTRTPS_USE_QOS_FROM_XML=1 makes rmw_fastrtps apply that).

    What the user set is honoured or refused, never widened (discovery_conflict): ROS_LOCALHOST_ONLY=1
    and the LOCALHOST range are what the local profile does (on loopback only, stricter than
    rmw_fastrtps's own LOCALHOST transports); OFF, or SUBNET without --network, and a host-only
    setting with --network, raise ConfigError naming the setting and the fix.
    """
    target = os.environ if env is None else env
    network = network_requested(target) if network is None else network
    conflict = discovery_conflict(target, network)
    if conflict:
        raise ConfigError(conflict)
    profile = dds_profile(network)
    if profile.is_file():
        target.setdefault("FASTRTPS_DEFAULT_PROFILES_FILE", str(profile))
    if _ours(target):
        # rmw_fastrtps then takes the profiles' history memory policy (buffers freed with their
        # samples) instead of its own, which keeps the largest message's buffers for good.
        target.setdefault(USE_XML_QOS_ENV, "1")
    if network:
        _check_network_key(target)
        target[NETWORK_ENV] = "1"   # child processes (respawned nodes) stay networked too
        if target.get("ROS_AUTOMATIC_DISCOVERY_RANGE") == "SYSTEM_DEFAULT" and _ours(target):
            target.pop("ROS_AUTOMATIC_DISCOVERY_RANGE")
    elif target["FASTRTPS_DEFAULT_PROFILES_FILE"] == str(profile):
        # the loopback profile is the host-only setting: rmw's own (LOCALHOST_ONLY, LOCALHOST range)
        # would swap its transports for ones bound to every interface
        if target.get("ROS_LOCALHOST_ONLY") == "1":
            target.pop("ROS_LOCALHOST_ONLY")
        target["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "SYSTEM_DEFAULT"
    else:
        target.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    return target


def _check_network_key(env: dict) -> None:
    """A networked graph signs its commands with the shared key (perch_common.network_auth): one that cannot
    be used is refused before anything starts (the graph started, and every mission failed with no reason)."""
    from perch_common.network_auth import AuthError, key_path, load_key

    try:
        load_key(key_path(env))
    except (OSError, AuthError) as exc:
        raise ConfigError(f"--network needs the graph's key: {exc}") from None


def discovery_conflict(env: dict, network: bool) -> str:
    """Why the user's ROS_LOCALHOST_ONLY / ROS_AUTOMATIC_DISCOVERY_RANGE cannot be honoured ('' if they can)."""
    only = env.get("ROS_LOCALHOST_ONLY", "").strip()
    wanted = env.get("ROS_AUTOMATIC_DISCOVERY_RANGE", "").strip().upper()
    if network:
        if only == "1":
            return ("ROS_LOCALHOST_ONLY=1 keeps ROS on this host but --network (PERCH_NETWORK=1) opens the graph "
                    "to other hosts: unset one of them")
        if wanted in ("LOCALHOST", "OFF"):
            return (f"ROS_AUTOMATIC_DISCOVERY_RANGE={wanted} keeps ROS on this host but --network (PERCH_NETWORK=1) "
                    "opens the graph to other hosts: unset one of them")
        return ""
    if wanted == "OFF":
        return ("ROS_AUTOMATIC_DISCOVERY_RANGE=OFF turns discovery off, so Perch's processes could not find each "
                "other; unset it (Perch keeps its graph on this host by default)")
    if wanted == "SUBNET":
        return ("ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET asks for a graph reachable from the subnet, but Perch keeps "
                "its graph on this host unless --network (or PERCH_NETWORK=1): pass that, or unset it")
    return ""


def _ours(env: dict) -> bool:
    return env.get("FASTRTPS_DEFAULT_PROFILES_FILE") in (str(dds_profile(False)), str(dds_profile(True)))


# Fast DDS's well-known UDP ports (RTPS spec 9.6.1.1): domain d owns 7400 + 250 d ... + 249.
_PORT_BASE, _DOMAIN_GAIN = 7400, 250
DOMAIN_RANGES = (range(0, 102), range(215, 233))   # domain ids ROS 2 allows on Linux


def domain_ports(domain: int) -> range:
    """The UDP ports a participant on `domain` binds for discovery and user traffic."""
    start = _PORT_BASE + _DOMAIN_GAIN * domain
    return range(start, start + _DOMAIN_GAIN)


def domains_in_use() -> set[int]:
    """Domains some process on this host takes part in, from /proc/net/udp.

    A participant binds its domain's SPDP multicast port (7400 + 250 d) unless multicast is off,
    and the first participant of a domain on a host binds 7400 + 250 d + 10 (participant 0's
    discovery unicast port). Only these exact ports count: random sending ports may fall anywhere
    in a higher domain's range.
    """
    import psutil

    used = set()
    for conn in psutil.net_connections(kind="udp"):
        port = conn.laddr.port if conn.laddr else 0
        domain, offset = divmod(port - _PORT_BASE, _DOMAIN_GAIN)
        if port >= _PORT_BASE and offset in (0, 10):
            used.add(domain)
    return used


def current_domain(env: dict | None = None) -> int:
    """ROS_DOMAIN_ID of `env` (default 0)."""
    value = (os.environ if env is None else env).get("ROS_DOMAIN_ID", "").strip()
    try:
        return int(value) if value else 0
    except ValueError:
        raise ConfigError(f"ROS_DOMAIN_ID={value!r} is not a number; set it to 0-101 or unset it") from None


def free_domain(avoid: set[int] | None = None) -> int | None:
    """A domain id no process on this host uses (and not in `avoid`); None when all are taken."""
    taken = domains_in_use() | (avoid or set())
    for ids in DOMAIN_RANGES:
        for domain in ids:
            if domain not in taken:
                return domain
    return None


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


def ros_arguments(config: Path, nodes: list[str], overrides: dict[str, list[str]], namespace: str = "") -> list[str]:
    """`--ros-args --params-file CONFIG [-r __ns:=/N] -p node:param:=value ...` for the given nodes.

    In a namespace, rcl matches a file's bare `NAME:` key and `-p NAME:param:=v` to `/NAME` only, so
    both would be ignored without a word; there the same parameters go in a second file under
    `/**/NAME` (every namespace), the overrides in a third, which wins."""
    args = ["--ros-args", "--params-file", str(config), *ros_namespace.ros_arguments(namespace)]
    if namespace:
        return args + [a for path in namespaced_parameter_files(config, nodes, overrides)
                       for a in ("--params-file", str(path))]
    # `-p param:=v` would apply to every node and lose to the node's own section of the
    # parameter file; `-p node:param:=v` is node-specific and wins.
    for name in nodes:
        for param in overrides.get("*", []) + overrides.get(name, []):
            args += ["-p", f"{name}:{param}"]
    return args


def namespaced_parameter_files(config: Path, nodes: list[str], overrides: dict[str, list[str]]) -> list[Path]:
    """The config's bare node sections re-keyed `/**/NAME`, then the -p overrides likewise: two
    parameter files that apply in any namespace (written once per content, kept for respawns)."""
    import hashlib
    import tempfile

    import yaml

    from perch_common.config import load_yaml

    sections = {f"/**/{key}": value for key, value in load_yaml(config).items() if "/" not in str(key)}
    forced: dict[str, dict] = {}
    for name in nodes:
        for item in overrides.get("*", []) + overrides.get(name, []):
            param, _, text = item.partition(":=")
            forced.setdefault(f"/**/{name}", {"ros__parameters": {}})["ros__parameters"][param] = yaml.safe_load(text)
    folder = Path(tempfile.gettempdir()) / f"perch-{os.getuid()}"
    folder.mkdir(mode=0o700, exist_ok=True)
    paths = []
    for part in (sections, forced):
        text = yaml.safe_dump(part, sort_keys=False)
        path = folder / f"params-{hashlib.sha256(text.encode()).hexdigest()[:16]}.yaml"
        if not path.exists():
            tmp = path.with_suffix(f".{os.getpid()}.tmp")
            tmp.write_text(text)
            os.replace(tmp, path)
        paths.append(path)
    return paths


@dataclass
class Respawn:
    """Back-off for restarting a node that died: 1 s, 2 s, 4 s ... up to `longest`; a node that ran
    for `stable` seconds before dying starts again from `first`."""

    first: float = 1.0
    longest: float = 30.0
    stable: float = 60.0
    _delay: dict[str, float] = field(default_factory=dict)

    def next_delay(self, name: str, ran_for: float) -> float:
        """Seconds to wait before restarting `name`, which died after running `ran_for` seconds."""
        delay = self.first if ran_for >= self.stable else min(self.longest, self._delay.get(name, self.first / 2) * 2)
        self._delay[name] = delay
        return delay


class GraphProcesses:
    """The node processes of one graph; a context manager that stops them all on exit.

    mode "per-node": one process per node (keys of `processes` are node names);
    mode "one-process": one container process hosting every node (key CONTAINER).
    """

    def __init__(self, config: Path | None = None, nodes: list[str] | None = None,
                 overrides: list[str] | tuple[str, ...] = (), log_dir: Path | None = None,
                 env: dict[str, str] | None = None, namespace: str | None = None, mode: str = "per-node",
                 network: bool | None = None):
        if mode not in GRAPH_MODES:
            raise ConfigError(f"graph mode '{mode}': use one of {', '.join(GRAPH_MODES)}")
        self.config = Path(config) if config else default_config_path()
        registered = available_nodes()
        listed = [n for n in node_names(self.config) if n in registered]
        if nodes is not None:
            unknown = [n for n in nodes if n not in registered]
            if unknown:
                raise ConfigError(f"unknown node(s) {', '.join(unknown)}; installed: {', '.join(sorted(registered))}")
            listed = list(nodes)
        self.nodes = listed
        self.mode = mode
        self.modules = {n: registered[n] for n in listed}
        self.log_dir = Path(log_dir) if log_dir else None
        self.env = dict(os.environ if env is None else env)
        self.env.update(thread_environment(self.env))
        use_perch_dds(self.env, network)
        self.namespace = ros_namespace.current(self.env) if namespace is None else ros_namespace.normalise(namespace)
        # Every -p checked against what its node declares before anything starts (rcl would drop a
        # wrongly typed override silently when the file sets the key, or the node would die on it).
        self.overrides = check_overrides(parse_overrides(overrides), listed, self.config, self.namespace)
        if self.namespace:
            self.env[ros_namespace.NAMESPACE_ENV] = self.namespace
        self.processes: dict[str, subprocess.Popen] = {}
        self.started_at: dict[str, float] = {}

    @property
    def units(self) -> list[str]:
        """Names of the processes this graph runs (nodes, or the one container)."""
        return [CONTAINER] if self.mode == "one-process" and self.nodes else list(self.nodes)

    def command(self, name: str) -> list[str]:
        """The command line of process `name` (a node, or CONTAINER)."""
        if name == CONTAINER:
            return [sys.executable, "-m", "perch_common.ros.container", "--nodes", ",".join(self.nodes),
                    *ros_arguments(self.config, self.nodes, self.overrides, self.namespace)]
        return [sys.executable, "-m", self.modules[name],
                *ros_arguments(self.config, [name], self.overrides, self.namespace)]

    def node_environment(self, name: str) -> dict[str, str]:
        """The environment of process `name`: the graph's, plus NODE_ENVIRONMENT's variables it does not set."""
        return {**NODE_ENVIRONMENT.get(name, {}), **self.env}

    def start_node(self, name: str) -> subprocess.Popen:
        """Start process `name` (its output goes to LOG_DIR/NAME.log when a log folder is set)."""
        out = subprocess.DEVNULL
        if self.log_dir:
            self.log_dir.mkdir(parents=True, exist_ok=True)
            out = open(self.log_dir / f"{name}.log", "ab")
        # the node dies with this process, however it ends (perch_common.processes.die_with_parent)
        proc = subprocess.Popen(self.command(name), env=child_environment(self.node_environment(name)), stdout=out,
                                stderr=subprocess.STDOUT if self.log_dir else None)
        self.processes[name] = proc
        self.started_at[name] = time.monotonic()
        return proc

    def start(self) -> "GraphProcesses":
        """Start every process of the graph (first clearing the shared memory killed processes left)."""
        clean_dead_shm()
        for name in self.units:
            self.start_node(name)
        return self

    def alive(self) -> dict[str, bool]:
        """Process name -> still running."""
        return {name: proc.poll() is None for name, proc in self.processes.items()}

    def stop_node(self, name: str, timeout: float = 10.0) -> None:
        """Stop one process like Ctrl-C would (SIGKILL after `timeout`)."""
        proc = self.processes.get(name)
        if proc is not None:
            stop_process(proc, timeout)

    def stop(self) -> None:
        """SIGINT to every process, SIGKILL to any still running after 10 s."""
        for proc in self.processes.values():
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
            missing = [n for n in missing if not server_endpoints(node, n)]   # servers only, not clients
            if missing:
                dead = [n for n, ok in self.alive().items() if not ok]
                if dead:
                    raise RuntimeError(f"node process(es) exited during start-up: {', '.join(dead)}")
                time.sleep(0.1)
        return missing

    def __enter__(self) -> "GraphProcesses":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()


def add_graph_arguments(p, default_mode: str) -> None:
    """--graph-mode and --network, shared by every command that starts nodes."""
    p.add_argument("--graph-mode", choices=GRAPH_MODES, default=default_mode,
                   help=f"host the nodes in one process or one process per node (default: {default_mode})")
    p.add_argument("--network", action="store_true",
                   help=f"let the nodes use every network interface (default: this host only; or {NETWORK_ENV}=1)")


def register(sub) -> None:
    """The `perch launch` command."""
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
    p.add_argument("--no-respawn", action="store_true",
                   help="stop the whole graph when a node dies (default: restart it with back-off)")
    add_graph_arguments(p, "per-node")
    p.set_defaults(func=_run)


DDS_ENV = ("FASTRTPS_DEFAULT_PROFILES_FILE", "ROS_AUTOMATIC_DISCOVERY_RANGE", "ROS_LOCALHOST_ONLY",
           "RMW_FASTRTPS_USE_QOS_FROM_XML", "ROS_STATIC_PEERS", "RMW_IMPLEMENTATION")


def running_graph(graph: GraphProcesses, wait: float = 2.0) -> list[str]:
    """The services of `graph`'s nodes that some process already offers on its domain and namespace.

    Only looked for when a process on this host takes part in the domain (its discovery port is
    bound); discovery on loopback then lists a running graph's services within `wait` seconds."""
    from perch_common.conventions import NODE_SERVICES

    domain = current_domain(graph.env)
    if domain not in domains_in_use():
        return []
    import rclpy
    from rclpy.context import Context

    for key in DDS_ENV:   # the graph's own transport settings, so that the probe sees what its nodes would
        if key in graph.env:
            os.environ[key] = graph.env[key]
    names = [f"{graph.namespace}/{service}" for n in graph.nodes for service in NODE_SERVICES.get(n, [])[:1]]
    context = Context()
    rclpy.init(args=[], context=context, domain_id=domain)
    try:
        node = rclpy.create_node("perch_launch_probe", context=context, start_parameter_services=False)
        deadline = time.monotonic() + wait
        while True:
            found = [name for name in names if server_endpoints(node, name)]   # servers only, not clients
            if found or time.monotonic() > deadline:
                node.destroy_node()
                return found
            time.sleep(0.1)
    finally:
        rclpy.try_shutdown(context=context)


CONFIG_EXIT = 2   # perch_common.ros.node_main.run_node: the node stopped on a bad parameter


def config_reason(graph: GraphProcesses, name: str) -> str:
    """': <the error line>' from the node's log (its last `error:` line), '' without a log."""
    if graph.log_dir is None or not (graph.log_dir / f"{name}.log").is_file():
        return ""
    lines = [line for line in (graph.log_dir / f"{name}.log").read_text(errors="replace").splitlines()
             if line.startswith("error:")]
    return f": {lines[-1].removeprefix('error:').strip()}" if lines else ""


def _run(args) -> int:
    overrides = list(args.param)
    if args.up is not None:
        from perch_common.transforms import parse_up_axis

        if args.up.strip().lower() != "auto":
            parse_up_axis(args.up)  # a malformed axis fails before anything starts
        overrides.append(f"perch_operator:input_up_axis:={args.up}")
    nodes = [n.strip() for n in args.nodes.split(",") if n.strip()] if args.nodes is not None else None
    if nodes == []:
        raise ConfigError(f"--nodes {args.nodes!r} names no node; give them comma-separated (perch launch --list "
                          "shows them), or leave --nodes out to start all")
    graph = GraphProcesses(args.config, nodes, overrides, args.log_dir,
                           namespace=args.launch_namespace, mode=args.graph_mode, network=args.network or None)
    if args.list or not graph.nodes:
        for name in graph.units:
            print(f"{name}: {' '.join(graph.command(name))}")
        if not graph.nodes:
            print(f"no installed node is listed in {graph.config}")
        return 0
    where = f" in namespace {graph.namespace}" if graph.namespace else ""
    running = running_graph(graph)
    if running:
        print(f"perch launch: a Perch graph already runs on ROS domain {current_domain(graph.env)}{where} (it offers "
              f"{', '.join(running)}); not starting a second one. Stop it first, or give this one another "
              "ROS_DOMAIN_ID or --namespace", file=sys.stderr, flush=True)
        return 1
    reach = "every network interface" if network_requested(graph.env) else "this host only"
    print(f"perch launch: starting {', '.join(graph.nodes)}{where} ({args.graph_mode}, domain "
          f"{current_domain(graph.env)}, {reach}; Ctrl-C to stop)", flush=True)
    stopping = False

    def on_signal(signum, frame):
        nonlocal stopping
        stopping = True

    for signum in STOP_SIGNALS:
        signal.signal(signum, on_signal)
    respawn = Respawn()
    pending: dict[str, float] = {}   # process name -> when to start it again
    with graph:
        while not stopping:
            now = time.monotonic()
            for name, ok in graph.alive().items():
                if ok or name in pending:
                    continue
                code = graph.processes[name].returncode
                if code == CONFIG_EXIT:   # restarting cannot help: the same parameters fail the same way
                    print(f"perch launch: {name} refused its parameters (exit code {code}"
                          f"{config_reason(graph, name)}); not restarting it, stopping the graph; fix the "
                          "parameter and launch again", file=sys.stderr, flush=True)
                    return 1
                if args.no_respawn:
                    print(f"perch launch: {name} exited (code {code}); stopping the graph", file=sys.stderr)
                    return 1
                delay = respawn.next_delay(name, now - graph.started_at[name])
                print(f"perch launch: {name} exited (code {code}); restarting it in {delay:.0f} s",
                      file=sys.stderr, flush=True)
                pending[name] = now + delay
            for name, when in list(pending.items()):
                if now >= when and not stopping:
                    graph.start_node(name)
                    del pending[name]
                    print(f"perch launch: {name} restarted", file=sys.stderr, flush=True)
            time.sleep(0.2)
    print("perch launch: stopped")
    return 0
