"""Independent checker of the safety model on real scans (no ground truth; shares no code with the filter).

Perch centres on a plane (point, unit normal into free space) are judged by direct geometric tests
on the mesh alone: exact triangle-box overlap (separating axes) for the approach prism and the fall
corridor, ray casts for support and visibility, closest points for the standoff clearance.
  approach  no triangle overlaps window + approach_margin x [START, approach_distance] along the normal;
  fall      walls: no triangle in the corridor (window width + 2 approach_margin) x [START, 2 rho]
            out x from min_recovery_height below the window's bottom to its top; ceilings: none in
            the column (window + approach_margin on every side) x [START, min_recovery_height] below;
            the window's bottom (walls) or the perch (ceilings) at least min_recovery_height above
            the floor;
  support   of a 21 x 21 grid over the window, at least min_support - SUPPORT_SLACK find their first
            mesh hit (cast from START + 1 cm) within plane_tolerance of the window's perch plane (at
            the median of the hits within plane_tolerance + max_support_rms of the plane), RMS
            distance to it <= max_support_rms (the slack: two grids of 21 and 25 steps over one
            ragged window disagree by up to ~3 points);
  sight     at least min_visible_share of the target's sample points seen (not behind the plane) from
            the perch seated on its perch plane;
  reach     the standoff point in front of the seated perch is at least a drone radius from the mesh.
START (7 cm): geometry nearer the plane than surface_depth (6 cm) is taken for the scanned surface
itself (the support test bounds what the window's own surface may do), plus 1 cm for faces that
cross a box's side between the filter's mesh samples (5 cm apart).
"""

from __future__ import annotations

import numpy as np
from filtering_checker import Spec, local_plane_support, surface_kind, triangles_overlap_box, window_grid

from perch_common.mesh import Mesh
from perch_common.raycast import RayScene
from perch_common.target import TargetVolume

SUPPORT_SLACK = 0.03


class ScanOracle:
    """The safety model on a real scan, perch by perch."""

    def __init__(self, mesh: Mesh, target: TargetVolume, up: np.ndarray, spec: Spec):
        self.mesh, self.spec = mesh, spec
        self.up = np.asarray(up, np.float64) / np.linalg.norm(up)
        self.rays = RayScene(mesh)
        self.tris = mesh.triangles()
        self.centroids = self.tris.mean(axis=1)
        self.radii = np.linalg.norm(self.tris - self.centroids[:, None], axis=2).max(axis=1)
        self.floor = float(np.percentile(mesh.vertices @ self.up, 1.0))  # the scan's floor level
        self.target_points = target.sample(spec.visibility_points, seed=spec.seed)
        self.start = spec.surface_depth + 0.01

    def frame(self, normal: np.ndarray) -> np.ndarray:
        """Rows u, v, n: v along up projected on the plane (walls), else any in-plane pair."""
        n = normal / np.linalg.norm(normal)
        v = self.up - (self.up @ n) * n
        if np.linalg.norm(v) < 0.3:
            v = np.cross(n, [1.0, 0, 0]) if abs(n[0]) < 0.9 else np.cross(n, [0, 1.0, 0])
        v /= np.linalg.norm(v)
        return np.stack([np.cross(v, n), v, n])

    def kind(self, normal: np.ndarray) -> str:
        """'wall', 'ceiling', 'floor' or 'intermediate' by the spec's class angle."""
        return surface_kind(normal, self.up, self.spec.class_angle_deg)

    def box_free(self, centre: np.ndarray, axes: np.ndarray, half: np.ndarray) -> bool:
        """No mesh triangle overlaps the box centre + axes.T @ [-half, half]."""
        near = np.linalg.norm(self.centroids - centre, axis=1) <= np.linalg.norm(half) + self.radii
        if not near.any():
            return True
        local = np.einsum("fvk,ak->fva", self.tris[near] - centre, axes)
        return not triangles_overlap_box(local, half).any()

    def approach_free(self, point: np.ndarray, normal: np.ndarray) -> bool:
        """The approach prism in front of the perch is free."""
        s, axes = self.spec, self.frame(normal)
        half = np.array([s.window_width / 2 + s.approach_margin, s.window_height / 2 + s.approach_margin,
                         (s.approach_distance - self.start) / 2])
        return self.box_free(point + axes[2] * (self.start + s.approach_distance) / 2, axes, half)

    def fall_free(self, point: np.ndarray, normal: np.ndarray) -> bool:
        """The fall corridor (walls) or column (ceilings) is free and high enough above the floor."""
        s, axes = self.spec, self.frame(normal)
        kind = self.kind(normal)
        if kind == "floor":
            return True
        rho, h, margin = s.drone_radius, s.min_recovery_height, s.approach_margin
        if kind == "wall":
            if point @ self.up - s.window_height / 2 - h < self.floor:
                return False
            half = np.array([s.window_width / 2 + margin, (s.window_height + h) / 2, (2 * rho - self.start) / 2])
            centre = point + axes[1] * (-h / 2) + axes[2] * (self.start + 2 * rho) / 2
            return self.box_free(centre, axes, half)
        if point @ self.up - h < self.floor:
            return False
        half = np.array([s.window_width / 2 + margin, s.window_height / 2 + margin, (h - self.start) / 2])
        return self.box_free(point + axes[2] * (self.start + h) / 2, axes, half)

    def support(self, point: np.ndarray, normal: np.ndarray) -> tuple[float, float, float]:
        """Share of the window grid whose first hit lies on the window's perch plane, RMS of those hits
        and the perch plane's offset along the normal (where the drone touches the scan)."""
        axes = self.frame(normal)
        grid = point + window_grid(self.spec, axes[0], axes[1])
        start = self.start + 0.01
        hits = self.rays.cast(grid + start * axes[2], np.repeat(-axes[2][None], len(grid), axis=0))
        depth = np.where(hits.hit, start - hits.distance, np.inf)[:, None]
        share, rms, offset = local_plane_support(depth, self.spec)
        return float(share[0]), float(rms[0]), float(offset[0])

    def visible_share(self, point: np.ndarray, normal: np.ndarray) -> float:
        """Share of the target's sample points seen from 2 cm in front of the perch."""
        origin = point + 0.02 * normal
        t = self.target_points
        facing = (t - origin) @ normal > 0
        seen = np.zeros(len(t), bool)
        seen[facing] = ~self.rays.occluded(np.repeat(origin[None], int(facing.sum()), axis=0), t[facing])
        return float(seen.mean())

    def failures(self, point: np.ndarray, normal: np.ndarray) -> list[str]:
        """The rules a perch at `point` with `normal` breaks (empty: safe)."""
        s = self.spec
        point, normal = np.asarray(point, np.float64), np.asarray(normal, np.float64)
        out = []
        if not self.approach_free(point, normal):
            out.append("approach")
        if not self.fall_free(point, normal):
            out.append("fall")
        share, rms, offset = self.support(point, normal)
        if share < s.min_support - SUPPORT_SLACK or rms > s.max_support_rms + 1e-9:
            out.append(f"support {share:.2f} rms {rms:.3f}")
        seated = point + offset * normal  # the drone sits on the scan, at the window's perch plane
        if self.visible_share(seated, normal) < s.min_visible_share - 1e-9:
            out.append("sight")
        if self.rays.closest_points((seated + s.standoff * normal)[None])[2][0] < s.drone_radius:
            out.append("reach")
        return out
