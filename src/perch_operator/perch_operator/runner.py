"""Run one recorded mission from the command line and write its outputs.

Used by `perch plan` and `perch demo`: start whatever part of the graph is missing, record the
mission to run.mcap, then derive waypoints.yaml, run.rrd and report.html from the recording.
"""

from __future__ import annotations

import contextlib
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from perch_common.errors import PerchError
from perch_interfaces.action import PlanPerches
from perch_operator.recorder import EVENT_SUFFIX, MissionRecorder
from perch_operator.stages import STAGES

# Which node serves which service (relative names; to launch only what is missing).
NODE_SERVICES = {"perch_operator": ["perch/crop", "perch/confirm"],
                 "perch_reconstruction": ["perch/clean_mesh", "perch/reconstruct"],
                 "perch_segmentation": ["perch/segment"], "perch_filtering": ["perch/filter"],
                 "perch_placement": ["perch/optimise"]}


@dataclass
class PlanOutputs:
    result: PlanPerches.Result
    out_dir: Path
    mcap: Path
    rrd: Path | None = None
    report: Path | None = None
    waypoints: Path | None = None
    mission_seconds: float = 0.0


@contextlib.contextmanager
def client_context():
    """rclpy for a command-line client: Ctrl-C raises KeyboardInterrupt in Python (not a silent
    context shutdown), so a mission can be cancelled and its recording closed properly."""
    import rclpy
    from rclpy.signals import SignalHandlerOptions

    from perch_common import namespace

    # Every node of this client process resolves Perch's relative names in the graph's namespace.
    rclpy.init(args=["--ros-args", *namespace.ros_arguments(namespace.current())],
               signal_handler_options=SignalHandlerOptions.NO)
    try:
        yield
    finally:
        rclpy.try_shutdown()


def offered_services(node) -> set[str]:
    return {name for name, _ in node.get_service_names_and_types()}


def ensure_graph(node, config: Path | None = None, overrides=(), log_dir: Path | None = None,
                 settle: float = 2.0, timeout: float = 90.0, out=sys.stderr):
    """Start the nodes whose services are not in the graph; returns the GraphProcesses (or None)."""
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
    import rclpy

    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        rclpy.spin_once(node, timeout_sec=min(0.05, max(0.0, deadline - time.monotonic())))


def run_recorded_mission(node, goal: PlanPerches.Goal, out_dir: Path, progress: bool = True,
                         timeout: float = 900.0, describe: dict | None = None, out=sys.stderr) -> PlanOutputs:
    """Record the mission to out_dir/run.mcap; returns the result (outputs are written separately)."""
    from perch_operator.client import ProgressPrinter, run_mission

    out_dir.mkdir(parents=True, exist_ok=True)
    recorder = MissionRecorder(node, out_dir / "run.mcap")
    offered = offered_services(node)
    services = [node.resolve_service_name(s.service) for s in STAGES.values()]
    expected = [service + EVENT_SUFFIX for service in services if service in offered]
    silent = recorder.wait_matched(expected, lambda t: spin_for(node, t), timeout=10.0)
    for topic in silent:
        out.write(f"perch: warning: {topic[:-len(EVENT_SUFFIX)]} publishes no introspection events; its calls "
                  "will not be in the recording (its node's parameter `introspection`)\n")
    printer = ProgressPrinter(out) if progress else None
    started = time.monotonic()
    try:
        result = run_mission(node, goal, timeout=timeout, on_feedback=printer)
    except (KeyboardInterrupt, TimeoutError) as exc:
        recorder.close()
        raise PerchError(f"mission {'interrupted' if isinstance(exc, KeyboardInterrupt) else str(exc)}; "
                         f"cancelled; the recording so far is in {recorder.path}") from None
    finally:
        if printer:
            printer.close()
    _drain(node, recorder)
    seconds = time.monotonic() - started
    recorder.add_metadata("perch_mission", {
        "success": result.success, "message": result.message, "stage_names": list(result.stage_names),
        "stage_seconds": list(result.stage_seconds), "fitness": result.fitness, "coverage": result.coverage,
        "mean_uncertainty": result.mean_uncertainty, "cameras": len(result.placements),
        "mission_seconds": seconds, **(describe or {})})
    recorder.close()
    return PlanOutputs(result, out_dir, out_dir / "run.mcap", mission_seconds=seconds)


def _drain(node, recorder: MissionRecorder, quiet: float = 0.3, limit: float = 5.0) -> None:
    """Spin until no recorded message arrived for `quiet` seconds (trailing events, waypoints)."""
    deadline = time.monotonic() + limit
    last = -1
    while time.monotonic() < deadline:
        total = sum(recorder.counts.values())
        if total == last:
            return
        last = total
        spin_for(node, quiet)


def write_outputs(outputs: PlanOutputs, out=sys.stderr) -> PlanOutputs:
    """waypoints.yaml, run.rrd and report.html from the recording."""
    from perch_operator.mission_data import load_mission, write_waypoints_yaml
    from perch_operator.render import camera_views
    from perch_operator.report import write_report
    from perch_operator.rerun_log import write_rrd

    data = load_mission(outputs.mcap)
    outputs.waypoints = write_waypoints_yaml(outputs.out_dir / "waypoints.yaml", data.waypoints)
    if data.mesh is None:
        out.write("perch: the recording holds no mesh (no stage events recorded); no report or rerun file\n")
        return outputs
    views = camera_views(data)
    outputs.rrd = write_rrd(data, outputs.out_dir / "run.rrd", views)
    outputs.report = write_report(data, outputs.out_dir, views=views)
    return outputs


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
