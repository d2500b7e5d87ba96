"""`perch bench filter --mesh PATH | --scene SEED [--json]`: time the filtering stage, score it on scenes.

--mesh segments the mesh first (perch_segmentation) and times only the filter. --scene filters a
generated scene's ground-truth surfaces (doors and windows left out) and scores the output with
the independent checker in perch_filtering's test folder (precision, recall).
"""

from __future__ import annotations

import importlib
import os
import resource
import statistics
import sys
import time
from pathlib import Path

import numpy as np

from perch_common.bench import emit, peak_rss_mb
from perch_common.cli_types import non_negative_int, positive_float, positive_int


def register(sub) -> None:
    """Add `perch bench filter`: time the filtering stage and score it on generated scenes."""
    p = sub.add_parser("filter", help="time the filtering stage (and score it on generated scenes)")
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--mesh", help="mesh file; segmented first, only the filter is timed")
    src.add_argument("--scene", type=non_negative_int, metavar="SEED", help="generated scene with ground truth")
    p.add_argument("--kind", default="apartment", help="scene kind for --scene")
    p.add_argument("--holes", type=non_negative_int, default=0, help="holes cut into the scene's walls (>= 0)")
    p.add_argument("--target-mesh", help="target footprint (default for --mesh: MESH_target.ply beside it)")
    p.add_argument("--target-height", type=positive_float, default=1.2, help="footprint extrusion (m, > 0)")
    p.add_argument("--repeats", type=positive_int, default=5, help="timed runs (>= 1) after one warm-up run")
    p.add_argument("--no-score", action="store_true", help="--scene: skip precision/recall")
    p.add_argument("--json", action="store_true", help="print JSON (the only output format)")
    p.set_defaults(func=run)


def run(args) -> int:
    """Run the filter benchmark; prints JSON."""
    from perch_common.memory import KEEP_FREED_MEMORY
    from perch_common.raycast import RayScene
    from perch_filtering.core import FilterConfig, filter_surfaces

    config = FilterConfig()
    info: dict = {"benchmark": "filter"}
    if args.mesh:
        mesh, surfaces, target, up = _mesh_case(args, info)
    else:
        scene, surfaces = _scene_case(args, info)
        mesh, target, up = scene.mesh, scene.target, scene.up
    RayScene(mesh)  # Open3D's one-off initialisation is not part of the stage
    first = time.perf_counter()
    with KEEP_FREED_MEMORY:   # as the node's calls run (perch_common.ros.service)
        result = filter_surfaces(mesh, surfaces, target, up, config)
    info["seconds_first"] = time.perf_counter() - first
    times, cpu = [], []
    for _ in range(max(args.repeats, 1)):
        start, start_cpu = time.perf_counter(), _cpu_with_children()
        with KEEP_FREED_MEMORY:
            result = filter_surfaces(mesh, surfaces, target, up, config)
        times.append(time.perf_counter() - start)
        cpu.append(_cpu_with_children() - start_cpu)
    # cpu_seconds: the machine is shared; wall time alone overstates the stage's cost under load. It
    # includes the second process's (the filter's forked helper, once it has ended).
    info.update(seconds=statistics.median(times), seconds_all=times, cpu_seconds=statistics.median(cpu),
                second_process=result.second_process,
                load_average=list(os.getloadavg()), faces=mesh.num_faces,
                surfaces=len(surfaces), regions=len(result.regions),
                area_m2=float(sum(r.area for r in result.regions)),
                removed_m2=result.removed_area(), stage_timings=result.timings, message=result.message)
    if args.scene is not None and not args.no_score:
        info.update(_score(scene, surfaces, result, config))
    info["peak_rss_mb"] = peak_rss_mb()
    # The largest forked helper's peak RSS, the pages it shares with this process included.
    info["second_process_peak_rss_mb"] = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024.0
    return emit(info)


def _cpu_with_children() -> float:
    """CPU seconds of this process and of its children that have ended."""
    own, children = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime


def _mesh_case(args, info: dict):
    from perch_common.mesh import load_mesh
    from perch_common.target import TargetVolume
    from perch_filtering.cli import segment_surfaces

    mesh = load_mesh(args.mesh)
    target_path = Path(args.target_mesh) if args.target_mesh else Path(args.mesh).with_name(
        Path(args.mesh).stem + "_target.ply")
    if not target_path.is_file():
        raise ValueError(f"target footprint {target_path} not found: give --target-mesh")
    target = TargetVolume.from_footprint_mesh(load_mesh(target_path), args.target_height)
    start = time.perf_counter()
    surfaces = segment_surfaces(mesh)
    info.update(mesh=str(args.mesh), segment_seconds=time.perf_counter() - start)
    return mesh, surfaces, target, np.array([0.0, 0.0, 1.0])


def _scene_case(args, info: dict):
    from perch_common.scene_generator import generate_scene

    scene = generate_scene(args.scene, args.kind, holes=args.holes)
    accuracy = _accuracy_module()
    surfaces = accuracy.filter_input_surfaces(scene) if accuracy else scene.ground_truth_surfaces()
    info.update(scene=args.scene, kind=args.kind, holes=args.holes)
    return scene, surfaces


def _score(scene, surfaces, result, config) -> dict:
    accuracy = _accuracy_module()
    if accuracy is None:
        return {"precision": None, "recall": None, "note": "checker not found (perch_filtering/test)"}
    return accuracy.evaluate(scene, surfaces, result, accuracy.spec_from(config))


def _accuracy_module():
    """The independent checker lives with the tests (source checkout only)."""
    test_dir = Path(__file__).resolve().parents[1] / "test"
    if not (test_dir / "filtering_accuracy.py").is_file():
        return None
    if str(test_dir) not in sys.path:
        sys.path.insert(0, str(test_dir))
    return importlib.import_module("filtering_accuracy")
