"""The filtering stage's pure core: surface candidates in, perch regions and per-filter removals out.

Filters, in order: orientation/class, recovery height, obstacle clearance, line of sight, perch
window, flight reachability. Each surface is handled on one raster in its plane frame; the line of
sight rays of all surfaces go to the shared ray-cast scene in one batch.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from perch_common.conventions import FILTER_NAMES, is_wall
from perch_common.mesh import Mesh, validate_mesh
from perch_common.polygons import faces_outline, from_shapely
from perch_common.raycast import RayScene
from perch_common.target import TargetVolume
from perch_common.timing import Laps
from perch_common.types import FilterRemoval, PerchRegion, Surface
from perch_filtering.checks import clearance_blocked, geometry_in_front, recovery_blocked
from perch_filtering.config import FilterConfig
from perch_filtering.holes import hole_patches, patched_occlusion
from perch_filtering.orientation import class_enabled, find_floor, orient, oriented_copy, visibility_scores, winding_votes
from perch_filtering.raster import SurfaceRaster, erode_window, rasterise, window_kernel
from perch_filtering.regions import mask_polygons, triangulate
from perch_filtering.sampling import SampleIndex, project, sample_mesh
from perch_filtering.validation import validate_inputs
from perch_filtering.voxels import FlightGrid, build_flight_grid, grid_rotation

__all__ = ["FilterConfig", "FilterResult", "filter_surfaces", "FILTER_NAMES"]

@dataclass
class FilterResult:
    regions: list[PerchRegion]
    removals: list[FilterRemoval]   # one per input surface, same order
    surfaces: list[Surface]         # oriented and classed copies of the input surfaces
    message: str
    floor_height: float = 0.0
    floor_surfaces: list[int] = field(default_factory=list)
    decided_by: list[str] = field(default_factory=list)  # how each surface was oriented
    seconds: float = 0.0
    timings: dict = field(default_factory=dict)

    def removed_area(self) -> dict[str, float]:
        """Total area (m^2) each filter removed over all surfaces."""
        return {name: float(sum(getattr(r, name) for r in self.removals)) for name in FILTER_NAMES}


@dataclass
class _Work:
    """One surface between the raster filters and the batched ones."""

    surface: Surface
    raster: SurfaceRaster | None
    alive: np.ndarray | None
    removal: FilterRemoval
    roughness: float = 0.0  # RMS distance (m) of the surface's vertices to its plane


def filter_surfaces(mesh: Mesh, surfaces: list[Surface], target: TargetVolume, up: np.ndarray,
                    config: FilterConfig | None = None, ray_scene: RayScene | None = None) -> FilterResult:
    """Perch regions on `surfaces` of `mesh`; the inputs are never modified.

    Raises ValueError / MeshError with a precise message for malformed input.
    """
    start = time.perf_counter()
    config = (config or FilterConfig()).validate()
    validate_mesh(mesh, "environment mesh")
    up = validate_inputs(mesh, surfaces, target, up)
    clock = Laps()
    samples = sample_mesh(mesh, config.voxel_size)
    walls = [s for s, wall in zip(surfaces, is_wall([s.frame.normal for s in surfaces], up, config.class_angle_deg)) if wall]
    rotation = grid_rotation(up, np.array([s.frame.normal for s in walls]) if walls else None,
                             np.array([s.area for s in walls]))
    grid = build_flight_grid(samples.points, rotation, target, config.voxel_size, config.drone_radius,
                             config.max_voxels, config.seed)
    index = SampleIndex(samples, rotation)
    clock.lap("grid")
    scene = ray_scene if ray_scene is not None else RayScene(mesh)
    centre = target.centroid()
    clock.lap("ray_scene")
    orientations = orient(winding_votes(mesh, surfaces),
                          visibility_scores(mesh, surfaces, grid, scene, centre, config.seed))
    oriented = [oriented_copy(s, o.sign, up, config.class_angle_deg) for s, o in zip(surfaces, orientations)]
    floor_height, floor_ids = find_floor(oriented, mesh, up, config)
    clock.lap("orientation")

    work = [_raster_filters(s, mesh, samples, index, up, floor_height, config) for s in oriented]
    clock.lap("raster_filters")
    patches = hole_patches(oriented, config.drone_radius)
    _line_of_sight(work, scene, RayScene(patches) if patches is not None else None, centre, config)
    clock.lap("line_of_sight")
    kernel = window_kernel(config.window_width, config.window_height, config.cell, config.window_ellipse)
    regions: list[PerchRegion] = []
    for w in work:
        if w.raster is not None:
            kept = _window_and_reachability(w, kernel, grid, config)
            regions.extend(_regions(w, kept, len(regions), mesh.frame_id, config))
    clock.lap("window_reachability_regions")
    removals = [w.removal for w in work]
    result = FilterResult(regions, removals, oriented, "", floor_height, floor_ids,
                          [o.decided_by for o in orientations], time.perf_counter() - start, clock.laps)
    result.message = _summary(result)
    return result


def _window_and_reachability(w: _Work, kernel: np.ndarray, grid: FlightGrid, config: FilterConfig) -> np.ndarray:
    """Filters 5 and 6: the whole window fits on surviving cells; the standoff point is reachable."""
    cell_area = w.raster.cell_area
    window = erode_window(w.alive, kernel)
    w.removal.perch_window = float((w.alive & ~window).sum() * cell_area)
    stand = w.raster.cell_world(window) + config.standoff * w.surface.frame.normal
    kept = np.zeros(w.raster.shape, bool)
    kept[window] = grid.lookup(grid.hover, stand)
    w.removal.reachability = float((window & ~kept).sum() * cell_area)
    w.removal.area_kept = float(kept.sum() * cell_area)
    return kept


def _regions(w: _Work, kept: np.ndarray, first_id: int, frame_id: str, config: FilterConfig) -> list[PerchRegion]:
    """One region per connected piece of kept cells: polygons with holes and a triangulated mesh."""
    out = []
    for poly in mask_polygons(kept, w.raster):
        if poly.area >= config.min_region_area:
            out.append(PerchRegion(
                id=first_id + len(out), source_surface=int(w.surface.id), surface_class=w.surface.surface_class,
                frame=w.surface.frame, polygons=from_shapely(poly), area=float(poly.area),
                mesh=triangulate(poly, w.raster, frame_id)))
    return out


def _raster_filters(surface: Surface, mesh: Mesh, samples, index: SampleIndex, up: np.ndarray,
                    floor_height: float, config: FilterConfig) -> _Work:
    """Rasterise one oriented surface and apply the class, recovery and clearance filters."""
    boundary = surface.boundary
    if not boundary and len(surface.face_indices):
        boundary = faces_outline(surface.frame, mesh.triangles()[surface.face_indices])
    kernel_half = 0.5 * max(config.window_width, config.window_height) + config.cell
    pad = int(np.ceil(kernel_half / config.cell)) + 1
    raster = rasterise(surface.frame, boundary, config.cell, pad, config.max_cells_per_surface,
                       f"surface {surface.id}")
    inside = raster.inside
    removal = FilterRemoval(int(surface.id), float(inside.sum() * raster.cell_area))
    if not class_enabled(surface.surface_class, config):
        removal.orientation = removal.area_total
        return _Work(surface, None, None, removal)
    spacing = samples.spacing
    roughness = _roughness(surface, mesh)
    depth_tol = config.plane_tolerance + 2.0 * roughness
    reach = max(config.clearance_radius, 2 * config.drone_radius, config.min_recovery_height) + spacing
    margin = max(config.clearance_radius, config.drone_radius) + spacing + 2 * config.cell
    near = geometry_in_front(samples, index, raster, surface.face_indices, up, depth_tol, reach, margin)
    fall = recovery_blocked(raster, near, up, floor_height, config.min_recovery_height, config.drone_radius,
                            spacing, surface.surface_class)
    alive = inside & ~fall
    removal.recovery_height = float((inside & fall).sum() * raster.cell_area)
    clear = clearance_blocked(raster, near, config.clearance_radius, spacing)
    removal.obstacle_clearance = float((alive & clear).sum() * raster.cell_area)
    return _Work(surface, raster, alive & ~clear, removal, roughness)


def _roughness(surface: Surface, mesh: Mesh) -> float:
    """RMS distance of the surface's vertices to its plane: the given one or, if larger, measured
    (noisy scans must not hide their own rays or count their own bumps as obstacles)."""
    if not len(surface.face_indices):
        return float(surface.rms_distance)
    vertices = mesh.vertices[np.unique(mesh.faces[surface.face_indices])]
    depth = project(vertices, surface.frame.normal, surface.frame.origin)[:, 0]
    return max(float(surface.rms_distance), float(np.sqrt(np.mean(depth ** 2))))


def _line_of_sight(work: list[_Work], scene: RayScene, patches: RayScene | None, centre: np.ndarray,
                   config: FilterConfig) -> None:
    """Remove cells that do not see the target centre (through the mesh and the patches over small
    holes), all surfaces in one batch of rays."""
    live = [w for w in work if w.raster is not None and w.alive.any()]
    if not live:
        return
    points = [w.raster.cell_world(w.alive) for w in live]
    normals = np.concatenate([np.repeat(w.surface.frame.normal[None], len(p), axis=0) for w, p in zip(live, points)])
    # Start in front of the surface's own bumps: the configured offset plus three RMS deviations.
    offsets = np.concatenate([np.full(len(p), config.los_offset + 3.0 * w.roughness) for w, p in zip(live, points)])
    p = np.concatenate(points)
    facing = np.einsum("ij,ij->i", centre - p, normals) > 0
    visible = facing.copy()
    visible[facing] = ~patched_occlusion(scene, patches, p[facing] + offsets[facing, None] * normals[facing],
                                         np.repeat(centre[None], int(facing.sum()), axis=0))
    offset = 0
    for w, pts in zip(live, points):
        ok = visible[offset:offset + len(pts)]
        offset += len(pts)
        seen = np.zeros(w.raster.shape, bool)
        seen[w.alive] = ok
        w.removal.line_of_sight = float((w.alive & ~seen).sum() * w.raster.cell_area)
        w.alive = seen


def _summary(result: FilterResult) -> str:
    if not result.surfaces:
        return "no surfaces given: nothing to filter"
    kept = sum(r.area for r in result.regions)
    if result.regions:
        return (f"{len(result.regions)} perch regions, {kept:.2f} m^2 on "
                f"{len({r.source_surface for r in result.regions})} of {len(result.surfaces)} surfaces")
    removed = result.removed_area()
    worst = max(removed, key=removed.get) if result.removals else "orientation"
    total = sum(r.area_total for r in result.removals)
    return (f"no perch region survived: {worst.replace('_', ' ')} removed the most area "
            f"({removed.get(worst, 0.0):.2f} of {total:.2f} m^2 over {len(result.surfaces)} surfaces)")
