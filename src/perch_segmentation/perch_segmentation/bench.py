"""`perch bench segment --mesh PATH | --scene SEED --json`: speed, memory and accuracy of the stage,
side by side with an Open3D baseline on the same input."""

from __future__ import annotations

import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np

from perch_common.bench import emit, peak_rss_mb
from perch_common.cli_types import non_negative_float, non_negative_int, positive_int, scene_resolution
from perch_common.mesh import Mesh


def register(sub) -> None:
    """Add `perch bench segment`: seconds, peak memory, surfaces and accuracy against a baseline."""
    p = sub.add_parser("segment", help="segmentation: seconds, peak memory, surfaces, accuracy on scenes")
    source = p.add_mutually_exclusive_group(required=True)
    source.add_argument("--mesh", type=Path, help="mesh file (e.g. ../shared/data/meshes/apartment.ply)")
    source.add_argument("--scene", type=non_negative_int, metavar="SEED", help="procedural scene with ground truth")
    p.add_argument("--kind", default="apartment",
                   help="scene kind: room, l_shaped, two_rooms, apartment, building, multi_storey")
    p.add_argument("--noise", type=non_negative_float, default=0.0, help="scene vertex noise sigma (m, >= 0)")
    p.add_argument("--holes", type=non_negative_int, default=0, help="scene: holes cut into walls (>= 0)")
    p.add_argument("--resolution", type=scene_resolution, default=0.1,
                   help="scene face size (m, 0.02-0.5); 0.022 gives ~1M faces")
    p.add_argument("--subdivide", type=non_negative_int, default=0, metavar="N",
                   help="split every face into 4, N times (N >= 0; the apartment twice: 1.6M faces)")
    p.add_argument("--repeats", type=positive_int, default=3,
                   help="timed runs (>= 1; median reported) after one warm-up")
    p.add_argument("--baseline", choices=("patches", "ransac", "none"), default="patches",
                   help="Open3D baseline: planar patch detection (default) or sequential RANSAC")
    p.add_argument("--out", type=Path, default=Path("out/bench/segment"), help="folder for the PNG rendering")
    p.add_argument("--no-render", action="store_true", help="skip the PNG rendering")
    p.add_argument("--json", action="store_true", help="print JSON (the only output format)")
    p.set_defaults(func=run)


def subdivide(mesh: Mesh) -> Mesh:
    """Midpoint subdivision: every face into 4, shared edge midpoints, colours averaged."""
    f, n = mesh.faces, np.int64(mesh.num_vertices)
    ends = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    keys, inverse = np.unique(np.minimum(ends[:, 0], ends[:, 1]) * n + np.maximum(ends[:, 0], ends[:, 1]),
                              return_inverse=True)
    a, b = keys // n, keys % n
    vertices = np.concatenate([mesh.vertices, 0.5 * (mesh.vertices[a] + mesh.vertices[b])])
    colors = None
    if mesh.vertex_colors is not None:
        mid = (mesh.vertex_colors[a].astype(np.uint16) + mesh.vertex_colors[b]) // 2
        colors = np.concatenate([mesh.vertex_colors, mid.astype(np.uint8)])
    m01, m12, m20 = (n + inverse.reshape(3, -1)).astype(np.int64)
    v0, v1, v2 = f[:, 0], f[:, 1], f[:, 2]
    faces = np.concatenate([np.stack(t, 1) for t in ((v0, m01, m20), (v1, m12, m01), (v2, m20, m12), (m01, m12, m20))])
    return Mesh(vertices, faces, colors, frame_id=mesh.frame_id)


def area_fractions(mesh: Mesh, surfaces) -> dict:
    """Share of the mesh area in the largest surfaces."""
    total = float(mesh.face_areas().sum())
    areas = sorted((s.area for s in surfaces), reverse=True)
    return {"top10_area_fraction": sum(areas[:10]) / total, "labelled_area_fraction": sum(areas) / total,
            "mesh_area_m2": total}


def _current_rss_mb() -> float:
    import psutil

    return psutil.Process().memory_info().rss / 2**20


def run(args) -> int:
    """Run the segmentation benchmark; prints JSON."""
    from perch_segmentation.core import SegmentationConfig, segment_mesh
    from perch_segmentation.evaluation import score_scene

    scene = None
    if args.scene is not None:
        from perch_common.scene_generator import generate_scene

        scene = generate_scene(args.scene, args.kind, noise=args.noise, holes=args.holes, resolution=args.resolution)
        mesh, name = scene.mesh, f"scene_{args.kind}_{args.scene}"
        name += f"_res{args.resolution:g}" if args.resolution != 0.1 else ""
        name += f"_noise{args.noise:g}_holes{args.holes}" if (args.noise or args.holes) else ""
    else:
        from perch_common.mesh import load_mesh

        mesh, name = load_mesh(args.mesh), args.mesh.stem
    for _ in range(args.subdivide):
        mesh = subdivide(mesh)
    if args.subdivide:
        name += f"_sub{args.subdivide}"
        if scene is not None:  # ground truth per face carries over to the 4 children
            scene.face_plane = np.tile(scene.face_plane, 4 ** args.subdivide)
    config = SegmentationConfig()
    rss_before = _current_rss_mb()
    result = segment_mesh(mesh, config)  # warm-up (imports, caches); timed below
    walls, cpus = [], []
    for _ in range(max(1, args.repeats)):
        wall, cpu = time.perf_counter(), time.process_time()
        result = segment_mesh(mesh, config)
        walls.append(time.perf_counter() - wall)
        cpus.append(time.process_time() - cpu)
    out = {
        "input": str(args.mesh) if args.mesh else name, "faces": mesh.num_faces, "vertices": mesh.num_vertices,
        "seconds": statistics.median(walls), "seconds_runs": walls, "cpu_seconds": statistics.median(cpus),
        "peak_rss_mb": peak_rss_mb(), "rss_before_segmentation_mb": rss_before,
        "surfaces": len(result.surfaces), "clusters_step1": result.clusters_step1,
        "clusters_step2": result.clusters_step2, "phase_seconds": result.timings,
        **area_fractions(mesh, result.surfaces), "load_average_1min": os.getloadavg()[0],
        "omp_num_threads": os.environ.get("OMP_NUM_THREADS", ""),
    }
    if scene is not None:
        out.update(score_scene(scene, result).as_dict())
        raw = score_scene(scene, result, unite_floor_ceiling=False)
        out["scores_without_uniting_floor_ceiling"] = {"plane_recall": raw.plane_recall,
                                                       "plane_precision": raw.plane_precision}
    if not args.no_render:
        from perch_segmentation.render import render_segmentation

        out["png"] = str(render_segmentation(mesh, result.face_labels, args.out / f"{name}.png"))
    if args.baseline != "none":
        try:
            out["baseline"] = _baseline(args.baseline, mesh, scene)
        except Exception as exc:  # noqa: BLE001 - Open3D raises bare RuntimeErrors (Qhull); ours stand regardless
            out["baseline"] = {"method": args.baseline, "error": f"{type(exc).__name__}: {str(exc).splitlines()[0]}"}
            print(f"baseline {args.baseline} failed: {out['baseline']['error']}", file=sys.stderr)
    return emit(out)


def _baseline(method: str, mesh: Mesh, scene) -> dict:
    from perch_segmentation import baseline
    from perch_segmentation.evaluation import score_planes, unite_boundary_planes

    detect = baseline.planar_patches if method == "patches" else baseline.ransac
    seconds, face_labels, surfaces = detect(mesh)
    block = {"method": {"patches": "open3d PointCloud.detect_planar_patches (defaults)",
                        "ransac": "open3d segment_plane, sequential (0.02 m, >=200 points)"}[method],
             "seconds": seconds, "surfaces": len(surfaces), **area_fractions(mesh, surfaces)}
    if scene is not None:
        normals = np.array([p.normal for p in scene.planes]).reshape(-1, 3)
        scores = score_planes(face_labels, surfaces, unite_boundary_planes(scene.face_plane, scene.planes),
                              normals, mesh.face_areas())
        block.update(scores.as_dict())
    return block
