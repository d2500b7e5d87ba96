"""`perch bench up`: the up estimate on every shared real scan in every test orientation, and on a
1M+-face mesh (target < 0.2 s per 1M faces)."""

from __future__ import annotations

import os
import statistics
import time

import numpy as np

from perch_common.bench import emit, peak_rss_mb
from perch_common.cli_types import positive_int

TARGET_S_PER_1M_FACES = 0.2
MAX_ANGLE_DEG = 3.0


def register(sub) -> None:
    """Add `perch bench up` to the CLI."""
    p = sub.add_parser("up", help="up-axis estimate: angle error, sign, confidence, seconds per scan and orientation")
    p.add_argument("--repeats", type=positive_int, default=3, help="timed runs per case (>= 1; the median is reported)")
    p.add_argument("--json", action="store_true", help="print JSON (the only output format)")
    p.set_defaults(func=_run)


def _timed(mesh, repeats: int):
    """(estimate, median seconds) of estimating from the mesh's vertices and faces (no cached face data)."""
    from perch_common.up_axis import estimate_mesh_up

    times, estimate = [], None
    for _ in range(max(1, repeats)):
        mesh._cache.clear()
        start = time.perf_counter()
        estimate = estimate_mesh_up(mesh)
        times.append(time.perf_counter() - start)
    return estimate, statistics.median(times)


def _case(scan: str, orientation: str, mesh, true_up: np.ndarray, repeats: int) -> dict:
    estimate, seconds = _timed(mesh, repeats)
    cos = float(np.clip(estimate.up @ true_up, -1.0, 1.0))
    return {"scan": scan, "orientation": orientation, "faces": mesh.num_faces,
            "angle_error_deg": round(float(np.degrees(np.arccos(abs(cos)))), 3),
            "sign": "right" if cos > 0 else "WRONG", "confidence": round(estimate.confidence, 3),
            "confident": estimate.confident, "seconds": round(seconds, 4)}


def _run(args) -> int:
    import trimesh

    from perch_common.data import shared_file
    from perch_common.mesh import Mesh, load_mesh
    from perch_common.scan_orientations import ORIENTATIONS, REAL_SCANS, oriented

    cases, missing = [], []
    for name, true_up in REAL_SCANS.items():
        path = shared_file("meshes", name)
        if path is None:
            missing.append(name)
            continue
        mesh = load_mesh(path)
        for orientation in ORIENTATIONS:
            rotated, up, _ = oriented(mesh, true_up, orientation)
            cases.append(_case(name, orientation, rotated, up, args.repeats))
    large = None
    if "apartment.ply" not in missing:
        # The apartment subdivided twice (each face into four, twice): 1.6M faces of the same room.
        apartment = load_mesh(shared_file("meshes", "apartment.ply"))
        vertices, faces = trimesh.remesh.subdivide(apartment.vertices, apartment.faces)
        vertices, faces = trimesh.remesh.subdivide(vertices, faces)
        big, up, _ = oriented(Mesh(vertices, faces), REAL_SCANS["apartment.ply"], "tilt-35")
        large = _case("apartment.ply subdivided", "tilt-35", big, up, args.repeats)
        large["seconds_per_1m_faces"] = round(large["seconds"] * 1e6 / big.num_faces, 4)
    worst = max((c["angle_error_deg"] for c in cases), default=None)
    result = {
        "cases": cases, "large_mesh": large, "missing_scans": missing,
        "summary": {"cases": len(cases), "max_angle_error_deg": worst,
                    "sign_errors": sum(c["sign"] != "right" for c in cases),
                    "not_confident": sum(not c["confident"] for c in cases),
                    "all_within_target": bool(cases) and worst <= MAX_ANGLE_DEG
                    and all(c["sign"] == "right" for c in cases)},
        "targets": {"angle_error_deg": MAX_ANGLE_DEG, "seconds_per_1m_faces": TARGET_S_PER_1M_FACES},
        "peak_rss_mb": peak_rss_mb(),
        "load_average_1min": round(os.getloadavg()[0], 2)}  # seconds mean little on a busy machine
    return emit(result)
