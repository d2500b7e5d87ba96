"""Independent validity oracle for perch points on generated scenes (shares no code with the filter).

It decides from the scene's ground truth (plane normals into free space, solid voxel grid, floor)
and direct geometric tests on the mesh (ray casts, closest points, exact triangle-box overlap),
perch centre by perch centre:
  class      plane class from the ground-truth normal (angle to up) is enabled;
  on plane   the centre lies on its ground-truth plane;
  recovery   the perch window is at least h_min above the floor (walls: its bottom edge) and no
             triangle of other geometry overlaps its fall corridor (separating-axis test): walls,
             the box (window width + 2 approach_margin) x [TOL, 2 rho] in front of the wall from
             h_min below the window's bottom to its top; ceilings, the column (window +
             approach_margin on every side) x [TOL, h_min] below it;
  approach   no triangle of other geometry overlaps the prism (window grown by the lateral margin)
             x [TOL, approach_distance] along the normal (separating-axis test);
  support    of a 21 x 21 grid over the window, at least min_support find their first mesh hit
             (cast from surface_depth + 2 cm in front) within plane_tolerance of the window's perch
             plane, the plane moved to the median of the hits within plane_tolerance +
             max_support_rms of it; RMS distance to that plane <= max_support_rms;
  sight      at least min_visible_share of the target's sample points (the filter's count and seed:
             the target's definition, not the model) are in front of the plane and the segment from
             the centre (offset 2 cm) to them misses the mesh;
  reach      the standoff point is at least rho from the mesh, and its voxel is 6-connected to the
             target volume through voxels whose centre is at least rho from solid voxel centres.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from perch_common.mesh import Mesh
from perch_common.raycast import RayScene
from perch_common.scene_generator import GeneratedScene, SemanticClass
from perch_common.types import PlaneFrame
from perch_filtering.perch_check import (
    CheckSpec,
    local_plane_support,
    surface_kind,
    triangles_overlap_box,
    turned,
    window_grid,
    window_yaws,
)

TOL = 0.01          # m: geometry closer to a plane than this is the plane itself


Spec = CheckSpec  # the safety model's numbers (FilterConfig's names), shared with the scan checker


class SceneOracle:
    def __init__(self, scene: GeneratedScene, spec: Spec):
        self.scene, self.spec = scene, spec
        self.mesh = scene.mesh
        self.rays = RayScene(self.mesh)
        self.up = np.asarray(scene.up, np.float64)
        self.target_points = scene.target.sample(spec.visibility_points, seed=spec.seed)
        floors = [p for p in scene.planes if p.semantic_class == SemanticClass.FLOOR]
        self.floor_z = min(float(p.centroid @ self.up) for p in floors)
        self._others: dict = {}
        self.drone_free = self._reachable_voxels()

    # --- per plane -----------------------------------------------------------------------------
    def plane_class(self, plane_id: int) -> str:
        return surface_kind(self.scene.planes[plane_id].normal, self.up, self.spec.class_angle_deg)

    def enabled(self, plane_id: int) -> bool:
        sem = self.scene.planes[plane_id].semantic_class
        if sem in (SemanticClass.DOOR, SemanticClass.WINDOW):
            return False
        s = self.spec
        return {"wall": s.allow_walls, "ceiling": s.allow_ceiling, "floor": s.allow_floor,
                "intermediate": s.allow_intermediate}[self.plane_class(plane_id)]

    def frame(self, plane_id: int) -> PlaneFrame:
        p = self.scene.planes[plane_id]
        return PlaneFrame.from_normal(p.centroid, p.normal, self.up)

    # --- tests ---------------------------------------------------------------------------------
    def recovery_ok(self, plane_id: int, points: np.ndarray) -> np.ndarray:
        """Floor height and fall corridor of the windows centred on the points (False where the class
        is disabled)."""
        points = np.asarray(points, np.float64).reshape(-1, 3)
        if not self.enabled(plane_id) or len(points) == 0:
            return np.zeros(len(points), bool)
        s, up = self.spec, self.up
        kind = self.plane_class(plane_id)
        if kind == "floor":
            return np.ones(len(points), bool)
        f = self.frame(plane_id)
        h, rho, margin = s.min_recovery_height, s.drone_radius, s.approach_margin
        axes = np.stack([f.axis_u, f.axis_v, f.normal])
        if kind == "ceiling":
            ok = points @ up >= self.floor_z + h
            half = np.array([s.window_width / 2 + margin, s.window_height / 2 + margin, (h - TOL) / 2])
            offset = f.normal * (TOL + h) / 2
        else:
            ok = points @ up - s.window_height / 2 * float(f.axis_v @ up) >= self.floor_z + h
            half = np.array([s.window_width / 2 + margin, (s.window_height + h) / 2, (2 * rho - TOL) / 2])
            offset = f.axis_v * (-h / 2) + f.normal * (TOL + 2 * rho) / 2
        for yaw in window_yaws(kind, s):  # the column turned about the normal: the offset stays
            ok[ok] = boxes_free(self._corridor_triangles(plane_id), points[ok] + offset, turned(axes, yaw), half)
        return ok

    def _corridor_triangles(self, plane_id: int) -> np.ndarray:
        """Triangles of other planes (the fall corridor and column lie in front of and below this one)."""
        key = ("corridor", plane_id)
        if key not in self._others:
            self._others[key] = self.mesh.triangles()[self.scene.face_plane != plane_id]
        return self._others[key]

    def on_plane(self, plane_id: int, points: np.ndarray) -> np.ndarray:
        """Points whose ray along the inverted normal meets their own ground-truth plane right there."""
        n = self.scene.planes[plane_id].normal
        hits = self.rays.cast(points + 0.05 * n, np.repeat(-n[None], len(points), axis=0))
        plane = np.where(hits.hit, self.scene.face_plane[np.maximum(hits.face, 0)], -1)
        return (plane == plane_id) & (np.abs(hits.distance - 0.05) < 0.01)

    def approach_free(self, plane_id: int, points: np.ndarray) -> np.ndarray:
        """No triangle of other geometry overlaps the approach prism in front of each point."""
        s = self.spec
        f = self.frame(plane_id)
        tris = self._other_triangles(plane_id)
        half = np.array([s.window_width / 2 + s.approach_margin, s.window_height / 2 + s.approach_margin,
                         (s.approach_distance - TOL) / 2])
        axes = np.stack([f.axis_u, f.axis_v, f.normal])
        ok = np.ones(len(points), bool)
        for yaw in window_yaws(self.plane_class(plane_id), s):
            ok[ok] = boxes_free(tris, points[ok] + f.normal * (TOL + s.approach_distance) / 2, turned(axes, yaw), half)
        return ok

    def _other_triangles(self, plane_id: int) -> np.ndarray:
        """Triangles of other planes reaching more than TOL in front of this plane."""
        if plane_id not in self._others:
            p = self.scene.planes[plane_id]
            tris = self.mesh.triangles()
            depth = (tris - p.centroid) @ p.normal
            keep = (self.scene.face_plane != plane_id) & (depth.max(axis=1) > TOL)
            self._others[plane_id] = tris[keep]
        return self._others[plane_id]

    def support(self, plane_id: int, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Share of a grid over each window whose first mesh hit lies within plane_tolerance of the
        window's perch plane, and the RMS distance of those hits to it."""
        f = self.frame(plane_id)
        n = self.scene.planes[plane_id].normal
        axes = np.stack([f.axis_u, f.axis_v, f.normal])
        share, rms = np.ones(len(points)), np.zeros(len(points))
        for yaw in window_yaws(self.plane_class(plane_id), self.spec):  # the worst yaw
            u, v = turned(axes, yaw)[:2]
            offsets = window_grid(self.spec, u, v)
            grid = (points[None, :, :] + offsets[:, None, :]).reshape(-1, 3)
            start = self.spec.surface_depth + 0.02
            hits = self.rays.cast(grid + start * n, np.repeat(-n[None], len(grid), axis=0))
            depth = np.where(hits.hit, start - hits.distance, np.inf).reshape(len(offsets), len(points))
            yaw_share, yaw_rms = local_plane_support(depth, self.spec)[:2]
            share, rms = np.minimum(share, yaw_share), np.maximum(rms, yaw_rms)
        return share, rms

    def visible_share(self, points: np.ndarray, normal: np.ndarray) -> np.ndarray:
        """Share of the target's sample points each point sees."""
        t = self.target_points
        origins = np.repeat(points + 0.02 * normal, len(t), axis=0)
        targets = np.tile(t, (len(points), 1))
        facing = (targets - origins) @ normal > 0
        seen = np.zeros(len(origins), bool)
        seen[facing] = ~self.rays.occluded(origins[facing], targets[facing])
        return seen.reshape(len(points), len(t)).mean(axis=1)

    def _voxel(self, points: np.ndarray) -> np.ndarray:
        """Ground-truth voxel index of world points (written out: BLAS matmul is slow under load)."""
        grid = self.scene.free_space
        inv = np.linalg.inv(grid.world_from_grid)
        local = sum(points[:, k, None] * inv[:3, k] for k in range(3)) + inv[:3, 3]
        return np.floor((local - grid.origin) / grid.voxel_size).astype(np.int64)

    def reachable(self, plane_id: int, points: np.ndarray) -> np.ndarray:
        stand = points + self.spec.standoff * self.scene.planes[plane_id].normal
        idx = self._voxel(stand)
        inside = np.all((idx >= 0) & (idx < self.drone_free.shape), axis=1)
        out = np.zeros(len(points), bool)
        out[inside] = self.drone_free[tuple(idx[inside].T)]
        if out.any():
            _, _, distance = self.rays.closest_points(stand[out])
            out[out] = distance >= self.spec.drone_radius
        return out

    def valid(self, plane_id: int, points: np.ndarray) -> np.ndarray:
        """The whole model for perch centres on one plane (cheap tests first, the rest on survivors)."""
        points = np.asarray(points, np.float64).reshape(-1, 3)
        if not self.enabled(plane_id) or len(points) == 0:
            return np.zeros(len(points), bool)
        s = self.spec
        n = self.scene.planes[plane_id].normal
        ok = self.on_plane(plane_id, points)
        for test in (lambda p: self.reachable(plane_id, p), lambda p: self.recovery_ok(plane_id, p),
                     lambda p: self._supported(plane_id, p),
                     lambda p: self.visible_share(p, n) >= s.min_visible_share - 1e-9,
                     lambda p: self.approach_free(plane_id, p)):
            if ok.any():
                ok[ok] = test(points[ok])
        return ok

    def _supported(self, plane_id: int, points: np.ndarray) -> np.ndarray:
        share, rms = self.support(plane_id, points)
        return (share >= self.spec.min_support - 1e-9) & (rms <= self.spec.max_support_rms)

    def _reachable_voxels(self) -> np.ndarray:
        """Voxels whose centre is >= rho from solid voxel centres, 6-connected to the target."""
        grid = self.scene.free_space
        free = ~grid.occupied
        clearance = ndimage.distance_transform_edt(free, sampling=grid.voxel_size)
        fits = free & (clearance >= self.spec.drone_radius)
        labels, _ = ndimage.label(fits)
        idx = self._voxel(self.scene.target.sample(count=3000, seed=1))
        idx = idx[np.all((idx >= 0) & (idx < fits.shape), axis=1)]
        ids = np.unique(labels[tuple(idx.T)])
        return np.isin(labels, ids[ids > 0])


def boxes_free(tris: np.ndarray, centres: np.ndarray, axes: np.ndarray, half: np.ndarray) -> np.ndarray:
    """For each centre (M,3): no triangle (F,3,3) overlaps the box centre + axes.T @ [-half, half]."""
    out = np.ones(len(centres), bool)
    if len(tris) == 0:
        return out
    centroids = tris.mean(axis=1)
    reach = np.linalg.norm(half) + np.linalg.norm(tris - centroids[:, None], axis=2).max(axis=1)
    for k, centre in enumerate(centres):
        near = np.linalg.norm(centroids - centre, axis=1) <= reach
        if near.any():
            local = np.einsum("fvk,ak->fva", tris[near] - centre, axes)
            out[k] = not triangles_overlap_box(local, half).any()
    return out


def sample_plane(scene: GeneratedScene, plane_id: int, spacing: float, rng: np.random.Generator) -> np.ndarray:
    """Uniform random points on a ground-truth plane's faces, about one per spacing^2."""
    faces = np.flatnonzero(scene.face_plane == plane_id)
    areas = scene.mesh.face_areas()[faces]
    count = max(1, int(round(areas.sum() / spacing ** 2)))
    pick = rng.choice(faces, size=count, p=areas / areas.sum())
    return _in_triangles(scene.mesh.triangles()[pick], rng)


def sample_mesh_surface(mesh: Mesh, count: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Uniform random points on a mesh (region meshes) and the face of each."""
    areas = mesh.face_areas()
    pick = rng.choice(mesh.num_faces, size=count, p=areas / areas.sum())
    return _in_triangles(mesh.triangles()[pick], rng), pick


def _in_triangles(tris: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    r1, r2 = rng.random(len(tris)), rng.random(len(tris))
    flip = r1 + r2 > 1
    r1[flip], r2[flip] = 1 - r1[flip], 1 - r2[flip]
    return tris[:, 0] + r1[:, None] * (tris[:, 1] - tris[:, 0]) + r2[:, None] * (tris[:, 2] - tris[:, 0])
