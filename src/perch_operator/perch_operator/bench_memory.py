"""`perch bench memory`: does every stage node give its memory back after a very large request?

Launches the graph, runs one small mission, samples each node's RSS, sends the whole stage chain (crop, clean, segment,
filter, optimise) a mesh of at least `--faces` faces (copies of the generated apartment), and
samples every node's RSS again a moment after its reply. Stage nodes release freed buffers after
each call (perch_common.memory); the target is RSS back within 20 % of the pre-request level.

    perch bench memory --faces 2000000 --json
"""

from __future__ import annotations

import os
import tempfile
import time
from pathlib import Path

SETTLE = 1.5          # s after a reply before sampling (the node frees memory 0.2 s after replying)
TOLERANCE = 0.20      # RSS after / before - 1


def big_scene(faces: int):
    """At least `faces` faces: copies of the generated apartment (subdivided once) side by side in a row
    of buildings 15 m apart, with the first apartment's target."""
    import numpy as np
    import trimesh

    from perch_common.mesh import Mesh
    from perch_common.scene_generator import generate_scene

    scene = generate_scene(7, "apartment")
    vertices, triangles = trimesh.remesh.subdivide(scene.mesh.vertices, scene.mesh.faces)
    copies = max(1, -(-faces // len(triangles)))
    offsets = np.arange(copies)[:, None, None] * np.array([15.0, 0.0, 0.0])
    tiled_vertices = (vertices[None] + offsets).reshape(-1, 3)
    tiled_faces = (triangles[None] + (np.arange(copies) * len(vertices))[:, None, None]).reshape(-1, 3)
    return Mesh(tiled_vertices, tiled_faces), scene.target


def register(sub) -> None:
    """`perch bench memory`."""
    p = sub.add_parser("memory", help="node RSS before and after a very large request to every stage")
    p.add_argument("--faces", type=int, default=2_000_000, help="at least this many faces")
    p.add_argument("--json", action="store_true", help="JSON on stdout (always)")
    p.set_defaults(func=_run)


def _rss(graph) -> dict[str, float]:
    import psutil

    return {name: psutil.Process(p.pid).memory_info().rss / 2**20 for name, p in graph.processes.items()}


def _run(args) -> int:
    import numpy as np
    import rclpy

    from perch_common.bench import emit
    from perch_common.launch import GraphProcesses, use_fast_liveliness
    from perch_common.ros.conversions import mesh_to_msg, target_to_msg, vector_msg
    from perch_common.ros.testing import call_service, use_isolated_ros_env
    from perch_interfaces import srv
    from perch_operator.runner import NODE_SERVICES, client_context

    if "ROS_DOMAIN_ID" not in os.environ:
        use_isolated_ros_env()
    use_fast_liveliness()
    mesh, target = big_scene(args.faces)
    mesh_msg, target_msg = mesh_to_msg(mesh), target_to_msg(target)
    logs = Path(tempfile.mkdtemp(prefix="perch_bench_memory_"))
    rows: dict[str, dict] = {}
    with client_context(), GraphProcesses(None, list(NODE_SERVICES), log_dir=logs) as graph:
        node = rclpy.create_node("perch_bench_memory")
        missing = graph.wait_for_services(node, [node.resolve_service_name(s[0]) for s in NODE_SERVICES.values()],
                                          180)
        if missing:
            raise RuntimeError(f"services missing: {missing}; logs in {logs}")
        # Pre-request level: after one ordinary mission (imports and caches of first use are loaded).
        from perch_common.scene_generator import generate_scene
        from perch_interfaces.action import PlanPerches
        from perch_operator.client import run_mission

        room = generate_scene(3, "room")
        warm = run_mission(node, PlanPerches.Goal(mesh=mesh_to_msg(room.mesh), target=target_to_msg(room.target),
                                                  num_cameras=2, auto_accept=True, seed=-1), timeout=600)
        if not warm.success:
            raise RuntimeError(f"warm-up mission failed: {warm.message}")
        time.sleep(SETTLE)
        before = _rss(graph)

        def call(stage: str, node_name: str, srv_type, name: str, request):
            started = time.monotonic()
            reply = call_service(node, srv_type, name, request, timeout=1800, wait=30)
            seconds = time.monotonic() - started
            time.sleep(SETTLE)
            after = _rss(graph)[node_name]
            rows[stage] = {"node": node_name, "seconds": round(seconds, 1), "success": bool(reply.success),
                           "message": reply.message[:160], "rss_before_mb": round(before[node_name], 1),
                           "rss_after_mb": round(after, 1),
                           "ratio": round(after / before[node_name], 3)}
            return reply

        crop = call("crop", "perch_operator", srv.Crop, "perch/crop", srv.Crop.Request(mesh=mesh_msg, target=target_msg))
        call("clean", "perch_reconstruction", srv.CleanMesh, "perch/clean_mesh",
             srv.CleanMesh.Request(mesh=mesh_msg, gravity=vector_msg(np.array([0.0, 0.0, -1.0]))))
        segment = call("segment", "perch_segmentation", srv.Segment, "perch/segment",
                       srv.Segment.Request(mesh=crop.mesh))
        filtered = call("filter", "perch_filtering", srv.Filter, "perch/filter",
                        srv.Filter.Request(mesh=crop.mesh, surfaces=segment.surfaces, target=crop.target,
                                           up=vector_msg(np.array([0.0, 0.0, 1.0]))))
        if filtered.regions:
            call("optimise", "perch_placement", srv.Optimise, "perch/optimise",
                 srv.Optimise.Request(mesh=mesh_msg, regions=filtered.regions, target=crop.target, num_cameras=3,
                                      seed=1))
        del crop, segment, filtered
        dead = [n for n, ok in graph.alive().items() if not ok]
    worst = max((r["ratio"] for r in rows.values()), default=0.0)
    emit({"faces": mesh.num_faces, "stages": rows, "worst_ratio": worst, "tolerance": 1 + TOLERANCE,
          "dead_nodes": dead, "logs": str(logs)})
    return 0 if worst <= 1 + TOLERANCE and not dead else 1
