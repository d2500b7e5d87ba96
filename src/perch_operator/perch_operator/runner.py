"""Run one recorded mission from the command line and write its outputs.

Used by `perch plan` and `perch demo`: start whatever part of the graph is missing, record the
mission to run.mcap in a staging folder, then write waypoints.yaml, run.rrd and report.html from the
mission result (the recording adds the stage replies) and move them into the output folder together.
"""

from __future__ import annotations

import contextlib
import shutil
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from perch_common.conventions import NODE_SERVICES
from perch_common.errors import PerchError
from perch_common.outputs import replace_outputs, staging_folder
from perch_interfaces.action import PlanPerches
from perch_operator.recorder import EVENT_SUFFIX, MISSION_TOPICS, MissionRecorder
from perch_operator.stages import STAGES


@dataclass
class PlanOutputs:
    result: PlanPerches.Result
    out_dir: Path
    mcap: Path
    rrd: Path | None = None
    report: Path | None = None
    waypoints: Path | None = None
    mission_seconds: float = 0.0
    staged: Path | None = None          # staging folder until the outputs are moved into out_dir
    goal: PlanPerches.Goal | None = None


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


FAILED_NAME = "FAILED"
# Everything a mission writes into its output folder (logs/ of launched nodes is not a mission output).
OUTPUT_NAMES = ("waypoints.yaml", "run.mcap", "run.rrd", "report.html", "report_files", FAILED_NAME)


def run_recorded_mission(node, goal: PlanPerches.Goal, out_dir: Path, progress: bool = True,
                         timeout: float = 900.0, describe: dict | None = None, out=sys.stderr) -> PlanOutputs:
    """Record the mission into a fresh staging folder beside out_dir; `write_outputs` moves it into place.

    A goal the coordinator rejects leaves nothing behind (GoalRejected); an interrupted or timed-out
    mission leaves out_dir with a FAILED marker and its recording (PerchError).
    """
    from perch_operator.client import GoalRejected, ProgressPrinter, run_mission

    staged = staging_folder(out_dir)
    recorder = MissionRecorder(node, staged / "run.mcap")
    offered = offered_services(node)
    services = [node.resolve_service_name(s.service) for s in STAGES.values()]
    expected = [service + EVENT_SUFFIX for service in services if service in offered]
    mission_topics = [node.resolve_topic_name(name) for name in MISSION_TOPICS]
    silent = recorder.wait_matched(expected + mission_topics, lambda t: spin_for(node, t), timeout=10.0)
    for topic in silent:
        if topic in mission_topics:
            continue  # transient local on the coordinator's side; the result carries what outputs need
        out.write(f"perch: warning: {topic[:-len(EVENT_SUFFIX)]} publishes no introspection events; its calls "
                  "will not be in the recording (its node's parameter `introspection`)\n")
    printer = ProgressPrinter(out) if progress else None
    started = time.monotonic()
    outputs = PlanOutputs(PlanPerches.Result(), out_dir, staged / "run.mcap", staged=staged, goal=goal)
    try:
        outputs.result = run_mission(node, goal, timeout=timeout, on_feedback=printer)
    except GoalRejected:
        recorder.close()
        shutil.rmtree(staged, ignore_errors=True)
        raise
    except (KeyboardInterrupt, TimeoutError) as exc:
        recorder.close()
        reason = f"mission {'interrupted' if isinstance(exc, KeyboardInterrupt) else str(exc)}; cancelled"
        outputs.result = PlanPerches.Result(success=False, message=reason)
        fail_outputs(outputs, reason)
        raise PerchError(f"{reason}; the recording so far is in {outputs.mcap}") from None
    except BaseException:
        recorder.close()
        shutil.rmtree(staged, ignore_errors=True)
        raise
    finally:
        if printer:
            printer.close()
    result = outputs.result
    _drain(node, recorder)
    outputs.mission_seconds = time.monotonic() - started
    recorder.add_metadata("perch_mission", {
        "success": result.success, "message": result.message, "stage_names": list(result.stage_names),
        "stage_seconds": list(result.stage_seconds), "fitness": result.fitness, "coverage": result.coverage,
        "mean_uncertainty": result.mean_uncertainty, "cameras": len(result.placements),
        "mission_seconds": outputs.mission_seconds, **(describe or {})})
    recorder.close()
    return outputs


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
    except BaseException as exc:
        fail_outputs(outputs, f"writing the outputs failed: {type(exc).__name__}: {exc}")
        raise
    return outputs


def _write_success(outputs: PlanOutputs, out) -> None:
    from perch_operator.mission_data import mission_data_from_result, write_waypoints_yaml
    from perch_operator.render import camera_views
    from perch_operator.report import write_report
    from perch_operator.rerun_log import write_rrd

    staged = outputs.staged
    data = mission_data_from_result(outputs.mcap, outputs.result, outputs.goal)
    write_waypoints_yaml(staged / "waypoints.yaml", data.waypoints)
    if data.mesh is None:
        out.write("perch: neither the goal nor the recording holds the mesh (a bag mission without stage "
                  "events); no report or rerun file\n")
    else:
        views = camera_views(data)
        write_rrd(data, staged / "run.rrd", views)
        write_report(data, staged, views=views)
    moved = {p.name: p for p in replace_outputs(staged, outputs.out_dir, OUTPUT_NAMES, OUTPUT_NAMES)}
    outputs.staged = None
    outputs.mcap = moved.get("run.mcap", outputs.out_dir / "run.mcap")
    outputs.waypoints, outputs.rrd = moved.get("waypoints.yaml"), moved.get("run.rrd")
    outputs.report = moved.get("report.html")


def fail_outputs(outputs: PlanOutputs, reason: str) -> Path:
    """out_dir gets FAILED (the reason) and this mission's recording; earlier outputs are removed."""
    staged = outputs.staged
    if staged is None:
        staged = staging_folder(outputs.out_dir)
    (staged / FAILED_NAME).write_text(
        f"{reason}\n\nfailed at {time.strftime('%Y-%m-%d %H:%M:%S %Z')}; run.mcap (when present) records "
        "this failed mission; no waypoints, report or rerun file were written.\n")
    replace_outputs(staged, outputs.out_dir, (FAILED_NAME, "run.mcap"), OUTPUT_NAMES)
    outputs.staged = None
    outputs.mcap = outputs.out_dir / "run.mcap"
    return outputs.out_dir / FAILED_NAME


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
