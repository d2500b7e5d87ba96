"""`perch bench mission`: missions on a live graph with per-stage times and the nodes' memory.

    perch bench mission --scene 7 --missions 20          # stability: RSS of every node per mission
    perch bench mission --mesh apartment.ply --target-footprint apartment_target.ply
"""

from __future__ import annotations

import statistics
import time
from pathlib import Path


def register(sub) -> None:
    p = sub.add_parser("mission", help="run missions on a launched graph; per-stage times and node memory")
    source = p.add_mutually_exclusive_group()
    source.add_argument("--mesh", type=Path, help="environment mesh (default: a generated scene)")
    source.add_argument("--scene", type=int, default=7, help="generated scene seed")
    p.add_argument("--kind", default="apartment", help="generated scene kind")
    p.add_argument("--target-footprint", type=Path, help="target footprint mesh (extruded by --height)")
    p.add_argument("--height", type=float, default=1.2, help="target extrusion height (m)")
    p.add_argument("--missions", type=int, default=1, help="consecutive missions in one graph")
    p.add_argument("--cameras", type=int, default=0, help="cameras (0: node default)")
    p.add_argument("--reject", action="store_true", help="after the first mission, time one rejection's re-plan")
    p.add_argument("--config", type=Path, help="parameter file")
    p.add_argument("-p", "--param", action="append", default=[], metavar="NODE:PARAM:=VALUE")
    p.set_defaults(func=_run)


def build_goal(args):
    from perch_common.mesh import load_mesh
    from perch_common.ros.conversions import mesh_to_msg, target_to_msg
    from perch_common.target import TargetVolume
    from perch_interfaces.action import PlanPerches

    goal = PlanPerches.Goal(num_cameras=args.cameras, auto_accept=True, seed=-1)
    if args.mesh:
        mesh = load_mesh(args.mesh)
        source = str(args.mesh.name)
    else:
        from perch_common.scene_generator import generate_scene

        scene = generate_scene(args.scene, args.kind)
        mesh, source = scene.mesh, f"{args.kind} seed {args.scene}"
        goal.target = target_to_msg(scene.target)
    if args.target_footprint:
        goal.target = target_to_msg(TargetVolume.from_footprint_mesh(load_mesh(args.target_footprint), args.height))
    goal.mesh = mesh_to_msg(mesh)
    return goal, source, mesh.num_faces


def _run(args) -> int:
    import psutil
    import rclpy

    from perch_common.bench import emit, peak_rss_mb
    from perch_common.launch import GraphProcesses, use_fast_liveliness
    from perch_operator.client import run_mission
    from perch_operator.runner import client_context

    use_fast_liveliness()
    goal, source, faces = build_goal(args)
    with client_context(), GraphProcesses(args.config, None, args.param) as graph:
        node = rclpy.create_node("perch_bench_mission")
        started = time.monotonic()
        from perch_common.conventions import NODE_SERVICES

        missing = graph.wait_for_services(node, [NODE_SERVICES[n][0] for n in graph.nodes if n in NODE_SERVICES], 120)
        if missing:
            raise RuntimeError(f"services missing: {missing}")
        startup = time.monotonic() - started
        procs = {name: psutil.Process(p.pid) for name, p in graph.processes.items()}
        stage_times: dict[str, list[float]] = {}
        rss: dict[str, list[float]] = {name: [] for name in procs}
        walls, failures = [], []
        for i in range(args.missions):
            t0 = time.monotonic()
            result = run_mission(node, goal, timeout=900)
            walls.append(time.monotonic() - t0)
            if not result.success:
                failures.append(f"mission {i}: {result.message}")
            for name, seconds in zip(result.stage_names, result.stage_seconds):
                stage_times.setdefault(name, []).append(seconds)
            for name, proc in procs.items():
                rss[name].append(proc.memory_info().rss / 2**20)
        dead = [n for n, ok in graph.alive().items() if not ok]
        out = {"source": source, "faces": faces, "missions": args.missions, "failures": failures, "dead_nodes": dead,
               "graph_startup_s": round(startup, 2), "mission_wall_s_median": round(statistics.median(walls), 3),
               "stage_seconds_median": {k: round(statistics.median(v), 3) for k, v in stage_times.items()},
               "cameras": len(result.placements), "coverage": result.coverage,
               "mean_uncertainty": result.mean_uncertainty, "fitness": result.fitness,
               "rss_mb_first_last": {k: [round(v[0], 1), round(v[-1], 1)] for k, v in rss.items() if v},
               "rss_mb_growth_second_half": {k: round(_growth(v), 1) for k, v in rss.items() if v},
               "client_peak_rss_mb": round(peak_rss_mb(), 1)}
        if args.reject and result.success and result.placements:
            out["reject_replan_s"] = _time_rejection(node, result)
        emit(out)
        return 1 if failures or dead else 0


def _growth(values: list[float]) -> float:
    """RSS change over the second half of the missions (the first ones warm caches up)."""
    half = values[len(values) // 2:]
    return half[-1] - half[0] if len(half) > 1 else 0.0


def _time_rejection(node, result) -> float:
    """Reject the first proposal of the last mission; seconds until the replacement arrives."""
    from perch_common.conventions import CONFIRM_SERVICE
    from perch_common.ros.testing import call_service
    from perch_interfaces.msg import Proposal
    from perch_interfaces.srv import Confirm
    from perch_operator.node import LATCHED
    from perch_operator.runner import spin_for

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
