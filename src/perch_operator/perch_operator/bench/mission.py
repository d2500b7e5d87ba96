"""`perch bench mission`: what a user waits for, from the command's start to waypoints written.

    perch bench mission --mesh apartment.ply --target apartment_target.ply:1.2 --json
    perch bench mission --scene 3 --kind apartment --resolution 0.022 --noise 0.005 --repeat 3
    perch bench mission --scene 1 --kind building --cameras 20
    perch bench mission --scene 7 --missions 20          # stability: RSS per mission on one graph

One run starts its own graph (one process by default, `--graph-mode per-node` for node processes),
runs the mission with auto-accept and writes waypoints.yaml. The graph runs on your ROS_DOMAIN_ID in
a namespace of its own (`<your namespace>/perch_bench_<pid>`, field `namespace`): it times a graph's
start-up, so it never uses a graph already running there, and never meets one. JSON fields:
  wall_s       process start to waypoints written (interpreter, imports, scene, graph start-up);
  input_s      the part of wall_s spent making the goal: loading --mesh, or generating the scene
               (a user planning a scan never pays a generated scene's making);
  outputs_s    with --record (the first mission run as `perch plan` runs it: recorded, waypoints.yaml
               written as the result comes in): process start to run.mcap, run.rrd and report.html written;
  startup_s    graph start-up alone (nodes created, services offered);
  mission_s    goal sent to result received (first mission);
  stages       seconds each stage reported for its own work;
  transport_s  mission_s minus the stages' own seconds: (de)serialising, delivering and converting
               messages between client, coordinator and stages;
  peak_rss_mb  peak resident memory of the whole graph (client and node processes, sampled 10 Hz,
               and this process's own peak).
`--repeat N` runs N fresh processes one after another (each pays its own start-up and frees its
memory before the next) and reports the median of each figure, of the stage times and of cameras,
coverage and fitness, with each run's 1-minute load average; it exits 1 when any run failed.
"""

from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

FIGURES = ("wall_s", "input_s", "startup_s", "mission_s", "transport_s", "peak_rss_mb")
OUTCOMES = ("cameras", "coverage", "fitness")   # also medians with --repeat (seeded: equal unless a run differs)


def register(sub) -> None:
    """The `perch bench mission` benchmark."""
    from perch_common.cli_types import non_negative_float, non_negative_int, positive_int, scene_resolution
    from perch_common.launch import add_graph_arguments
    from perch_operator.bench import camera_count

    p = sub.add_parser("mission", help="a whole mission from the command's start: start-up, stages, transport, memory")
    source = p.add_mutually_exclusive_group()
    source.add_argument("--mesh", type=Path, help="environment mesh (default: a generated scene)")
    source.add_argument("--scene", type=non_negative_int, default=7, help="generated scene seed (>= 0)")
    p.add_argument("--kind", default="apartment", help="generated scene kind")
    p.add_argument("--resolution", type=scene_resolution, default=None,
                   help="generated scene resolution (m, 0.02-0.5; kind default)")
    p.add_argument("--noise", type=non_negative_float, default=0.0, help="generated scene vertex noise (m, >= 0)")
    p.add_argument("--target", default=None, metavar="SPEC", help="as for perch plan (default: the scene's "
                                                                   "own target; for --mesh the cropped floor)")
    p.add_argument("--cameras", type=camera_count, default=0, help="cameras (0: node default)")
    p.add_argument("--up", default="", help="the mesh's up axis, as for perch plan (+z, -y, auto, \"x y z\"; "
                                             "default: the coordinator's input_up_axis)")
    p.add_argument("--missions", type=positive_int, default=1, help="consecutive missions on one graph (>= 1)")
    p.add_argument("--repeat", type=positive_int, default=1, help="fresh processes to run (>= 1; medians reported)")
    p.add_argument("--reject", action="store_true", help="after the first mission, time one rejection's re-plan")
    p.add_argument("--record", action="store_true",
                   help="run the first mission as `perch plan` does: recorded to run.mcap, waypoints.yaml written "
                        "as the result comes in, then run.rrd and report.html (adds outputs_s)")
    p.add_argument("--config", type=Path, help="parameter file")
    p.add_argument("-p", "--param", action="append", default=[], metavar="NODE:PARAM:=VALUE")
    p.add_argument("--json", action="store_true", help="print JSON (always on; accepted for uniformity)")
    add_graph_arguments(p, "one-process")
    p.set_defaults(func=_run)


def build_goal(args):
    """The PlanPerches goal, a description of its source, and its face count."""
    from perch_common.ros.conversions import mesh_to_msg, target_to_msg
    from perch_interfaces.action import PlanPerches
    from perch_operator.cli.plan import parse_target

    if args.up.strip().lower() not in ("", "auto"):
        from perch_common.transforms import parse_up_axis

        parse_up_axis(args.up)  # a malformed axis fails here, before anything is launched
    goal = PlanPerches.Goal(num_cameras=max(0, args.cameras), auto_accept=True, seed=-1, up_axis=args.up)
    if args.mesh:
        from perch_common.mesh import load_mesh

        mesh, source = load_mesh(args.mesh), str(args.mesh.name)
        goal.target = parse_target(args.target)
    else:
        from perch_common.scene_generator import generate_scene

        extra = {} if args.resolution is None else {"resolution": args.resolution}
        scene = generate_scene(args.scene, args.kind, noise=args.noise, **extra)
        mesh, source = scene.mesh, f"{args.kind} seed {args.scene}"
        goal.target = target_to_msg(scene.target) if args.target is None else parse_target(args.target)
    goal.mesh = mesh_to_msg(mesh)
    return goal, source, mesh.num_faces


class RssSampler:
    """Peak of the summed RSS of some processes, sampled in a thread."""

    def __init__(self, pids: list[int], period: float = 0.1):
        import psutil

        self.procs = [psutil.Process(pid) for pid in set(pids) | {os.getpid()}]
        self.period = period
        self.peak_bytes = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, daemon=True)

    def _loop(self) -> None:
        while not self._stop.is_set():
            total = 0
            for proc in self.procs:
                try:
                    total += proc.memory_info().rss
                except Exception:  # noqa: BLE001 - a process that ended counts as 0
                    pass
            self.peak_bytes = max(self.peak_bytes, total)
            self._stop.wait(self.period)

    def __enter__(self) -> "RssSampler":
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join()


def _run(args) -> int:
    from perch_common.bench import emit

    if args.repeat > 1:
        result = _repeated(args)
        emit(result)
        return 1 if any(r["failures"] or r.get("dead_nodes") for r in result["runs"]) else 0
    result = _one_run(args)
    emit(result)
    return 1 if result["failures"] or result.get("dead_nodes") else 0


def _one_run(args) -> dict:
    import psutil
    import rclpy

    from perch_common import namespace
    from perch_common.bench import peak_rss_mb
    from perch_common.launch import use_perch_dds
    from perch_operator.api.client import run_mission
    from perch_operator.cli.runner import (
        choose_domain,
        client_context,
        graph_ros_args,
        run_recorded_mission,
        start_own_graph,
        write_outputs,
    )
    from perch_operator.outputs.mission_data import waypoint_dict, write_waypoints_yaml

    process_start = psutil.Process().create_time()
    # Its own namespace on the user's domain: a graph already running there is neither used nor disturbed.
    own_namespace = namespace.current() + f"/perch_bench_{os.getpid()}"
    os.environ[namespace.NAMESPACE_ENV] = own_namespace
    use_perch_dds(network=args.network or None)
    input_start = time.monotonic()
    goal, source, faces = build_goal(args)
    input_s = time.monotonic() - input_start  # a generated scene's making is in wall_s, not a user's cost
    out_dir = Path(tempfile.mkdtemp(prefix="perch_bench_mission_"))
    domain = choose_domain()
    in_process = args.graph_mode == "one-process"
    ros_args = graph_ros_args(args.config, args.param, out_dir / "logs") if in_process else None
    with client_context(ros_args, domain):
        node = rclpy.create_node("perch_bench_mission")
        graph = start_own_graph(node, args.graph_mode, domain, args.config, args.param, out_dir / "logs")
        try:
            with RssSampler(graph.pids()) as sampler:
                missions, failures, stage_times = [], [], {}
                outputs_s = None
                for i in range(max(1, args.missions)):
                    t0 = time.monotonic()
                    if i == 0 and args.record:
                        outputs = run_recorded_mission(node, goal, out_dir / "plan", progress=False, timeout=1800)
                        result = outputs.result
                        missions.append(outputs.result_seconds)
                        wall = (outputs.waypoints_at or time.time()) - process_start
                        write_outputs(outputs)
                        outputs_s = round(time.time() - process_start, 3)
                        first = result
                        continue
                    result = run_mission(node, goal, timeout=1800)
                    missions.append(time.monotonic() - t0)
                    if i == 0:
                        write_waypoints_yaml(out_dir / "waypoints.yaml", [waypoint_dict(w) for w in result.waypoints])
                        wall = time.time() - process_start
                        first = result
                    if not result.success:
                        failures.append(f"mission {i}: {result.message}")
                    for name, seconds in zip(result.stage_names, result.stage_seconds):
                        stage_times.setdefault(name, []).append(seconds)
                reject = _time_rejection(node, first) if args.reject and first.success and first.placements else None
            dead = [n for n, ok in graph.processes.alive().items() if not ok] if graph.processes else []
        finally:
            graph.stop()
    stages = {n: round(s, 3) for n, s in zip(first.stage_names, first.stage_seconds) if n != "total"}
    out = {"source": source, "faces": faces, "graph_mode": args.graph_mode, "domain": domain,
           "namespace": own_namespace,
           "wall_s": round(wall, 3), "input_s": round(input_s, 3), "startup_s": round(graph.startup_seconds, 3),
           "mission_s": round(missions[0], 3),
           "stages": stages, "transport_s": round(missions[0] - sum(stages.values()), 3),
           "peak_rss_mb": round(max(sampler.peak_bytes / 2**20, peak_rss_mb()), 1),
           "cameras": len(first.placements), "coverage": first.coverage, "mean_uncertainty": first.mean_uncertainty,
           "fitness": first.fitness, "failures": failures, "dead_nodes": dead,
           "load_average_1min": round(os.getloadavg()[0], 2), "recorded": bool(args.record),
           "waypoints": str(out_dir / "plan" / "waypoints.yaml" if args.record else out_dir / "waypoints.yaml")}
    if outputs_s is not None:
        out["outputs_s"] = outputs_s
    if len(missions) > 1:
        out["missions"] = len(missions)
        out["mission_s_all"] = [round(m, 3) for m in missions]
        out["stage_seconds_median"] = {k: round(statistics.median(v), 3) for k, v in stage_times.items()}
    if reject is not None:
        out["reject_replan_s"] = reject
    return out


def _repeated(args) -> dict:
    """`--repeat N`: N fresh processes (each pays its own start-up), and the median of each figure."""
    argv = [a for a in sys.argv[1:]]
    if "--repeat" in argv:
        i = argv.index("--repeat")
        del argv[i:i + 2]
    runs = []
    for _ in range(args.repeat):
        done = subprocess.run([sys.executable, "-m", "perch_common.cli", *argv], capture_output=True, text=True)
        if done.returncode not in (0, 1) or not done.stdout.strip():
            raise RuntimeError(f"benchmark run failed (exit {done.returncode}): {done.stderr[-2000:]}")
        runs.append(json.loads(done.stdout))
    figures = FIGURES + (("outputs_s",) if all("outputs_s" in r for r in runs) else ())
    median = {k: round(statistics.median(r[k] for r in runs), 3) for k in figures + OUTCOMES}
    stage_names = runs[0]["stages"].keys()
    median["stages"] = {n: round(statistics.median(r["stages"].get(n, float("nan")) for r in runs), 3)
                        for n in stage_names}
    return {"source": runs[0]["source"], "faces": runs[0]["faces"], "graph_mode": args.graph_mode,
            "repeat": args.repeat, "median": median,
            "load_average_1min": [r["load_average_1min"] for r in runs], "runs": runs}


def _time_rejection(node, result) -> float:
    """Reject the first proposal of the last mission; seconds until the replacement arrives."""
    from perch_common.conventions import CONFIRM_SERVICE
    from perch_common.ros.testing import call_service
    from perch_interfaces.msg import Proposal
    from perch_interfaces.srv import Confirm
    from perch_operator.cli.runner import spin_for
    from perch_operator.coordinator.node import LATCHED

    latest: dict[int, Proposal] = {}
    sub = node.create_subscription(Proposal, "perch/proposals", lambda m: latest.__setitem__(m.id, m), LATCHED)
    spin_for(node, 1.0)
    node.destroy_subscription(sub)
    accepted = sorted(pid for pid, m in latest.items() if m.status == Proposal.STATUS_ACCEPTED)
    t0 = time.monotonic()
    reply = call_service(node, Confirm, CONFIRM_SERVICE,
                         Confirm.Request(proposal_id=accepted[-1], decision=Confirm.Request.FAILED_IN_FLIGHT), timeout=60)
    seconds = time.monotonic() - t0
    if not reply.success:
        raise RuntimeError(reply.message)
    return round(seconds, 3)
