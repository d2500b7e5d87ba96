"""Run one recorded mission from the command line and write its outputs.

Used by `perch plan` and `perch demo`: start the mission's own graph (in this process by default,
or as node processes) on a domain no other graph uses, record the mission to run.mcap in a staging
folder, then write waypoints.yaml, run.rrd and report.html from the mission result (the recording
adds the stage replies) and move them into the output folder together. `--no-launch` uses the
graph already running instead.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from perch_common.conventions import NODE_SERVICES
from perch_common.errors import PerchError
from perch_common.outputs import (
    check_writable_folder,
    publish_output,
    remove_outputs,
    replace_outputs,
    staging_folder,
    written_by_perch,
)
from perch_common.ros.servers import server_endpoints
from perch_interfaces.action import PlanPerches
from perch_operator.coordinator.stages import STAGES
from perch_operator.outputs.recorder import EVENT_SUFFIX, MISSION_TOPICS, MissionRecorder


@dataclass
class PlanOutputs:
    """A mission's result and where its outputs are (or are staged until `write_outputs`)."""

    result: PlanPerches.Result
    out_dir: Path
    mcap: Path
    rrd: Path | None = None
    report: Path | None = None
    waypoints: Path | None = None
    mission_seconds: float = 0.0
    staged: Path | None = None          # staging folder until the outputs are moved into out_dir
    goal: PlanPerches.Goal | None = None
    removals: str = ""                  # text table: area each filter removed on the largest surfaces
    coordinates: str = ""               # how waypoints relate to a mesh file loaded with --scale/--shift
    perches: str = ""                   # text: each accepted perch with its safety evidence
    waypoints_at: float | None = None   # time.time() when waypoints.yaml was in out_dir
    result_seconds: float = 0.0         # goal sent to result received (mission_seconds adds the recording's tail)


@contextlib.contextmanager
def client_context(ros_args: list[str] | None = None, domain_id: int | None = None):
    """rclpy for a command-line client: Ctrl-C, SIGTERM and SIGHUP raise KeyboardInterrupt in Python
    (not a silent context shutdown), so a mission can be cancelled, its recording closed and the
    nodes it started stopped. `ros_args` (`--ros-args ...`) configure nodes hosted in this process."""
    import rclpy
    from rclpy.signals import SignalHandlerOptions

    from perch_common import namespace
    from perch_common.launch import use_perch_dds
    from perch_common.processes import clean_dead_shm

    use_perch_dds()   # every client (operator CLI, record, replay, ...) on Perch's host-only profile unless networked
    clean_dead_shm()  # what killed Perch processes (a SIGKILLed `perch plan`) left in /dev/shm
    previous = {signum: signal.signal(signum, _interrupt) for signum in (signal.SIGTERM, signal.SIGHUP)}
    # Every node of this client process resolves Perch's relative names in the graph's namespace.
    rclpy.init(args=["perch", "--ros-args", *namespace.ros_arguments(namespace.current()), *(ros_args or [])],
               domain_id=domain_id,
               signal_handler_options=SignalHandlerOptions.NO)
    try:
        yield
    finally:
        rclpy.try_shutdown()
        for signum, handler in previous.items():
            signal.signal(signum, handler)


def _interrupt(signum, frame):
    """SIGTERM/SIGHUP end a client the way Ctrl-C does."""
    raise KeyboardInterrupt(signal.Signals(signum).name)


def offered_services(node) -> set[str]:
    """Fully qualified names of the services some server now offers (a name only clients use is not offered)."""
    return {name for name, _ in node.get_service_names_and_types() if server_endpoints(node, name)}


def graph_ros_args(config: Path | None, overrides, log_dir: Path | None) -> list[str]:
    """`--ros-args` for nodes hosted in this process: parameters, and logs into `log_dir` (not the terminal)."""
    import os

    from perch_common import namespace
    from perch_common.config import check_overrides, default_config_path
    from perch_common.launch import parse_overrides, ros_arguments

    config = Path(config) if config else default_config_path()
    # -p checked against the nodes' declarations before any node is created (perch_common.config).
    checked = check_overrides(parse_overrides(overrides), mission_nodes(), config, namespace.current())
    if log_dir is not None:
        log_dir.mkdir(parents=True, exist_ok=True)
        os.environ["ROS_LOG_DIR"] = str(log_dir.resolve())   # read by rclpy.init
    return [*ros_arguments(config, mission_nodes(), checked, namespace.current()), "--disable-stdout-logs"]


def mission_nodes() -> list[str]:
    """The installed nodes a mission needs (NODE_SERVICES), in start order."""
    from perch_common.launch import available_nodes

    registered = available_nodes()
    return [n for n in NODE_SERVICES if n in registered]


def choose_domain(out=sys.stderr) -> int:
    """The user's ROS_DOMAIN_ID, as given: Perch never moves itself to another domain (a viewer or
    bridge on the user's domain must see the mission). Whether a Perch graph already runs there is
    for `existing_perch_graph` to tell once the client node is up."""
    from perch_common.launch import current_domain

    return current_domain()


def existing_perch_graph(node, wait: float = 6.0, settle: float = 1.0) -> tuple[list[str], list[str]]:
    """(services of a Perch mission graph found on this domain and namespace, why it cannot be used).

    Looked for only when some process on this host takes part in the domain. The look ends when
    every mission service is found, or when the graph's node list has not changed for `settle`
    seconds and holds no Perch mission node in this namespace (other tools only), or after `wait`
    seconds (Perch nodes whose services did not all appear). A graph is usable when every mission node's
    service is there with this installation's types: service type names, and the RIHS01 hashes of
    the coordinator's feedback and the stages' introspection events (interfaces changed since it
    started, or another Perch version, would garble every message)."""
    from perch_common.conventions import MISSION_FEEDBACK_TOPIC
    from perch_common.launch import current_domain, domains_in_use
    from perch_common.ros.msgdefs import type_hash
    from perch_operator.coordinator.stages import STAGES
    from perch_operator.outputs.recorder import EVENT_SUFFIX

    if current_domain() not in domains_in_use():
        return [], []
    kinds = {node.resolve_service_name(s.service): f"perch_interfaces/srv/{s.srv_type.__name__}"
             for s in STAGES.values()}
    wanted = [node.resolve_service_name(NODE_SERVICES[n][0]) for n in mission_nodes()]
    ours = set(mission_nodes())
    namespace = node.get_namespace()
    deadline = time.monotonic() + wait
    seen, changed = None, time.monotonic()
    while True:
        offered = dict(node.get_service_names_and_types())
        found = [name for name in wanted if name in offered and server_endpoints(node, name)]
        names = set(node.get_node_names_and_namespaces())
        if names != seen:
            seen, changed = names, time.monotonic()
        perch_here = any(name in ours and ns == namespace for name, ns in names)
        quiet = not found and not perch_here and time.monotonic() - changed >= settle
        if len(found) == len(wanted) or quiet or time.monotonic() > deadline:
            break
        time.sleep(0.1)
    if not found:
        return [], []
    problems = [f"{name} is missing" for name in wanted if name not in found]
    problems += [f"{name} has type {', '.join(offered[name])}, this Perch expects {kinds[name]}"
                 for name in found if name in kinds and kinds[name] not in offered[name]]
    hashed = {node.resolve_topic_name(MISSION_FEEDBACK_TOPIC): "perch_interfaces/action/PlanPerches_FeedbackMessage"}
    hashed.update({name + EVENT_SUFFIX: kinds[name] + "_Event" for name in found if name in kinds})
    for topic, type_name in hashed.items():
        for info in node.get_publishers_info_by_topic(topic):
            theirs, ours = str(info.topic_type_hash), type_hash(type_name)
            if info.topic_type_hash.version > 0 and ours and theirs != ours:
                problems.append(f"{topic} carries {type_name} {theirs[:15]}..., this Perch's is {ours[:15]}... "
                                "(another version of perch_interfaces)")
                break
    return found, problems


@dataclass
class OwnGraph:
    """The graph a command started for itself: nodes in this process (container) or node processes."""

    mode: str
    domain: int
    container: object | None = None      # perch_common.ros.container.NodeContainer
    processes: object | None = None      # perch_common.launch.GraphProcesses
    startup_seconds: float = 0.0

    def pids(self) -> list[int]:
        """Process ids that host the nodes (this process in one-process mode)."""
        import os

        if self.processes is None:
            return [os.getpid()]
        return [p.pid for p in self.processes.processes.values()]

    def stop(self) -> None:
        """Stop every node this graph started."""
        if self.container is not None:
            self.container.stop()
        if self.processes is not None:
            self.processes.stop()


def start_own_graph(node, mode: str, domain: int, config: Path | None = None, overrides=(),
                    log_dir: Path | None = None, timeout: float = 90.0, out=sys.stderr) -> OwnGraph:
    """Start every node a mission needs and wait for their services (nothing of another graph is used).

    one-process: the nodes join this process's rclpy context (created by client_context with
    `ros_arguments(...)`); per-node: child processes on `domain`.
    """
    import os

    from perch_common.launch import GraphProcesses

    started = time.monotonic()
    nodes = mission_nodes()
    graph = OwnGraph(mode, domain)
    try:
        if mode == "one-process":
            from perch_common.ros.container import NodeContainer

            graph.container = NodeContainer(nodes).start()
        else:
            env = dict(os.environ, ROS_DOMAIN_ID=str(domain))
            graph.processes = GraphProcesses(config, nodes, overrides, log_dir, env=env,
                                             namespace=node.get_namespace()).start()
            out.write(f"perch: starting {', '.join(nodes)}" + (f" (logs in {log_dir})" if log_dir else "") + "\n")
        wanted = [node.resolve_service_name(NODE_SERVICES[n][0]) for n in nodes]
        missing = _wait_offered(node, wanted, timeout, graph.processes)
        if missing:
            raise PerchError(f"services {', '.join(missing)} did not appear within {timeout:.0f} s"
                             + (f"; see the logs in {log_dir}" if log_dir and graph.processes else ""))
    except BaseException:
        graph.stop()
        raise
    graph.startup_seconds = time.monotonic() - started
    return graph


def _wait_offered(node, names: list[str], timeout: float, processes=None) -> list[str]:
    """Wait until `node` sees every service; a node process that exits ends the wait with an error."""
    if processes is not None:
        try:
            return processes.wait_for_services(node, names, timeout)
        except RuntimeError as exc:
            raise PerchError(str(exc)) from None
    deadline = time.monotonic() + timeout
    missing = list(names)
    while missing and time.monotonic() < deadline:
        missing = [n for n in missing if n not in offered_services(node)]
        if missing:
            time.sleep(0.02)
    return missing


def ensure_graph(node, config: Path | None = None, overrides=(), log_dir: Path | None = None,
                 settle: float = 2.0, timeout: float = 90.0, out=sys.stderr):
    """Start the nodes whose services are not in the graph; returns the GraphProcesses (or None).

    For `perch replay --launch`, which replays onto whatever graph runs; `perch plan` uses
    start_own_graph instead and never mixes with a running graph.
    """
    from perch_common.launch import GraphProcesses, available_nodes

    resolved = {n: [node.resolve_service_name(s) for s in services] for n, services in NODE_SERVICES.items()}
    deadline = time.monotonic() + settle   # discovery of an already running graph takes a moment
    missing = list(NODE_SERVICES)
    while missing and time.monotonic() < deadline:
        offered = offered_services(node)
        missing = [n for n, services in resolved.items() if not set(services) & offered]
        time.sleep(0.2)
    registered = available_nodes()
    to_start = [n for n in missing if n in registered]
    if not to_start:
        return None
    graph = GraphProcesses(config, to_start, overrides, log_dir, namespace=node.get_namespace())
    out.write(f"perch: starting {', '.join(to_start)}" + (f" (logs in {log_dir})" if log_dir else "") + "\n")
    graph.start()
    wanted = [s for n in to_start for s in resolved[n][:1]]
    try:
        still = graph.wait_for_services(node, wanted, timeout)
    except RuntimeError as exc:
        graph.stop()
        raise PerchError(f"{exc}" + (f"; see {log_dir}" if log_dir else "")) from None
    if still:
        graph.stop()
        raise PerchError(f"services {', '.join(still)} did not appear within {timeout:.0f} s"
                         + (f"; see the logs in {log_dir}" if log_dir else ""))
    return graph


def spin_for(node, seconds: float) -> None:
    """Spin `node` for about `seconds`."""
    import rclpy

    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        rclpy.spin_once(node, timeout_sec=min(0.05, max(0.0, deadline - time.monotonic())))


FAILED_NAME = "FAILED"
FAILED_RECORDING = "failed.mcap"   # a failed mission's recording, beside the last good outputs it left alone
# What a successful mission leaves in its output folder.
GOOD_SET = ("waypoints.yaml", "run.mcap", "run.rrd", "report.html", "report_files")
# Everything a mission writes into its output folder (logs/ of launched nodes is not a mission output).
OUTPUT_NAMES = (*GOOD_SET, FAILED_NAME, FAILED_RECORDING)


def run_recorded_mission(node, goal: PlanPerches.Goal, out_dir: Path, progress: bool = True,
                         timeout: float = 900.0, describe: dict | None = None, out=sys.stderr) -> PlanOutputs:
    """Record the mission into a fresh staging folder beside out_dir; `write_outputs` moves it into place.

    A goal the coordinator rejects leaves nothing behind (GoalRejected); an interrupted or timed-out
    mission leaves out_dir with a FAILED marker and its recording (PerchError).
    """
    from perch_operator.api.client import GoalRejected, ProgressPrinter, run_mission

    check_writable_folder(out_dir)   # before the mission: a finished mission is never lost to a PermissionError
    staged = staging_folder(out_dir)
    recorder = MissionRecorder(node, staged / "run.mcap")
    offered = offered_services(node)
    services = [node.resolve_service_name(s.service) for s in STAGES.values()]
    expected = [service + EVENT_SUFFIX for service in services if service in offered]
    mission_topics = [node.resolve_topic_name(name) for name in MISSION_TOPICS]
    silent = recorder.wait_matched(expected + mission_topics, lambda t: spin_for(node, t), timeout=min(10.0, timeout))
    for topic in silent:
        if topic in mission_topics:
            continue  # transient local on the coordinator's side; the result carries what outputs need
        out.write(f"perch: warning: {topic[:-len(EVENT_SUFFIX)]} publishes no introspection events; its calls "
                  "will not be in the recording (its node's parameter `introspection`)\n")
    printer = ProgressPrinter(out) if progress else None
    started = time.monotonic()
    outputs = PlanOutputs(PlanPerches.Result(), out_dir, staged / "run.mcap", staged=staged, goal=goal,
                          coordinates=(describe or {}).get("coordinates", ""))
    try:
        outputs.result = run_mission(node, goal, timeout=timeout, on_feedback=printer)
        outputs.result_seconds = time.monotonic() - started
        result = outputs.result
        if result.success:
            publish_waypoints(outputs)
            if progress:
                out.write(f"perch: {len(result.waypoints)} waypoint(s) in {outputs.waypoints}; writing the "
                          "recording, report and rerun file\n")
            _load_output_writers()
        _drain(node, recorder)
        watched = {topic: stage for stage, topic in zip(STAGES, (s + EVENT_SUFFIX for s in services))
                   if topic in expected and topic not in silent}
        missing = await_stage_events(node, recorder, result, watched)
        if missing:
            out.write(f"perch: warning: the recording {outputs.mcap.name} misses stage calls the mission made "
                      f"({'; '.join(missing)}): `perch replay` and the report lack them (the mission's result "
                      "and waypoints are complete)\n")
        outputs.mission_seconds = time.monotonic() - started
        recorder.add_metadata("perch_mission", {
            "success": result.success, "message": result.message, "stage_names": list(result.stage_names),
            "stage_seconds": list(result.stage_seconds), "fitness": result.fitness, "coverage": result.coverage,
            "mean_uncertainty": result.mean_uncertainty, "cameras": len(result.placements),
            "mission_seconds": outputs.mission_seconds, "recording_missing": missing, **(describe or {})})
    except GoalRejected:
        recorder.close()
        shutil.rmtree(staged, ignore_errors=True)
        raise
    except (KeyboardInterrupt, TimeoutError) as exc:
        recorder.close()
        finished = outputs.result.message
        if isinstance(exc, TimeoutError):
            reason = f"{exc}; cancelled"
        elif finished:
            reason = f"interrupted (SIGINT) before the outputs were written; the mission itself ended: {finished}"
        else:
            reason = "mission interrupted (SIGINT); cancelled"
        outputs.result = PlanPerches.Result(success=False, message=reason)
        fail_outputs(outputs, reason)
        raise PerchError(f"{reason}; the recording so far is in {outputs.mcap}") from None
    except Exception as exc:  # anything else that ends the client's mission still leaves its reason
        recorder.close()
        reason = f"the client failed during the mission: {type(exc).__name__}: {exc}"
        outputs.result = PlanPerches.Result(success=False, message=reason)
        fail_outputs(outputs, reason)
        raise
    except BaseException:
        recorder.close()
        shutil.rmtree(staged, ignore_errors=True)
        raise
    finally:
        if printer:
            printer.close()
    recorder.close()
    return outputs


def publish_waypoints(outputs: PlanOutputs) -> Path:
    """The mission's product first: waypoints.yaml goes into out_dir as soon as the result is in, so
    a dispatcher reading the file does not wait for the report. It replaces the earlier mission's in
    one rename (a reader polling the file never finds it missing); an earlier failure's FAILED goes;
    the earlier report, rerun file and recording are swapped for the new ones by write_outputs."""
    from perch_operator.outputs.mission_data import waypoint_dict, write_waypoints_yaml

    waypoints = [waypoint_dict(w) for w in outputs.result.waypoints]
    outputs.waypoints = publish_output(outputs.out_dir, "waypoints.yaml",
                                       lambda path: write_waypoints_yaml(path, waypoints, outputs.coordinates))
    outputs.waypoints_at = time.time()
    remove_outputs(outputs.out_dir, (FAILED_NAME, FAILED_RECORDING))
    return outputs.waypoints


def _load_output_writers() -> None:
    """Import the rerun writer on a thread (rerun alone takes ~0.45 s) while the recording waits
    for the mission's last messages, a wait spent mostly idle in rcl; writing the outputs then
    finds it loaded. A failed import is left for the writer itself to report."""
    import importlib.util
    import threading

    def load() -> None:
        with contextlib.suppress(Exception):
            importlib.import_module("rerun")

    if "rerun" not in sys.modules and importlib.util.find_spec("rerun") is not None:
        threading.Thread(target=load, name="perch-load-rerun", daemon=True).start()


# How long a finished mission's recording waits for stage events still on their way (only spent
# when some are missing: a complete recording closes at once).
STAGE_EVENTS_WAIT = 15.0


def await_stage_events(node, recorder: MissionRecorder, result, watched: dict[str, str],
                       limit: float = STAGE_EVENTS_WAIT) -> list[str]:
    """Spin until the recording holds the request and reply of every stage call the result says
    ran (`watched`: event topic -> stage, the services publishing events), or `limit` passes;
    returns what is still missing, one phrase per stage service (empty: complete)."""
    ran = list(result.stage_names)
    expected = {topic: ran.count(stage) for topic, stage in watched.items() if stage in ran}
    deadline = time.monotonic() + limit
    while True:
        missing = recorder.missing_calls(expected, whole=bool(result.success))
        if not missing or time.monotonic() > deadline:
            return missing
        spin_for(node, 0.1)


def _drain(node, recorder: MissionRecorder, quiet: float = 0.3, limit: float = 5.0) -> None:
    """Spin until no recorded message arrived for `quiet` seconds (trailing events, waypoints)."""
    deadline = time.monotonic() + limit
    last = -1
    while time.monotonic() < deadline:
        found = recorder.refresh(late=True)   # topics that appeared during the mission (each drone's views)
        total = sum(recorder.counts.values())
        if total == last and not found:
            return
        last = total
        spin_for(node, quiet)


def write_outputs(outputs: PlanOutputs, out=sys.stderr) -> PlanOutputs:
    """Move a finished mission's outputs into out_dir: waypoints.yaml, run.rrd and report.html on success
    (built from the mission result, the recording only adding detail), a FAILED marker otherwise.

    Outputs of an earlier run that this one did not produce are removed, so whatever is in the folder
    belongs to this mission.
    """
    if outputs.staged is None:
        return outputs
    if not outputs.result.success:
        fail_outputs(outputs, outputs.result.message)
        return outputs
    try:
        _write_success(outputs, out)
    except KeyboardInterrupt:
        fail_outputs(outputs, "interrupted (SIGINT) while writing the outputs; the mission itself succeeded: "
                              f"{outputs.result.message}")
        raise
    except BaseException as exc:
        fail_outputs(outputs, f"writing the outputs failed: {type(exc).__name__}: {exc}")
        raise
    return outputs


def _write_success(outputs: PlanOutputs, out) -> None:
    from perch_operator.outputs.mission_data import mission_data_from_result, write_waypoints_yaml
    from perch_operator.outputs.render import camera_views
    from perch_operator.outputs.report import perch_text, removal_text, write_report
    from perch_operator.outputs.rerun_log import write_rrd

    staged = outputs.staged
    data = mission_data_from_result(outputs.mcap, outputs.result, outputs.goal)
    outputs.removals = removal_text(data)
    outputs.perches = perch_text(data)
    if outputs.waypoints_at is None:   # not yet in out_dir (run_recorded_mission publishes them at once)
        write_waypoints_yaml(staged / "waypoints.yaml", data.waypoints, outputs.coordinates)
    if data.mesh is None:
        out.write("perch: neither the goal nor the recording holds the mesh (a bag mission without stage "
                  "events); no report or rerun file\n")
    else:
        views = camera_views(data)
        write_rrd(data, staged / "run.rrd", views)
        write_report(data, staged, views=views)
    published = ("waypoints.yaml",) if outputs.waypoints_at is not None else ()
    moved = {p.name: p for p in replace_outputs(staged, outputs.out_dir, OUTPUT_NAMES,
                                                [n for n in OUTPUT_NAMES if n not in published])}
    outputs.staged = None
    outputs.mcap = moved.get("run.mcap", outputs.out_dir / "run.mcap")
    outputs.waypoints = moved.get("waypoints.yaml", outputs.waypoints)
    outputs.rrd = moved.get("run.rrd")
    outputs.report = moved.get("report.html")


def fail_outputs(outputs: PlanOutputs, reason: str) -> Path:
    """out_dir gets FAILED (the reason) and this mission's recording. The last good waypoints.yaml stays
    (with the rest of its set), and FAILED says whose it is; without one, FAILED and run.mcap are all
    the folder holds of Perch's."""
    staged = outputs.staged
    if staged is None or not staged.is_dir():
        staged = staging_folder(outputs.out_dir)
    out_dir = outputs.out_dir
    kept = "waypoints.yaml" in written_by_perch(out_dir) and (out_dir / "waypoints.yaml").is_file()
    failed_at = time.strftime('%Y-%m-%d %H:%M:%S %Z')
    if not kept:
        recording = "run.mcap"
        what = "no waypoints, report or rerun file were written."
    else:
        recording = FAILED_RECORDING
        written = time.strftime('%Y-%m-%d %H:%M:%S %Z', time.localtime((out_dir / "waypoints.yaml").stat().st_mtime))
        whose = ("this mission's own (its result was in before it failed)" if outputs.waypoints_at is not None
                 else "the last good mission's; this one wrote none")
        others = [n for n in GOOD_SET[1:] if n in written_by_perch(out_dir) and (out_dir / n).exists()]
        what = (f"the last good waypoints.yaml (written {written}) is kept: {whose}"
                + (f"; {', '.join(others)} beside it are of the mission that wrote them" if others else "") + ".")
    if (staged / "run.mcap").exists() and recording != "run.mcap":
        os.replace(staged / "run.mcap", staged / recording)
    (staged / FAILED_NAME).write_text(
        f"{reason}\n\nfailed at {failed_at}; {recording} (when present) records this failed mission; {what}\n")
    stale = (FAILED_NAME, FAILED_RECORDING) if kept else OUTPUT_NAMES
    replace_outputs(staged, out_dir, (FAILED_NAME, recording), stale)
    outputs.staged = None
    outputs.mcap = out_dir / recording
    return out_dir / FAILED_NAME


def summary_table(result: PlanPerches.Result) -> str:
    """The numbers a person wants after a mission, as a small text table."""
    unc = result.mean_uncertainty
    rows = [("cameras", f"{len(result.placements)}"), ("coverage", f"{100 * result.coverage:.1f} %"),
            ("mean uncertainty", "n/a" if unc != unc else f"{unc:.3g} m^2"), ("fitness", f"{result.fitness:.4f}")]
    rows += [(f"time {name}", f"{seconds:.2f} s") for name, seconds in zip(result.stage_names, result.stage_seconds)]
    width = max(len(k) for k, _ in rows)
    line = "+" + "-" * (width + 2) + "+" + "-" * 14 + "+"
    body = [f"| {k:<{width}} | {v:>12} |" for k, v in rows]
    return "\n".join([line, *body, line])
