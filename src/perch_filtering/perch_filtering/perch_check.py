"""The project's perch checker: placed perches judged on the mesh alone, in the mesh's own frame.

It shares no code with the filter (the filter rasterises mesh samples per surface; this casts rays
and tests triangles against boxes directly), so that the two can check each other. Perch by perch
(position on the scanned surface, unit normal into free space, `up` in the same frame):
  approach  no triangle overlaps window + approach_margin x [START, approach_distance] along the normal;
  fall      walls: no triangle in the corridor (window width + 2 approach_margin) x [START, 2 rho]
            out x from min_recovery_height below the window's bottom to its top; ceilings: none in
            the column (window + approach_margin on every side) x [START, min_recovery_height] below;
            the window's bottom (walls) or the perch (ceilings) at least min_recovery_height above
            the floor; floors and upward intermediate surfaces (landing) are not perches unless the
            spec allows them;
  support   of a 21 x 21 grid over the window, at least min_support - SUPPORT_SLACK find their first
            mesh hit within plane_tolerance of the window's perch plane (at the median of the hits
            within plane_tolerance + max_support_rms of the plane), RMS distance <= max_support_rms;
  observed  the approach prism and the fall corridor (column) lie in space the scan observed: at most
            max_unobserved_share + OBSERVED_SLACK of each may be unobserved (module doc below);
  sight     (with a target) at least min_visible_share of the target's sample points seen;
  reach     the standoff point in front of the seated perch is at least a drone radius from the mesh.
Ceilings and floors: gravity fixes no in-plane axis there, so a drone may settle in any yaw; the approach
prism, the fall column and the support grid are judged turned every YAW_STEP_DEG, and must pass in each.
START (6 cm): geometry nearer the plane than surface_depth (4 cm) is the scanned surface itself
(support bounds what it may do), plus 1 cm for faces crossing a box's side between mesh samples and
1 cm for the plane measured from: the filter's is the surface's fitted plane, the checker's the seated
perch's (the window's median depth), which lie up to ~1 cm apart on the corpus's walls.

Observed space with camera viewpoints (a reconstruction from posed RGB-D frames, Mesh.viewpoints): a
point is observed when some camera saw through it (perch_common.viewpoints.seen_free); the reason then
names the cause ("fall corridor 44 % unobserved (no camera saw it)").
Observed space on a bare mesh (no camera poses): a point is observed when the scan encloses it,
i.e. at most enclosed_escape_share (0.5) of the rays cast from it in ESCAPE_DIRECTIONS fixed directions leave
the model without a hit. A room's interior is enclosed (a doorway or window opening lets a minority
of rays out); space beyond the scan's edge, under a wall fragment with nothing scanned below or in
front of it, lets most rays out. A volume's unobserved share is the share of its sample points
(a grid inside it) that are not enclosed; in the fall corridor (column) also those with nothing
scanned below them (most rays of a 20 deg cone around gravity escape: no floor seen under the fall).

`check_perches` is the entry point (the benchmark and the tests call it).
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields

import numpy as np

from perch_common.mesh import Mesh
from perch_common.raycast import RayScene, sphere_directions
from perch_common.target import TargetVolume
from perch_common.viewpoints import seen_free

__all__ = ["CheckSpec", "PerchVerdict", "ScanChecker", "check_perches", "spec_from_config"]

SUPPORT_SLACK = 0.03  # two grids of 21 and 25 steps over one ragged window disagree by up to ~3 points
SUPPORT_POINTS = 21   # per side of the perch window
# The filter samples a volume on a 15 cm grid of 3 layers with 32 directions, this checker on a 4 x 4 x 4
# grid with 64: over one volume the two shares differ by up to ~4 points (measured on the corpus).
OBSERVED_SLACK = 0.05
ESCAPE_DIRECTIONS = 64  # rays per sample point of a volume (Fibonacci sphere, fixed)
ANY_YAW_KINDS = ("ceiling", "floor")  # gravity fixes no in-plane axis there: a drone may settle in any yaw
YAW_STEP_DEG = 15.0     # the yaws in which such a window is judged


@dataclass
class CheckSpec:
    """The safety model's numbers (FilterConfig's names and defaults)."""

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
    surface_depth: float = 0.04
    min_support: float = 0.9
    max_support_rms: float = 0.02
    min_visible_share: float = 0.2
    visibility_points: int = 64
    max_unobserved_share: float = 0.2
    enclosed_escape_share: float = 0.5
    seed: int = 0


def spec_from_config(config) -> CheckSpec:
    """The checker's spec from a FilterConfig (or anything with the same attribute names)."""
    return CheckSpec(**{f.name: getattr(config, f.name) for f in fields(CheckSpec) if hasattr(config, f.name)})


@dataclass
class PerchVerdict:
    """One perch judged: safe or not, why, and the measures behind it."""

    safe: bool
    reasons: list[str] = field(default_factory=list)
    kind: str = "wall"                 # wall | ceiling | floor | intermediate
    approach_free: bool = True
    fall_free: bool = True
    support_share: float = 0.0
    flatness_rms: float = float("inf")
    observed_share: float = 1.0        # the smaller of the approach prism's and the fall corridor's
    approach_observed: float = 1.0
    fall_observed: float = 1.0
    visible_share: float | None = None  # None without a target

    def as_dict(self) -> dict:
        """Plain data (JSON-ready)."""
        return {f.name: getattr(self, f.name) for f in fields(self)}


def surface_kind(normal: np.ndarray, up: np.ndarray, class_angle_deg: float) -> str:
    """'floor', 'ceiling', 'wall' or 'intermediate' of a surface normal, by the class angle."""
    c = float(np.asarray(normal) @ up)
    a = np.radians(class_angle_deg)
    if c >= np.cos(a):
        return "floor"
    if c <= -np.cos(a):
        return "ceiling"
    return "wall" if abs(c) <= np.sin(a) else "intermediate"


def window_yaws(kind: str, spec: CheckSpec) -> np.ndarray:
    """Yaws (rad) about the normal in which a window of this kind is judged: 0 where gravity fixes its
    axes (walls, intermediate surfaces), else every YAW_STEP_DEG over the turn after which the window
    repeats (a quarter turn for a square, half for a rectangle)."""
    if kind not in ANY_YAW_KINDS:
        return np.zeros(1)
    period = 90.0 if abs(spec.window_width - spec.window_height) < 1e-9 else 180.0
    return np.radians(np.arange(0.0, period - 1e-9, YAW_STEP_DEG))


def turned(axes: np.ndarray, yaw: float) -> np.ndarray:
    """Rows u, v, n turned by `yaw` about n."""
    c, s = np.cos(yaw), np.sin(yaw)
    return np.stack([c * axes[0] + s * axes[1], -s * axes[0] + c * axes[1], axes[2]])


def window_grid(spec: CheckSpec, axis_u: np.ndarray, axis_v: np.ndarray) -> np.ndarray:
    """(K*K, 3) offsets of the cell centres of a K x K grid over the perch window."""
    k = SUPPORT_POINTS
    us = (np.arange(k) + 0.5) / k * spec.window_width - spec.window_width / 2
    vs = (np.arange(k) + 0.5) / k * spec.window_height - spec.window_height / 2
    return np.array([u * axis_u + v * axis_v for u in us for v in vs])


def local_plane_support(depth: np.ndarray, spec: CheckSpec) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Support of windows from their grid's first-hit depths (K, windows; inf: no hit): the perch plane
    at the median of the depths within plane_tolerance + max_support_rms, the share of the grid
    within plane_tolerance of it, the RMS distance of those and the plane's offset (the median)."""
    band = np.abs(depth) <= spec.plane_tolerance + spec.max_support_rms
    median = np.zeros(depth.shape[1])
    some = band.any(axis=0)
    median[some] = [np.median(column[inside]) for column, inside in zip(depth[:, some].T, band[:, some].T)]
    found = band & (np.abs(depth - median) <= spec.plane_tolerance)
    count = found.sum(axis=0)
    squares = np.where(found, (depth - median) ** 2, 0.0).sum(axis=0)
    rms = np.sqrt(squares / np.maximum(count, 1))
    return count / depth.shape[0], np.where(count > 0, rms, np.inf), median


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


class ScanChecker:
    """The safety model on one mesh (in its own frame, `up` given in that frame), perch by perch."""

    def __init__(self, mesh: Mesh, up: np.ndarray, spec: CheckSpec | None = None,
                 target: TargetVolume | None = None, rays: RayScene | None = None):
        self.mesh, self.spec = mesh, spec or CheckSpec()
        self.up = np.asarray(up, np.float64) / np.linalg.norm(up)
        self.rays = rays if rays is not None else RayScene(mesh)
        self.tris = mesh.triangles()
        self.centroids = self.tris.mean(axis=1)
        self.radii = np.linalg.norm(self.tris - self.centroids[:, None], axis=2).max(axis=1)
        self.floor = float(np.percentile(mesh.vertices @ self.up, 1.0))  # the scan's floor level
        self.target_points = target.sample(self.spec.visibility_points, seed=self.spec.seed) if target else None
        self.start = self.spec.surface_depth + 0.02
        self.directions = sphere_directions(ESCAPE_DIRECTIONS)
        # Down and 12 directions 20 deg around it (a floor below a fall volume's point).
        tilt, turns = np.radians(20.0), np.arange(12) * np.pi / 6
        side = np.linalg.svd(self.up[None])[2][1:]  # two unit vectors across up
        ring = -np.cos(tilt) * self.up + np.sin(tilt) * (np.cos(turns)[:, None] * side[0] + np.sin(turns)[:, None] * side[1])
        self.floor_cone = np.vstack([-self.up, ring])

    def frame(self, normal: np.ndarray, yaw: float = 0.0) -> np.ndarray:
        """Rows u, v, n: v along up projected on the plane (walls), else any in-plane pair; turned by
        `yaw` about n."""
        n = normal / np.linalg.norm(normal)
        v = self.up - (self.up @ n) * n
        if np.linalg.norm(v) < 0.3:
            v = np.cross(n, [1.0, 0, 0]) if abs(n[0]) < 0.9 else np.cross(n, [0, 1.0, 0])
        v /= np.linalg.norm(v)
        return turned(np.stack([np.cross(v, n), v, n]), yaw)

    def yaws(self, normal: np.ndarray) -> np.ndarray:
        """The yaws in which a window on a surface with this normal is judged (window_yaws)."""
        return window_yaws(self.kind(normal), self.spec)

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

    def approach_box(self, point: np.ndarray, normal: np.ndarray,
                     yaw: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Centre, axes (rows) and half sizes of the approach prism (turned by `yaw`)."""
        s, axes = self.spec, self.frame(normal, yaw)
        half = np.array([s.window_width / 2 + s.approach_margin, s.window_height / 2 + s.approach_margin,
                         (s.approach_distance - self.start) / 2])
        return point + axes[2] * (self.start + s.approach_distance) / 2, axes, half

    def fall_box(self, point: np.ndarray, normal: np.ndarray,
                 yaw: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """Centre, axes and half sizes of the fall corridor (walls) or column (ceilings; turned by `yaw`);
        None for surfaces that need no fall (floors, upward intermediate surfaces)."""
        s, axes = self.spec, self.frame(normal, yaw)
        kind = self.kind(normal)
        rho, h, margin = s.drone_radius, s.min_recovery_height, s.approach_margin
        if kind == "wall":
            half = np.array([s.window_width / 2 + margin, (s.window_height + h) / 2, (2 * rho - self.start) / 2])
            return point + axes[1] * (-h / 2) + axes[2] * (self.start + 2 * rho) / 2, axes, half
        if normal @ self.up < 0:
            half = np.array([s.window_width / 2 + margin, s.window_height / 2 + margin, (h - self.start) / 2])
            return point + axes[2] * (self.start + h) / 2, axes, half
        return None

    def approach_free(self, point: np.ndarray, normal: np.ndarray) -> bool:
        """The approach prism in front of the perch is free (in every yaw the window is judged in)."""
        return all(self.box_free(*self.approach_box(point, normal, yaw)) for yaw in self.yaws(normal))

    def fall_free(self, point: np.ndarray, normal: np.ndarray) -> bool:
        """The fall corridor (walls) or column (ceilings) is free and high enough above the floor."""
        s = self.spec
        box = self.fall_box(point, normal)
        if box is None:
            return True
        bottom = point @ self.up - (s.window_height / 2 if self.kind(normal) == "wall" else 0.0)
        if bottom - s.min_recovery_height < self.floor:
            return False
        return all(self.box_free(*self.fall_box(point, normal, yaw)) for yaw in self.yaws(normal))

    def unobserved_share(self, centre: np.ndarray, axes: np.ndarray, half: np.ndarray, steps: int = 4,
                         fall: bool = False) -> tuple[float, str]:
        """(share of a steps^3 grid inside the box that the scan does not enclose (see the module doc), why):
        in a fall volume also the points with nothing scanned straight below them. `why` is "no camera
        saw it" (camera viewpoints), "no floor scanned below" when that rule left more unobserved, else ""."""
        ticks = (np.arange(steps) + 0.5) / steps * 2 - 1
        a, b, c = np.meshgrid(ticks, ticks, ticks, indexing="ij")
        local = np.column_stack([a.ravel(), b.ravel(), c.ravel()]) * half
        points = centre + local @ axes
        cause = ""
        if self.mesh.viewpoints is not None and len(self.mesh.viewpoints):  # a reconstruction's cameras
            unknown = ~seen_free(self.rays, self.mesh.viewpoints, points)
            cause = "no camera saw it"
        else:
            unknown = self.escape_shares(points) > self.spec.enclosed_escape_share
        if fall:  # nothing scanned below: most rays of a 20 deg cone around gravity escape
            no_floor = self.escape_shares(points, self.floor_cone) > 0.5
            if no_floor.sum() > unknown.sum():
                cause = "no floor scanned below"
            unknown |= no_floor
        return float(unknown.mean()), cause

    def escape_shares(self, points: np.ndarray, directions: np.ndarray | None = None) -> np.ndarray:
        """Per point, the share of its rays (ESCAPE_DIRECTIONS, or `directions`) that leave the model."""
        points = np.asarray(points, np.float64).reshape(-1, 3)
        d = self.directions if directions is None else directions
        origins = np.repeat(points, len(d), axis=0)
        hits = self.rays.cast(origins, np.tile(d, (len(points), 1)))
        return (~hits.hit).reshape(len(points), len(d)).mean(axis=1)

    def support(self, point: np.ndarray, normal: np.ndarray) -> tuple[float, float, float]:
        """Share of the window grid whose first hit lies on the window's perch plane, RMS of those hits
        and the perch plane's offset along the normal (where the drone touches the scan); in the worst
        of the yaws the window is judged in (the offset: in the first)."""
        yaws = self.yaws(normal)
        axes = [self.frame(normal, yaw) for yaw in yaws]
        grid = point + np.concatenate([window_grid(self.spec, a[0], a[1]) for a in axes])
        start = self.start + 0.01
        hits = self.rays.cast(grid + start * axes[0][2], np.repeat(-axes[0][2][None], len(grid), axis=0))
        depth = np.where(hits.hit, start - hits.distance, np.inf).reshape(len(yaws), -1).T
        share, rms, offset = local_plane_support(depth, self.spec)
        return float(share.min()), float(rms.max()), float(offset[0])

    def visible_share(self, point: np.ndarray, normal: np.ndarray) -> float:
        """Share of the target's sample points seen from 2 cm in front of the perch."""
        origin = point + 0.02 * normal
        t = self.target_points
        facing = (t - origin) @ normal > 0
        seen = np.zeros(len(t), bool)
        seen[facing] = ~self.rays.occluded(np.repeat(origin[None], int(facing.sum()), axis=0), t[facing])
        return float(seen.mean())

    def verdict(self, point: np.ndarray, normal: np.ndarray) -> PerchVerdict:
        """The whole model for one perch, with every reason it fails."""
        s = self.spec
        point = np.asarray(point, np.float64)
        normal = np.asarray(normal, np.float64) / np.linalg.norm(normal)
        kind = self.kind(normal)
        out = PerchVerdict(safe=True, kind=kind)
        allowed = {"wall": s.allow_walls, "ceiling": s.allow_ceiling, "floor": s.allow_floor,
                   "intermediate": s.allow_intermediate}[kind]
        if not allowed:
            out.reasons.append("landing on an upward surface" if normal @ self.up > 0 else f"{kind} perches disabled")
        out.approach_free = self.approach_free(point, normal)
        if not out.approach_free:
            out.reasons.append("approach blocked")
        out.fall_free = self.fall_free(point, normal)
        if not out.fall_free:
            out.reasons.append("fall blocked")
        out.support_share, out.flatness_rms, offset = self.support(point, normal)
        if out.support_share < s.min_support - SUPPORT_SLACK:
            out.reasons.append(f"support {100 * out.support_share:.0f} %")
        if out.flatness_rms > s.max_support_rms + 1e-9:
            out.reasons.append(f"not flat ({100 * out.flatness_rms:.1f} cm RMS)")
        approach_unknown, approach_cause = self.unobserved_share(*self.approach_box(point, normal))
        box = self.fall_box(point, normal)
        fall_unknown, fall_cause = self.unobserved_share(*box, fall=True) if box is not None else (0.0, "")
        out.approach_observed, out.fall_observed = 1.0 - approach_unknown, 1.0 - fall_unknown
        out.observed_share = min(out.approach_observed, out.fall_observed)
        limit = 1.0 - s.max_unobserved_share - OBSERVED_SLACK
        for name, share, cause in (("approach prism", out.approach_observed, approach_cause),
                                   ("fall corridor" if kind == "wall" else "fall column", out.fall_observed,
                                    fall_cause)):
            if share < limit - 1e-9:
                why = f" ({cause})" if cause and self.mesh.viewpoints is not None else ""
                out.reasons.append(f"{name} {100 * (1 - share):.0f} % unobserved{why}")
        seated = point + offset * normal  # the drone sits on the scan, at the window's perch plane
        if self.target_points is not None:
            out.visible_share = self.visible_share(seated, normal)
            if out.visible_share < s.min_visible_share - 1e-9:
                out.reasons.append(f"sees {100 * out.visible_share:.0f} % of the target")
        if self.rays.closest_points((seated + s.standoff * normal)[None])[2][0] < s.drone_radius:
            out.reasons.append("standoff point within a drone radius of the mesh")
        out.safe = not out.reasons
        return out


def check_perches(mesh: Mesh, positions: np.ndarray, normals: np.ndarray, up: np.ndarray,
                  spec: CheckSpec | None = None, target: TargetVolume | None = None) -> list[PerchVerdict]:
    """Judge perches (N,3) with normals (N,3) into free space on `mesh`, all in the mesh's frame with
    `up` in that frame; one verdict per perch. `spec` defaults to FilterConfig's defaults; without a
    `target` the sight rule is not judged."""
    positions = np.asarray(positions, np.float64).reshape(-1, 3)
    normals = np.asarray(normals, np.float64).reshape(-1, 3)
    if len(positions) != len(normals):
        raise ValueError(f"check_perches: {len(positions)} positions but {len(normals)} normals")
    up = np.asarray(up, np.float64).reshape(3)
    if not np.isfinite(up).all() or np.linalg.norm(up) < 1e-9:
        raise ValueError(f"check_perches: up {up.tolist()} is not a direction")
    if not len(positions):
        return []
    checker = ScanChecker(mesh, up, spec, target)
    return [checker.verdict(p, n) for p, n in zip(positions, normals)]
