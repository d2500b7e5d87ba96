"""Camera viewpoints a mesh was observed from, and the space they observed free.

A reconstructed mesh (RGB-D frames with poses) carries the camera views it was built from
(`Mesh.viewpoints`, `TriangleMesh.viewpoints`): one row of VIEWPOINT_COLUMNS numbers per view,
  centre x y z      the camera centre in the mesh's frame (m),
  axis x y z        its unit optical axis,
  range             the farthest depth it measured (the sensor's depth_max, m),
  half angle        the half angle (deg) of the cone inscribed in its image (the smaller half field of view).
A point p is observed free when some view sees through it: p lies in the view's cone within its
range, the ray from the camera towards p meets no surface before p, and it meets one beyond p within
the range (the camera measured something behind p, so the space up to it was seen empty). A bare
mesh (a file) has no viewpoints; mesh formats cannot hold them, so `perch reconstruct -o room.ply` writes
them beside the file (room.ply.viewpoints.json, below) and load_mesh reads them back for that geometry.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

VIEWPOINT_COLUMNS = 8
CENTRE, AXIS, RANGE, HALF_ANGLE = slice(0, 3), slice(3, 6), 6, 7
MAX_VIEWPOINTS = 256          # a mesh keeps at most this many views (a few kB in every message)
DISTINCT_METRES = 0.15        # a view is new when its centre moved this far from every kept one ...
DISTINCT_DEGREES = 15.0       # ... or its axis turned this far
VIEWS_PER_POINT = 16          # rays cast per point (spread over the views whose cone holds it)
BEHIND_TOLERANCE = 0.01       # m: a surface this little before the point still lets the view through


def viewpoint_rows(centres: np.ndarray, axes: np.ndarray, depth_range: float | np.ndarray,
                   half_angle_deg: float | np.ndarray) -> np.ndarray:
    """(K, VIEWPOINT_COLUMNS) rows of camera centres (K,3), optical axes (K,3, normalised here),
    ranges and cone half angles (scalars or (K,))."""
    centres = np.asarray(centres, np.float64).reshape(-1, 3)
    axes = np.asarray(axes, np.float64).reshape(-1, 3)
    norm = np.linalg.norm(axes, axis=1, keepdims=True)
    axes = np.divide(axes, norm, out=np.zeros_like(axes), where=norm > 0)
    rows = np.empty((len(centres), VIEWPOINT_COLUMNS))
    rows[:, CENTRE], rows[:, AXIS] = centres, axes
    rows[:, RANGE], rows[:, HALF_ANGLE] = depth_range, half_angle_deg
    return rows


def pinhole_half_angle(width: int, height: int, fx: float, fy: float) -> float:
    """Half angle (deg) of the cone inscribed in a pinhole image: the smaller half field of view."""
    return float(np.degrees(min(np.arctan(0.5 * width / fx), np.arctan(0.5 * height / fy))))


def select_viewpoints(rows: np.ndarray, limit: int = MAX_VIEWPOINTS) -> np.ndarray:
    """The distinct views of a trajectory (in order): a view is kept when its centre is DISTINCT_METRES
    from every kept one or its axis DISTINCT_DEGREES from theirs; then at most `limit`, evenly spread."""
    rows = np.asarray(rows, np.float64).reshape(-1, VIEWPOINT_COLUMNS)
    if len(rows) == 0:
        return rows
    cos_limit = np.cos(np.radians(DISTINCT_DEGREES))
    kept = [0]
    for i in range(1, len(rows)):
        near = np.linalg.norm(rows[kept, CENTRE] - rows[i, CENTRE], axis=1) < DISTINCT_METRES
        aligned = rows[kept, AXIS] @ rows[i, AXIS] > cos_limit
        if not (near & aligned).any():
            kept.append(i)
    kept = np.array(kept)
    if len(kept) > limit:
        kept = kept[np.linspace(0, len(kept) - 1, limit).round().astype(int)]
    return rows[kept]


def transform_viewpoints(rows: np.ndarray, matrix: np.ndarray) -> np.ndarray:
    """Views under a 4x4 rigid transform (centres moved, axes turned)."""
    r, t = matrix[:3, :3], matrix[:3, 3]
    out = np.array(rows, np.float64).reshape(-1, VIEWPOINT_COLUMNS)
    out[:, CENTRE] = out[:, CENTRE] @ r.T + t
    out[:, AXIS] = out[:, AXIS] @ r.T
    return out


def moved_viewpoints(rows: np.ndarray, scale: float, shift: np.ndarray | None = None) -> np.ndarray:
    """Views of a mesh whose coordinates became coordinates * `scale` + `shift` (centres scale and
    move, ranges scale)."""
    out = np.array(rows, np.float64).reshape(-1, VIEWPOINT_COLUMNS)
    out[:, CENTRE] *= scale
    out[:, RANGE] *= scale
    if shift is not None:
        out[:, CENTRE] += shift
    return out


def viewpoint_problem(rows: np.ndarray) -> str | None:
    """What is wrong with views as they travel (flat), or None."""
    flat = np.asarray(rows, np.float64).reshape(-1)
    if flat.size % VIEWPOINT_COLUMNS:
        return (f"viewpoints has {flat.size} numbers, not a multiple of {VIEWPOINT_COLUMNS} "
                "(centre x y z, axis x y z, range, half angle per view)")
    rows = flat.reshape(-1, VIEWPOINT_COLUMNS)
    if not np.isfinite(rows).all():
        return "viewpoints holds NaN or infinite numbers"
    if len(rows) and np.abs(np.linalg.norm(rows[:, AXIS], axis=1) - 1).max() > 1e-3:
        return "viewpoints: every optical axis must be a unit vector"
    if len(rows) and ((rows[:, RANGE] <= 0).any() or (rows[:, HALF_ANGLE] <= 0).any()
                      or (rows[:, HALF_ANGLE] >= 90).any()):
        return "viewpoints: every range must be > 0 m and every half angle in (0, 90) deg"
    return None


def _spread(candidate: np.ndarray, count: int) -> np.ndarray:
    """Of each row's True entries, at most `count`, evenly spread over them (deterministic)."""
    rank = np.cumsum(candidate, axis=1) - 1
    total = candidate.sum(axis=1, keepdims=True)
    slot = rank * count // np.maximum(total, 1)
    previous = np.where(rank > 0, (rank - 1) * count // np.maximum(total, 1), -1)
    return candidate & (slot != previous)


def seen_free(scene, rows: np.ndarray, points: np.ndarray, views_per_point: int = VIEWS_PER_POINT,
              chunk: int = 4096) -> np.ndarray:
    """(N,) whether some view observed each point free (module doc). `scene` is a
    perch_common.raycast.RayScene of the mesh; at most `views_per_point` rays a point."""
    points = np.asarray(points, np.float64).reshape(-1, 3)
    rows = np.asarray(rows, np.float64).reshape(-1, VIEWPOINT_COLUMNS)
    out = np.zeros(len(points), bool)
    if len(points) == 0 or len(rows) == 0:
        return out
    cos_half = np.cos(np.radians(rows[:, HALF_ANGLE]))
    for start in range(0, len(points), chunk):
        p = points[start:start + chunk]
        delta = p[:, None, :] - rows[None, :, CENTRE]                 # (P, K, 3)
        dist = np.linalg.norm(delta, axis=2)
        along = np.einsum("pkc,kc->pk", delta, rows[:, AXIS])
        candidate = (dist > 1e-6) & (dist < rows[None, :, RANGE]) & (along >= cos_half[None] * dist)
        pi, ki = np.nonzero(_spread(candidate, views_per_point))
        if not len(pi):
            continue
        hits = scene.cast(rows[ki, CENTRE], delta[pi, ki] / dist[pi, ki, None])
        through = (hits.distance >= dist[pi, ki] - BEHIND_TOLERANCE) & (hits.distance <= rows[ki, RANGE])
        seen = np.zeros(len(p), bool)
        seen[pi[through]] = True
        out[start:start + chunk] = seen
    return out


# --- beside a mesh file ------------------------------------------------------------------------
# Mesh formats cannot hold viewpoints: `perch reconstruct -o room.ply` writes them beside the file
# (room.ply.viewpoints.json) with a fingerprint of the geometry they belong to; load_mesh attaches them
# only to that geometry (a file edited or replaced since is loaded bare: judged by the escape rule).

SIDECAR_SUFFIX = ".viewpoints.json"
FINGERPRINT_TOLERANCE = 1e-4   # m per vertex, mean: a text format (OBJ) rounds coordinates


def sidecar_path(mesh_path) -> Path:
    """Where the viewpoints of a mesh file live."""
    mesh_path = Path(mesh_path)
    return mesh_path.with_name(mesh_path.name + SIDECAR_SUFFIX)


def _fingerprint(vertices: np.ndarray, faces: np.ndarray) -> dict:
    import hashlib

    return {"vertices": int(len(vertices)), "faces_blake2b": hashlib.blake2b(
                np.ascontiguousarray(faces, np.int64).tobytes(), digest_size=16).hexdigest(),
            "vertex_mean": np.asarray(vertices, np.float64).mean(axis=0).tolist() if len(vertices) else [0, 0, 0],
            "vertex_abs_mean": float(np.abs(np.asarray(vertices, np.float64)).mean()) if len(vertices) else 0.0}


def write_viewpoints_beside(mesh_path, vertices: np.ndarray, faces: np.ndarray, rows: np.ndarray) -> Path:
    """Write the viewpoints of the mesh saved at mesh_path (atomically) with its geometry's fingerprint."""
    import json

    from perch_common.outputs import atomic_path

    path = sidecar_path(mesh_path)
    text = json.dumps({"format": "perch viewpoints 1", "columns": "centre x y z, axis x y z, range m, half angle deg",
                       "geometry": _fingerprint(vertices, faces),
                       "viewpoints": np.asarray(rows, np.float64).reshape(-1, VIEWPOINT_COLUMNS).tolist()})
    with atomic_path(path) as temporary:
        temporary.write_text(text)
    return path


def read_viewpoints_beside(mesh_path, vertices: np.ndarray, faces: np.ndarray) -> np.ndarray | None:
    """The viewpoints written beside mesh_path for this geometry (vertices as in the file), else None."""
    import json

    path = sidecar_path(mesh_path)
    if not path.is_file():
        return None
    try:
        data = json.loads(path.read_text())
        stored, rows = data["geometry"], np.asarray(data["viewpoints"], np.float64)
    except (ValueError, KeyError, TypeError, OSError):
        return None   # not ours or damaged: the mesh is judged bare
    now = _fingerprint(vertices, faces)
    same = (stored.get("vertices") == now["vertices"] and stored.get("faces_blake2b") == now["faces_blake2b"]
            and np.allclose(stored.get("vertex_mean"), now["vertex_mean"], atol=FINGERPRINT_TOLERANCE)
            and abs(stored.get("vertex_abs_mean", -1) - now["vertex_abs_mean"]) <= FINGERPRINT_TOLERANCE)
    if not same or viewpoint_problem(rows) is not None:
        return None
    return rows.reshape(-1, VIEWPOINT_COLUMNS)
