"""`perch bench memory`: does every stage node give its memory back after a very large request?

Launches the graph (every node its own process), sends the stage chain (crop, clean, segment,
filter, optimise) one generated apartment (first-use imports and code paths loaded), samples each
node's RSS, then sends the chain a mesh of at least `--faces` faces (stacked copies of it), sampling
every node's RSS while it works (peak) and a moment after its reply (after). Stage nodes release
freed buffers after each call (perch_common.memory); the target is RSS back within 20 % of the
pre-request level.

The per-process mesh cache (PERCH_MESH_CACHE_MB) keeps the meshes a node received, by design,
up to its budget. `--mesh-cache-mb 0` (the default here) disables it in the graph so that the
figures measure the release of request buffers; with `--mesh-cache-mb 2048` (the nodes' default)
each node keeps the big mesh, and `ratio` is (after - what the cache holds of it) / before, with
`mesh_cache_holds_mb` from cached_mesh_mb.

    perch bench memory --faces 2000000 --json
"""

from __future__ import annotations

import os
import tempfile
import threading
import time
from pathlib import Path

SETTLE = 1.5          # s after a reply before sampling (the node frees memory 0.2 s after replying)
TOLERANCE = 0.20      # RSS after / before - 1
SAMPLE_PERIOD = 0.1   # s between RSS samples while a stage works
STOREY = 3.2          # m between the stacked copies of the apartment (its ceiling is at 2.9 m)


def big_scene(faces: int):
    """At least `faces` faces: the generated apartment, subdivided until one copy holds a quarter of them
    (at least once), stacked in storeys 3.2 m apart, with the ground floor's target. A stack keeps the
    filter's occupancy grid (bounding box / voxel size) small."""
    import numpy as np
    import trimesh

    from perch_common.mesh import Mesh
    from perch_common.scene_generator import generate_scene

    scene = generate_scene(7, "apartment")
    vertices, triangles = trimesh.remesh.subdivide(scene.mesh.vertices, scene.mesh.faces)
    while len(triangles) < faces / 4:
        vertices, triangles = trimesh.remesh.subdivide(vertices, triangles)
    copies = max(1, -(-faces // len(triangles)))
    offsets = np.arange(copies)[:, None, None] * np.array([0.0, 0.0, STOREY])
    tiled_vertices = (vertices[None] + offsets).reshape(-1, 3)
    tiled_faces = (triangles[None] + (np.arange(copies) * len(vertices))[:, None, None]).reshape(-1, 3)
    return Mesh(tiled_vertices, tiled_faces), scene.target


def cached_mesh_mb(mesh) -> float:
    """What a node's mesh cache holds of a mesh it received: float64 vertices, int64 faces and the face
    cross products (24 bytes per face) a stage computes for face areas and normals and keeps with it."""
    return (mesh.vertices.nbytes + mesh.faces.nbytes + 24 * mesh.num_faces) / 2**20


def register(sub) -> None:
    """`perch bench memory`."""
    from perch_common.cli_types import non_negative_float, positive_int

    p = sub.add_parser("memory", help="node RSS before, during and after a very large request to every stage")
    p.add_argument("--faces", type=positive_int, default=2_000_000, help="at least this many faces (>= 1)")
    p.add_argument("--mesh-cache-mb", type=non_negative_float, default=0.0,
                   help="the graph's PERCH_MESH_CACHE_MB (>= 0; default 0: cache off, measure request buffers only)")
    p.add_argument("--json", action="store_true", help="JSON on stdout (always)")
    p.set_defaults(func=_run)


class RssSampler:
    """Every graph process's RSS in MB, now and at its highest since `reset_peaks` (a sampling thread)."""

    def __init__(self, pids: dict[str, int]):
        import psutil

        self._processes = {name: psutil.Process(pid) for name, pid in pids.items()}
        self.peaks = {name: 0.0 for name in pids}
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._thread = threading.Thread(target=self._loop, daemon=True)

    def now(self) -> dict[str, float]:
        """Node name -> RSS in MB (0 for a process that exited)."""
        import psutil

        values = {}
        for name, process in self._processes.items():
            try:
                values[name] = process.memory_info().rss / 2**20
            except psutil.NoSuchProcess:
                values[name] = 0.0
        return values

    def _loop(self) -> None:
        while not self._stop.wait(SAMPLE_PERIOD):
            sample = self.now()
            with self._lock:
                self.peaks = {name: max(self.peaks[name], value) for name, value in sample.items()}

    def reset_peaks(self) -> None:
        """Start the peaks again from the current levels."""
        sample = self.now()
        with self._lock:
            self.peaks = dict(sample)

    def __enter__(self) -> "RssSampler":
        self.reset_peaks()
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join()


def _chain(node, mesh_msg, target_msg, call) -> None:
    """Crop, clean, segment, filter and optimise on one mesh, each request to its node; `call(stage,
    node_name, srv_type, service, request)` sends one and returns the reply."""
    import numpy as np

    from perch_common.ros.conversions import is_id_only, vector_msg
    from perch_interfaces import srv

    crop = call("crop", "perch_operator", srv.Crop, "perch/crop", srv.Crop.Request(mesh=mesh_msg, target=target_msg))
    if is_id_only(crop.mesh):   # crop kept every face and named the mesh it was sent
        crop.mesh = mesh_msg
    call("clean", "perch_reconstruction", srv.CleanMesh, "perch/clean_mesh",
         srv.CleanMesh.Request(mesh=mesh_msg, gravity=vector_msg(np.array([0.0, 0.0, -1.0]))))
    segment = call("segment", "perch_segmentation", srv.Segment, "perch/segment", srv.Segment.Request(mesh=crop.mesh))
    filtered = call("filter", "perch_filtering", srv.Filter, "perch/filter",
                    srv.Filter.Request(mesh=crop.mesh, surfaces=segment.surfaces, target=crop.target,
                                       up=vector_msg(np.array([0.0, 0.0, 1.0]))))
    if filtered.regions:
        call("optimise", "perch_placement", srv.Optimise, "perch/optimise",
             srv.Optimise.Request(mesh=mesh_msg, regions=filtered.regions, target=crop.target, num_cameras=3, seed=1))


def _run(args) -> int:
    import rclpy

    from perch_common.bench import emit
    from perch_common.conventions import NODE_SERVICES
    from perch_common.launch import GraphProcesses, use_perch_dds
    from perch_common.ros.conversions import mesh_to_msg, target_to_msg
    from perch_common.ros.testing import call_service, use_isolated_ros_env
    from perch_operator.cli.runner import client_context

    if "ROS_DOMAIN_ID" not in os.environ:
        use_isolated_ros_env()
    else:
        use_perch_dds()
    mesh, target = big_scene(args.faces)
    warm_mesh, _ = big_scene(1)
    logs = Path(tempfile.mkdtemp(prefix="perch_bench_memory_"))
    graph_env = dict(os.environ, PERCH_MESH_CACHE_MB=f"{args.mesh_cache_mb:g}")
    rows: dict[str, dict] = {}
    with client_context(), GraphProcesses(None, list(NODE_SERVICES), log_dir=logs, env=graph_env) as graph:
        node = rclpy.create_node("perch_bench_memory")
        missing = graph.wait_for_services(node, [node.resolve_service_name(s[0]) for s in NODE_SERVICES.values()],
                                          180)
        if missing:
            raise RuntimeError(f"services missing: {missing}; logs in {logs}")

        def warm_call(stage, node_name, srv_type, name, request):
            reply = call_service(node, srv_type, name, request, timeout=1800, wait=30)
            if not reply.success:
                raise RuntimeError(f"warm-up {stage} failed: {reply.message}; logs in {logs}")
            return reply

        # Pre-request level: after the same chain on one apartment (more faces than the clean stage's
        # face target, so it decimates too): every code path and library of first use is loaded.
        _chain(node, mesh_to_msg(warm_mesh), target_to_msg(target), warm_call)
        time.sleep(SETTLE)
        with RssSampler({name: p.pid for name, p in graph.processes.items()}) as rss:
            before = rss.now()

            def call(stage: str, node_name: str, srv_type, name: str, request):
                level = rss.now()[node_name]
                rss.reset_peaks()
                started = time.monotonic()
                reply = call_service(node, srv_type, name, request, timeout=1800, wait=30)
                seconds = time.monotonic() - started
                time.sleep(SETTLE)
                rows[stage] = {"node": node_name, "seconds": round(seconds, 1), "success": bool(reply.success),
                               "message": reply.message[:160], "rss_before_mb": round(level, 1),
                               "rss_peak_mb": round(rss.peaks[node_name], 1),
                               "rss_after_mb": round(rss.now()[node_name], 1)}
                return reply

            _chain(node, mesh_to_msg(mesh), target_to_msg(target), call)
            time.sleep(SETTLE)
            end = rss.now()
        dead = [n for n, ok in graph.alive().items() if not ok]
    cached = cached_mesh_mb(mesh) if cached_mesh_mb(mesh) <= args.mesh_cache_mb else 0.0
    nodes = {}
    for name in before:
        peak = max([before[name], end[name]] + [r["rss_peak_mb"] for r in rows.values() if r["node"] == name])
        nodes[name] = {"rss_before_mb": round(before[name], 1), "rss_peak_mb": round(peak, 1),
                       "rss_after_mb": round(end[name], 1), "ratio": round((end[name] - cached) / before[name], 3)}
    worst = max((n["ratio"] for n in nodes.values()), default=0.0)
    failed = [stage for stage, row in rows.items() if not row["success"]]
    emit({"faces": mesh.num_faces, "warm_up_faces": warm_mesh.num_faces, "mesh_cache_mb": args.mesh_cache_mb,
          "mesh_cache_holds_mb": round(cached, 1), "nodes": nodes, "stages": rows, "worst_ratio": worst,
          "tolerance": 1 + TOLERANCE, "failed_stages": failed, "dead_nodes": dead,
          "load_average_1min": round(os.getloadavg()[0], 2), "logs": str(logs)})
    return 0 if worst <= 1 + TOLERANCE and not dead and not failed and "optimise" in rows else 1
