"""Quality figures: trajectory error after rigid alignment, Chamfer distance between meshes."""

from __future__ import annotations

import numpy as np

from perch_common.mesh import Mesh
from perch_common.raycast import RayScene


def rigid_alignment(source: np.ndarray, target: np.ndarray) -> np.ndarray:
    """4x4 rigid transform (no scale) minimising |T(source) - target| (Umeyama/Kabsch)."""
    source, target = np.asarray(source, np.float64), np.asarray(target, np.float64)
    if len(source) != len(target) or len(source) < 3:
        raise ValueError(f"need >= 3 matched positions, got {len(source)} and {len(target)}")
    mu_s, mu_t = source.mean(axis=0), target.mean(axis=0)
    u, _, vt = np.linalg.svd((target - mu_t).T @ (source - mu_s))
    d = np.eye(3)
    d[2, 2] = np.sign(np.linalg.det(u @ vt))
    out = np.eye(4)
    out[:3, :3] = u @ d @ vt
    out[:3, 3] = mu_t - out[:3, :3] @ mu_s
    return out


def match_trajectories(estimated: list, reference: list, tolerance_ns: int = 1_000_000) -> tuple[np.ndarray, np.ndarray]:
    """Positions of (stamp, 4x4) pairs present in both lists (stamps within tolerance)."""
    ref = {int(s): p for s, p in reference}
    stamps = np.array(sorted(ref))
    est_pos, ref_pos = [], []
    for stamp, pose in estimated:
        if not len(stamps):
            break
        i = int(np.clip(np.searchsorted(stamps, stamp), 0, len(stamps) - 1))
        best = min((j for j in (i - 1, i) if 0 <= j < len(stamps)), key=lambda j: abs(stamps[j] - stamp))
        if abs(stamps[best] - stamp) <= tolerance_ns:
            est_pos.append(pose[:3, 3])
            ref_pos.append(ref[int(stamps[best])][:3, 3])
    return np.array(est_pos).reshape(-1, 3), np.array(ref_pos).reshape(-1, 3)


def ate_rmse(estimated: list, reference: list) -> tuple[float, np.ndarray]:
    """Absolute trajectory error RMSE (m) after the best rigid alignment, and that alignment
    (reference-from-estimated)."""
    est, ref = match_trajectories(estimated, reference)
    align = rigid_alignment(est, ref)
    aligned = est @ align[:3, :3].T + align[:3, 3]
    return float(np.sqrt(((aligned - ref) ** 2).sum(axis=1).mean())), align


def sample_surface(mesh: Mesh, count: int, seed: int) -> np.ndarray:
    """Area-weighted uniform samples on the mesh surface."""
    rng = np.random.default_rng(seed)
    areas = mesh.face_areas()
    faces = rng.choice(mesh.num_faces, size=count, p=areas / areas.sum())
    r1, r2 = rng.random(count), rng.random(count)
    flip = r1 + r2 > 1
    r1[flip], r2[flip] = 1 - r1[flip], 1 - r2[flip]
    t = mesh.triangles()[faces]
    return t[:, 0] + r1[:, None] * (t[:, 1] - t[:, 0]) + r2[:, None] * (t[:, 2] - t[:, 0])


def chamfer_distance(a: Mesh, b: Mesh, samples: int = 100_000, seed: int = 0) -> float:
    """Mean symmetric surface-to-surface distance (m): (mean d(a->b) + mean d(b->a)) / 2."""
    da = RayScene(b).closest_points(sample_surface(a, samples, seed))[2]
    db = RayScene(a).closest_points(sample_surface(b, samples, seed + 1))[2]
    return float(0.5 * (da.mean() + db.mean()))


def refine_alignment(source: Mesh, target: Mesh, initial: np.ndarray, max_distance: float = 0.05,
                     samples: int = 50_000, seed: int = 0) -> np.ndarray:
    """Point-to-plane ICP of source onto target surface samples, from `initial` (4x4 target-from-source).

    The trajectory alignment fixes the gauge only up to how well positions constrain rotation;
    comparing surfaces needs the surfaces aligned (as in standard reconstruction evaluation)."""
    from perch_common.open3d_loader import open3d
    o3d = open3d()

    def cloud(mesh: Mesh, s: int) -> "o3d.geometry.PointCloud":
        pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(sample_surface(mesh, samples, s)))
        pc.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=4 * max_distance, max_nn=30))
        return pc

    result = o3d.pipelines.registration.registration_icp(
        cloud(source, seed), cloud(target, seed + 1), max_distance, np.asarray(initial, np.float64),
        o3d.pipelines.registration.TransformationEstimationPointToPlane(),
        o3d.pipelines.registration.ICPConvergenceCriteria(max_iteration=30))
    return np.asarray(result.transformation)
