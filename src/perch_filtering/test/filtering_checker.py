"""Independent validity oracle for perch points on generated scenes (shares no code with the filter).

It decides from the scene's ground truth (plane normals into free space, solid voxel grid, floor)
and direct geometric tests on the mesh (ray casts, closest points, exact triangle-box overlap),
perch centre by perch centre:
  class      plane class from the ground-truth normal (angle to up) is enabled;
  on plane   the centre lies on its ground-truth plane;
  recovery   every point of the perch window is at least h_min above the floor with nothing in its
             fall corridor: walls, the box [0, 2 rho] deep and +-rho wide in front of the wall from
             the point's height down h_min; ceilings, the +-rho square column below it, h_min deep;
  approach   no triangle of other geometry overlaps the prism (window grown by the lateral margin)
             x [TOL, approach_distance] along the normal (separating-axis test);
  support    of a 21 x 21 grid over the window, at least min_support find mesh within
             plane_tolerance of the plane along the normal, with RMS distance <= max_support_rms;
  sight      at least min_visible_share of the target's sample points (the filter's count and seed:
             the target's definition, not the model) are in front of the plane and the segment from
             the centre (offset 2 cm) to them misses the mesh;
  reach      the standoff point is at least rho from the mesh, and its voxel is 6-connected to the
             target volume through voxels whose centre is at least rho from solid voxel centres.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from perch_common.mesh import Mesh
from perch_common.raycast import RayScene
from perch_common.scene_generator import GeneratedScene, SemanticClass
from perch_common.types import PlaneFrame

TOL = 0.01          # m: geometry closer to a plane than this is the plane itself
CORRIDOR_RAYS = 6   # per side of the corridor's top face (5 along the depth of a wall's corridor)
WINDOW_POINTS = 7   # per side of the perch window (recovery)
SUPPORT_POINTS = 21  # per side of the perch window (support: cell centres of a 21 x 21 grid)


def surface_kind(normal: np.ndarray, up: np.ndarray, class_angle_deg: float) -> str:
    """'floor', 'ceiling', 'wall' or 'intermediate' of a surface normal, by the class angle."""
    c = float(np.asarray(normal) @ up)
    a = np.radians(class_angle_deg)
    if c >= np.cos(a):
        return "floor"
    if c <= -np.cos(a):
        return "ceiling"
    return "wall" if abs(c) <= np.sin(a) else "intermediate"

@dataclass
class Spec:
    allow_walls: bool = True
    allow_ceiling: bool = True
    allow_floor: bool = False
    allow_intermediate: bool = False
    class_angle_deg: float = 15.0
    min_recovery_height: float = 0.5
    approach_distance: float = 0.5
    approach_margin: float = 0.1
    window_width: float = 0.5
    window_height: float = 0.5
    drone_radius: float = 0.35
    standoff: float = 0.5
    plane_tolerance: float = 0.03
    min_support: float = 0.9
    max_support_rms: float = 0.02
    min_visible_share: float = 0.2
    visibility_points: int = 64
    seed: int = 0


class SceneOracle:
    def __init__(self, scene: GeneratedScene, spec: Spec):
        self.scene, self.spec = scene, spec
        self.mesh = scene.mesh
        self.rays = RayScene(self.mesh)
        self.up = np.asarray(scene.up, np.float64)
        self.target_points = scene.target.sample(spec.visibility_points, seed=spec.seed)
        floors = [p for p in scene.planes if p.semantic_class == SemanticClass.FLOOR]
        self.floor_z = min(float(p.centroid @ self.up) for p in floors)
        self._others: dict[int, RayScene] = {}
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

    def _other_geometry(self, plane_id: int) -> RayScene | None:
        """Faces of other planes reaching more than TOL in front of this plane (none behind it)."""
        if plane_id not in self._others:
            p = self.scene.planes[plane_id]
            depth = (self.mesh.triangles() - p.centroid) @ p.normal
            keep = (self.scene.face_plane != plane_id) & (depth.max(axis=1) > TOL) & (depth.min(axis=1) > -TOL)
            self._others[plane_id] = RayScene(self.mesh.submesh(keep)) if keep.any() else None
        return self._others[plane_id]

    # --- tests ---------------------------------------------------------------------------------
    def recovery_ok(self, plane_id: int, points: np.ndarray) -> np.ndarray:
        """Floor height and fall corridor for points on one plane (False where the class is disabled)."""
        points = np.asarray(points, np.float64).reshape(-1, 3)
        if not self.enabled(plane_id) or len(points) == 0:
            return np.zeros(len(points), bool)
        return self._recovery(plane_id, points)

    def on_plane(self, plane_id: int, points: np.ndarray) -> np.ndarray:
        """Points whose ray along the inverted normal meets their own ground-truth plane right there."""
        n = self.scene.planes[plane_id].normal
        hits = self.rays.cast(points + 0.05 * n, np.repeat(-n[None], len(points), axis=0))
        plane = np.where(hits.hit, self.scene.face_plane[np.maximum(hits.face, 0)], -1)
        return (plane == plane_id) & (np.abs(hits.distance - 0.05) < 0.01)

    def _recovery(self, plane_id: int, points: np.ndarray) -> np.ndarray:
        s, up = self.spec, self.up
        kind = self.plane_class(plane_id)
        ok = points @ up >= self.floor_z + s.min_recovery_height
        if kind == "floor":
            return np.ones(len(points), bool)
        f = self.frame(plane_id)
        a = np.linspace(-s.drone_radius, s.drone_radius, CORRIDOR_RAYS)
        if kind == "ceiling":
            grid = [(x, y) for x in a for y in a]
            tops = np.concatenate([points + x * f.axis_u + y * f.axis_v - TOL * up for x, y in grid])
        else:  # in front of the wall: lateral +-rho, depth 0..2 rho (TOL off the wall)
            side = np.cross(up, f.normal)
            side /= np.linalg.norm(side)
            depth = np.linspace(TOL, 2 * s.drone_radius, CORRIDOR_RAYS - 1)
            tops = np.concatenate([points + x * side + d * f.normal for x in a for d in depth])
        down = np.repeat(-up[None], len(tops), axis=0)
        hits = self.rays.cast(tops, down)
        blocked = (hits.distance < s.min_recovery_height) | self._solid(tops)
        return ok & ~blocked.reshape(-1, len(points)).any(axis=0)

    def approach_free(self, plane_id: int, points: np.ndarray) -> np.ndarray:
        """No triangle of other geometry overlaps the approach prism in front of each point."""
        s = self.spec
        f = self.frame(plane_id)
        tris = self._other_triangles(plane_id)
        half = np.array([s.window_width / 2 + s.approach_margin, s.window_height / 2 + s.approach_margin,
                         (s.approach_distance - TOL) / 2])
        axes = np.stack([f.axis_u, f.axis_v, f.normal])
        out = np.ones(len(points), bool)
        if len(tris) == 0:
            return out
        reach = np.linalg.norm(half) + np.linalg.norm(tris - tris.mean(axis=1, keepdims=True), axis=2).max(axis=1)
        centroids = tris.mean(axis=1)
        for k, p in enumerate(points):
            centre = p + f.normal * (TOL + s.approach_distance) / 2
            near = np.linalg.norm(centroids - centre, axis=1) <= reach
            if near.any():
                local = np.einsum("fvk,ak->fva", tris[near] - centre, axes)
                out[k] = not triangles_overlap_box(local, half).any()
        return out

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
        """Share of a grid over each window with mesh within plane_tolerance of the plane, and the RMS
        distance of those hits to the plane."""
        s = self.spec
        f = self.frame(plane_id)
        n = self.scene.planes[plane_id].normal
        k = SUPPORT_POINTS
        us = (np.arange(k) + 0.5) / k * s.window_width - s.window_width / 2
        vs = (np.arange(k) + 0.5) / k * s.window_height - s.window_height / 2
        offsets = np.array([u * f.axis_u + v * f.axis_v for u in us for v in vs])
        grid = (points[None, :, :] + offsets[:, None, :]).reshape(-1, 3)
        start = s.plane_tolerance * 1.001 + 1e-4
        hits = self.rays.cast(grid + start * n, np.repeat(-n[None], len(grid), axis=0))
        found = hits.hit & (hits.distance <= start + s.plane_tolerance)
        depth = np.where(found, start - hits.distance, 0.0).reshape(len(offsets), len(points))
        found = found.reshape(len(offsets), len(points))
        count = found.sum(axis=0)
        rms = np.sqrt((depth ** 2).sum(axis=0) / np.maximum(count, 1))
        return count / len(offsets), np.where(count > 0, rms, np.inf)

    def visible_share(self, points: np.ndarray, normal: np.ndarray) -> np.ndarray:
        """Share of the target's sample points each point sees."""
        t = self.target_points
        origins = np.repeat(points + 0.02 * normal, len(t), axis=0)
        targets = np.tile(t, (len(points), 1))
        facing = (targets - origins) @ normal > 0
        seen = np.zeros(len(origins), bool)
        seen[facing] = ~self.rays.occluded(origins[facing], targets[facing])
        return seen.reshape(len(points), len(t)).mean(axis=1)

    def window_recovery(self, plane_id: int, points: np.ndarray) -> np.ndarray:
        """Every point of the perch window around each point passes the recovery test."""
        f = self.frame(plane_id)
        s = self.spec
        us = np.linspace(-s.window_width / 2, s.window_width / 2, WINDOW_POINTS)
        vs = np.linspace(-s.window_height / 2, s.window_height / 2, WINDOW_POINTS)
        offsets = [u * f.axis_u + v * f.axis_v for u in us for v in vs]
        around = np.concatenate([points + o for o in offsets])
        return self.recovery_ok(plane_id, around).reshape(len(offsets), len(points)).all(axis=0)

    def _voxel(self, points: np.ndarray) -> np.ndarray:
        """Ground-truth voxel index of world points (written out: BLAS matmul is slow under load)."""
        grid = self.scene.free_space
        inv = np.linalg.inv(grid.world_from_grid)
        local = sum(points[:, k, None] * inv[:3, k] for k in range(3)) + inv[:3, 3]
        return np.floor((local - grid.origin) / grid.voxel_size).astype(np.int64)

    def _solid(self, points: np.ndarray) -> np.ndarray:
        occupied = self.scene.free_space.occupied
        idx = self._voxel(points)
        inside = np.all((idx >= 0) & (idx < occupied.shape), axis=1)
        out = np.ones(len(points), bool)
        out[inside] = occupied[tuple(idx[inside].T)]
        return out

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
        ok = self.on_plane(plane_id, points) & self.recovery_ok(plane_id, points)
        for test in (lambda p: self.reachable(plane_id, p), lambda p: self.window_recovery(plane_id, p),
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


def triangles_overlap_box(tris: np.ndarray, half: np.ndarray) -> np.ndarray:
    """(F,3,3) triangles in the box's frame overlap the box [-half, half] (Akenine-Moller's 13 axes)."""
    edges = np.stack([tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 1], tris[:, 0] - tris[:, 2]], axis=1)
    axes = [np.broadcast_to(np.eye(3)[i], (len(tris), 3)) for i in range(3)]
    axes.append(np.cross(edges[:, 0], edges[:, 1]))
    axes += [np.cross(np.eye(3)[i], edges[:, j]) for i in range(3) for j in range(3)]
    overlap = np.ones(len(tris), bool)
    for axis in axes:
        proj = np.einsum("fvk,fk->fv", tris, axis)
        radius = np.abs(axis) @ half
        overlap &= ~((proj.min(axis=1) > radius + 1e-12) | (proj.max(axis=1) < -radius - 1e-12))
    return overlap


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
