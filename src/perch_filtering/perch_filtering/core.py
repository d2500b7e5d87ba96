"""The filtering stage's pure core: surface candidates in, perch regions and per-filter removals out.

One definition of a safe perch centre, filters in order (FILTER_NAMES):
  orientation      the surface's class (from its oriented normal) is enabled;
  recovery_height  the cell can fall min_recovery_height (fall corridor on walls, column below
                   ceilings, each approach_margin wider than the cell) and is that high above the floor;
  perch_window     every cell of the window centred on it passes recovery_height;
  obstacle_clearance  the approach prism (window + approach_margin, swept approach_distance along
                   the normal) is free of geometry;
  support          >= min_support of the window has scanned surface within plane_tolerance of its
                   perch plane (the fitted plane moved to the window's median depth), with RMS
                   distance <= max_support_rms;
Geometry nearer the plane than the surface's band (plane_tolerance plus three sigmas of its scan
noise, at most surface_depth) is the scanned surface itself (support judges it); farther geometry, the
surface's own bumps included, blocks the approach and the fall.
  line_of_sight    it sees >= min_visible_share of the target's sample points;
  reachability     its standoff point is reachable by flight from the target.
Each surface is handled on one raster in its plane frame; the visibility rays of all surfaces go
to the shared ray-cast scene in one batch.
"""

from __future__ import annotations

import time
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from typing import NamedTuple

import numpy as np

from perch_common.conventions import FILTER_NAMES, is_wall
from perch_common.mesh import Mesh, validate_mesh
from perch_common.mesh_samples import mesh_samples
from perch_common.polygons import faces_outline, from_shapely
from perch_common.proximity import LARGE_QUERY, clear_of_mesh
from perch_common.raycast import RayScene
from perch_common.raycast import ray_scene as shared_ray_scene
from perch_common.target import TargetVolume
from perch_common.threads import work_threads
from perch_common.timing import Laps
from perch_common.types import NOT_MEASURED, FilterRemoval, PerchEvidence, PerchRegion, Surface, SurfaceClass
from perch_common.work import report, span, steps
from perch_common.work_split import claimed_in_two_processes
from perch_filtering.checks import approach_clearance, free_fall, geometry_in_front
from perch_filtering.config import FilterConfig
from perch_filtering.holes import hole_patches
from perch_filtering.observed import unobserved_share, unobserved_shares
from perch_filtering.orientation import class_enabled, find_floor, orient, oriented_copy, visibility_scores, winding_votes
from perch_filtering.raster import (
    SurfaceRaster,
    any_yaw_radius,
    disc_kernel,
    erode,
    erode_window,
    rasterise,
    window_kernel,
)
from perch_filtering.regions import mask_polygons, triangulate
from perch_filtering.sampling import SampleIndex, project
from perch_filtering.standoff import standoffs_clear
from perch_filtering.support import first_surface_depth, local_window_support, scan_noise, turned_kernels
from perch_filtering.validation import validate_inputs
from perch_filtering.visibility import visible_shares
from perch_filtering.voxels import FlightGrid, build_flight_grid, grid_rotation

__all__ = ["FilterConfig", "FilterResult", "filter_surfaces", "FILTER_NAMES"]

ANY_YAW_CLASSES = (SurfaceClass.CEILING, SurfaceClass.FLOOR)  # gravity fixes no in-plane axis
ANY_YAW_STEP_DEG = 15.0  # yaws in which such a window's support is asked
CELL_HALF_DIAGONAL = 0.5 * 2 ** 0.5  # cells
NOISE_SIGMAS = 3.0  # scan noise sigmas in front of a plane that count as the surface itself (surface_band)
SUPPORT_BIN = 0.1  # depth bins of the support statistics, as a share of plane_tolerance (3 mm at 3 cm)
# Time per m^2 of a ceiling's (or floor's) judging, of a wall's, when two processes judge side by side:
# turned windows, a fall column and sight lines to every target point (the building's 483 m^2 ceiling:
# 1.1 against 0.75 us a cell alone, its share 1.6 s against 1.3 s alone; at 1.5 its share took 1.93 s
# and the other 1.55 s, at 1.85 1.65-1.79 s and 1.69-1.80 s).
ANY_YAW_COST = 1.85
SPLIT_MIN_CELLS = 200_000  # raster cells (m^2 of enabled surface / cell^2) from which a second process shares the judging
SPLIT_MIN_OBSERVED_CELLS = 100_000  # cells alive after line of sight from which a second process checks observed space
JUDGING_BATCH_SHARE = 1 / 48  # of the judging cost: batches of small surfaces that two processes take one by one
JUDGING = (0.2, 0.7)  # the call's progress while the surfaces are judged
SPLIT_PATIENCE = 10.0  # s the second process may take beyond the caller's share before it is judged here


@dataclass
class FilterResult:
    """Regions, per-surface removals and the oriented surfaces of one filtering run."""

    regions: list[PerchRegion]
    removals: list[FilterRemoval]   # one per input surface, same order
    surfaces: list[Surface]         # oriented and classed copies of the input surfaces
    message: str
    floor_height: float = 0.0
    floor_surfaces: list[int] = field(default_factory=list)
    decided_by: list[str] = field(default_factory=list)  # how each surface was oriented
    seconds: float = 0.0
    timings: dict = field(default_factory=dict)
    second_process: str = ""  # "" (one process), "done", or why the caller judged the second share itself

    def removed_area(self) -> dict[str, float]:
        """Total area (m^2) each filter removed over all surfaces."""
        return {name: float(sum(getattr(r, name) for r in self.removals)) for name in FILTER_NAMES}


@dataclass
class _Work:
    """One surface between the raster filters and the batched ones, with its evidence maps."""

    surface: Surface
    raster: SurfaceRaster | None
    alive: np.ndarray | None
    removal: FilterRemoval
    roughness: float = 0.0  # RMS distance (m) of the surface's vertices to its plane
    band: float = 0.0       # m, geometry nearer the plane is the scanned surface itself (surface_band)
    evidence: dict = field(default_factory=dict)  # PerchEvidence field -> per-cell map
    window: np.ndarray | None = None  # ceilings and floors: the any-yaw window's disc; None: upright (walls)


class _Observed(NamedTuple):
    """One surface after the observed-space rule: its removal, kept cells, the observed evidence at
    them and its regions; `before_reachability` when judged on the cells alive before reachability."""

    removal: FilterRemoval
    kept: np.ndarray
    approach_observed: np.ndarray
    fall_observed: np.ndarray
    regions: list[PerchRegion]
    before_reachability: bool = False


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
    # Progress (perch_common.work): shares of the call by phase, between a cProfile of a large scene and a
    # generated room's mission (grid 15 %, raster 13 %, line of sight 32 %, reachability 16 %, observed 20 %).
    report(0.0, "flight grid")
    samples = mesh_samples(mesh, config.voxel_size)
    wall = is_wall([s.frame.normal for s in surfaces], up, config.class_angle_deg)
    walls = [s for s, is_a_wall in zip(surfaces, wall) if is_a_wall]
    rotation = grid_rotation(up, np.array([s.frame.normal for s in walls]) if walls else None,
                             np.array([s.area for s in walls]))
    local = project(samples.points, rotation)  # one projection for the flight grid and the sample index
    # The sample index and the ray scene (Embree's BVH, when the mesh has none yet) are built beside the
    # flight grid: independent, and their numpy and Embree work releases the GIL.
    with ThreadPoolExecutor(max_workers=2, thread_name_prefix="perch-filter") as pool:
        submit = pool.submit if _surface_threads() > 1 else _done
        index_built = submit(SampleIndex, samples, rotation, local=local)
        scene_built = submit(lambda: ray_scene if ray_scene is not None else shared_ray_scene(mesh))
        grid = build_flight_grid(samples.points, rotation, target, config.voxel_size, config.drone_radius,
                                 config.max_voxels, config.seed, local)
        index = index_built.result()
        del local
        clock.lap("grid")
        report(0.12, "ray scene")
        scene = scene_built.result()
    centre = target.centroid()
    clock.lap("ray_scene")
    report(0.15, "orientation")
    orientations = orient(winding_votes(mesh, surfaces),
                          visibility_scores(mesh, surfaces, grid, scene, centre, config.seed,
                                            config.los_offset), [s.area for s in surfaces])
    oriented = [oriented_copy(s, o.sign, up, config.class_angle_deg) for s, o in zip(surfaces, orientations)]
    floor_height, floor_ids = find_floor(oriented, mesh, up, config)
    clock.lap("orientation")

    kernel = window_kernel(config.window_width, config.window_height, config.cell, config.window_ellipse)
    patches = hole_patches(oriented, config.drone_radius)
    patch_scene = RayScene(patches) if patches is not None else None  # built before a split (Embree's threads)
    target_points = target.sample(config.visibility_points, seed=config.seed)
    groups = _volume_groups(target, target_points, config)

    def judge(indices: list[int]) -> list[_Work]:
        """The per-surface filters up to line of sight, on the surfaces `indices` (each surface's answer
        is its own: the same alone, with the others, or in another process). Reports 0..1 of its work."""
        work = _per_surface(lambda i: _raster_filters(oriented[i], mesh, samples, index, scene, up, floor_height,
                                                      kernel, config),
                            indices, "raster filters: surface", 0.0, 0.5)
        clock.lap("raster_filters")
        _per_surface(lambda w: _support(w, scene, kernel, config) if w.raster is not None else None,
                     work, "support: surface", 0.5, 0.6)
        clock.lap("support")
        report(0.6, "line of sight")
        _visibility(work, scene, patch_scene, target_points, groups, config)
        clock.lap("line_of_sight")
        return work

    def judge_batches(taken) -> list[list[_Work]]:
        """judge on each batch of surfaces `taken` (indices into batches), in turn: claimed one at a time
        when two processes share them."""
        out = []
        for k, b in enumerate(taken):
            with span(JUDGING[0] + (JUDGING[1] - JUDGING[0]) * k / len(taken),
                      JUDGING[0] + (JUDGING[1] - JUDGING[0]) * (k + 1) / len(taken)):
                out.append(judge(batches[b]))
        return out

    # Each surface's judging costs about its raster's cells, a ceiling's ANY_YAW_COST times a wall's.
    judging_cost = [s.area / config.cell ** 2 * (ANY_YAW_COST if s.surface_class in ANY_YAW_CLASSES else 1.0)
                    if class_enabled(s.surface_class, config) else 0.0 for s in oriented]
    if _worth_a_split(judging_cost, SPLIT_MIN_CELLS, config):
        # In batches taken from both ends of one order (largest first): whichever process runs faster
        # judges more, and both end together.
        batches = _batches(judging_cost, JUDGING_BATCH_SHARE)
        judged, second_process = _claimed_out(judge_batches, [sum(judging_cost[i] for i in b) for b in batches],
                                              send=_evidence_at_alive, receive=_evidence_spread)
        by_surface = {i: w for batch, ws in zip(batches, judged) for i, w in zip(batch, ws)}
        work = [by_surface[i] for i in range(len(oriented))]
    else:
        with span(*JUDGING):
            work, second_process = judge(list(range(len(oriented)))), ""
    clock.lap("second_process")
    live = [w for w in work if w.raster is not None]
    reached: list[tuple[_Work, np.ndarray]] = []

    def observe_and_outline(w: _Work, kept: np.ndarray, before_reachability: bool = False) -> _Observed:
        """The observed-space rule on one surface's `kept` cells (updated), then its regions (numbered
        from 0). The rays are per kept cell; the observed maps are read nowhere else than at them."""
        _observed(w, kept, scene, up, config, mesh.viewpoints)
        return _Observed(w.removal, kept, w.evidence["approach_observed"][kept], w.evidence["fall_observed"][kept],
                         _regions(w, kept, 0, mesh.frame_id, config), before_reachability)

    def reach_and_observe(indices: list[int]) -> list[_Observed]:
        """Reachability on every live surface (Open3D's queries: the caller's), then observe_and_outline
        on the cells it kept of the surfaces `indices`."""
        report(0.7, "reachability")
        reached.extend(_reachability(live, grid, scene.mesh, config))
        clock.lap("reachability")
        return _per_surface(lambda i: observe_and_outline(*reached[i]), indices, "observed space: surface",
                            0.85, 0.99)

    def observe_alive(indices: list[int]) -> list[_Observed]:
        """The second process's share, beside reachability: observe_and_outline on the cells alive after
        line of sight (a cell's observed share does not depend on the other cells asked), on copies of
        the surfaces' removals and evidence (the caller's stay as reachability left them, should it run
        this share itself and then judge a surface again)."""
        return [observe_and_outline(replace(live[i], removal=replace(live[i].removal), evidence=dict(live[i].evidence)),
                                    live[i].alive.copy(), True) for i in indices]

    # The caller starts with reachability (a first call loads Open3D for it), then both processes take
    # surfaces from the two ends of one order until they meet: each share ends when the other's does.
    observe_cost = [float(w.alive.sum()) for w in live]
    if _worth_a_split(observe_cost, SPLIT_MIN_OBSERVED_CELLS, config):
        observed, observed_split = _claimed_out(reach_and_observe, observe_cost, run_theirs=observe_alive)
    else:
        observed, observed_split = reach_and_observe(list(range(len(live)))), ""
    for i, (w, kept) in enumerate(reached):
        # Reachability removes next to nothing; where it removed cells of a surface judged beside it, the
        # rule is applied again to the cells it kept (the same answer as one process gives).
        if observed[i].before_reachability and not np.array_equal(w.alive, kept):
            observed[i] = observe_and_outline(w, kept)
    regions: list[PerchRegion] = []
    for w, (removal, kept, approach, fall, outlined, _) in zip(live, observed):
        w.removal = removal
        w.evidence.update(approach_observed=_spread(approach, kept), fall_observed=_spread(fall, kept))
        for region in outlined:   # numbered in surface order, as one process numbers them
            region.id = len(regions)
            regions.append(region)
    removals = [w.removal for w in work]
    second_process = second_process if observed_split in ("", "done") else observed_split
    clock.lap("observed")
    result = FilterResult(regions, removals, oriented, "", floor_height, floor_ids,
                          [o.decided_by for o in orientations], time.perf_counter() - start, clock.laps,
                          second_process)
    result.message = _summary(result)
    return result


def prepare_mesh(mesh: Mesh, voxel_size: float, raster_density: float = 0.0) -> None:
    """Build what filter_surfaces derives from `mesh` whatever its request: the surface samples at
    `voxel_size` (config.voxel_size) and the ray scene, kept with the mesh (Mesh.derived); and, when
    the mesh could hold LARGE_QUERY raster cells at `raster_density` (its whole area as perches),
    the closest-point scene the reachability filter asks then (Open3D's import: 0.3 s of the call)."""
    mesh_samples(mesh, voxel_size)
    scene = shared_ray_scene(mesh)
    if mesh.num_faces and float(mesh.face_areas().sum()) * raster_density ** 2 >= LARGE_QUERY:
        scene.closest_point_scene()


def _surface_threads() -> int:
    """Threads the per-surface phases run on: as many as the ray casts get (OMP_NUM_THREADS, at most 2
    from Perch's entry points; 1 in each process of a split)."""
    return work_threads()


def _claimed_out(run, cost: list[float], run_theirs=None, send=None, receive=None) -> tuple[list, str]:
    """run(indices) -> one result per index, for all indices, in two processes that take the items as each
    is ready for the next (perch_common.work_split.Claims): the child's end of the order starts with
    the largest item, the caller's with the second (the caller may have work of its own first).
    `run_theirs` runs the child's items (in the child, or here in its place); `send`/`receive` shrink
    one result the child returns and restore it."""
    largest_first = [int(i) for i in np.argsort(-np.asarray(cost, np.float64), kind="stable")]
    order = largest_first[1::2] + largest_first[0::2][::-1]   # the front takes odd ranks, the back even ones
    split = claimed_in_two_processes(run, order, _patience, run_theirs=run_theirs, send=send)
    theirs = split.theirs
    if receive is not None and split.child == "done":
        theirs = {item: receive(result) for item, result in theirs.items()}
    by_index = split.mine | theirs
    return [by_index[i] for i in range(len(cost))], split.child


def _batches(cost: list[float], share: float) -> list[list[int]]:
    """The items largest first, in batches: an item alone, or consecutive smaller ones up to `share` of
    the total cost (a batch's fixed costs are paid once; the last batches taken are small)."""
    order = np.argsort(-np.asarray(cost, np.float64), kind="stable")
    enough = share * float(sum(cost))
    batches: list[list[int]] = [[]]
    held = 0.0
    for i in order:
        if batches[-1] and held >= enough:
            batches.append([])
            held = 0.0
        batches[-1].append(int(i))
        held += cost[i]
    return [b for b in batches if b]


def _worth_a_split(cost: list[float], min_cost: float, config: FilterConfig) -> bool:
    """Whether items of these costs (raster cells) pay for a second process (a fork)."""
    return config.processes >= 2 and float(sum(cost)) >= min_cost and np.count_nonzero(cost) >= 2


def _patience(own: float) -> float:
    """How long the caller waits for the child once its own share took `own` s: the child's share should
    take about as long; past three times that from the split (and a floor for a loaded machine), it is
    taken as lost and computed here."""
    return max(SPLIT_PATIENCE, 2.0 * own)


def _evidence_at_alive(work: list[_Work]) -> list[_Work]:
    """What a second process sends of its judged surfaces: the evidence maps at the live cells only
    (the later phases read them nowhere else; the building's second share pickles to 11.6 MB instead of 70.4)."""
    return [replace(w, evidence={name: values[w.alive] for name, values in w.evidence.items()})
            if w.raster is not None else w for w in work]


def _evidence_spread(work: list[_Work]) -> list[_Work]:
    """_evidence_at_alive undone: whole maps again, zero where the cell is not alive (never read)."""
    for w in work:
        if w.raster is not None:
            w.evidence = {name: _spread(values, w.alive) for name, values in w.evidence.items()}
    return work


def _spread(values: np.ndarray, mask: np.ndarray) -> np.ndarray:
    whole = np.zeros(mask.shape, values.dtype)
    whole[mask] = values
    return whole


def _done(work, *args, **kwargs) -> Future:
    """work(*args, **kwargs) run now, as a finished future (the one-thread path of a submit)."""
    future: Future = Future()
    future.set_result(work(*args, **kwargs))
    return future


def _per_surface(work, items: list, phase: str, low: float, high: float) -> list:
    """[work(item) for item in items] on _surface_threads() threads, in order. The surfaces are
    independent and their numpy, OpenCV and Embree work releases the GIL, so the phases use both
    cores where a surface's own work is serial. Progress and checkpoints (cancel, budget) stay on the
    calling thread, once per surface in order; a few surfaces run ahead of the one awaited (bounded
    memory); a cancel or an error leaves the ones not started unstarted."""
    threads = _surface_threads()
    if threads == 1 or len(items) < 2 or not hasattr(items, "__getitem__"):  # claimed items: one by one
        return [work(item) for item in steps(items, phase, low, high)]
    out: list = []
    futures: list = []
    with ThreadPoolExecutor(max_workers=threads, thread_name_prefix="perch-filter") as pool:
        try:
            for i, _ in enumerate(steps(range(len(items)), phase, low, high)):
                while len(futures) < min(len(items), i + 2 * threads):
                    futures.append(pool.submit(work, items[len(futures)]))
                out.append(futures[i].result())
                futures[i] = None
        finally:
            for future in futures:
                if future is not None:
                    future.cancel()
    return out


def _raster_filters(surface: Surface, mesh: Mesh, samples, index: SampleIndex, scene: RayScene, up: np.ndarray,
                    floor_height: float, kernel: np.ndarray, config: FilterConfig) -> _Work:
    """Rasterise one oriented surface; apply the class, recovery, window and approach filters."""
    boundary = surface.boundary
    if not boundary and len(surface.face_indices):
        boundary = faces_outline(surface.frame, mesh.triangles()[surface.face_indices])
    prism_half = 0.5 * max(config.window_width, config.window_height) + config.approach_margin
    pad = int(np.ceil((prism_half + config.cell) / config.cell)) + 1
    raster = rasterise(surface.frame, boundary, config.cell, pad, config.max_cells_per_surface,
                       f"surface {surface.id}")
    inside = raster.inside
    cell_area = raster.cell_area
    removal = FilterRemoval(int(surface.id), float(inside.sum() * cell_area))
    if not class_enabled(surface.surface_class, config):
        removal.orientation = removal.area_total
        return _Work(surface, None, None, removal)
    spacing = samples.spacing
    roughness = _roughness(surface, mesh)
    # Gravity fixes a wall window's axes; on a ceiling (or floor) a drone may settle in any yaw, so its
    # window, approach prism and fall column are judged turned to every yaw: discs of their half diagonals.
    any_yaw = surface.surface_class in ANY_YAW_CLASSES
    window = any_yaw_window(config) if any_yaw else kernel
    half_u = 0.5 * config.window_width + config.approach_margin
    half_v = 0.5 * config.window_height + config.approach_margin
    column_margin = (any_yaw_radius(half_u, half_v) - any_yaw_radius(0.5 * config.window_width,
                                                                     0.5 * config.window_height)
                     if any_yaw else config.approach_margin)
    # Geometry within the surface band of the plane is the scanned surface (support judges it under the
    # window); beyond it, anything blocks the approach and the fall. The surface's own faces may reach
    # as far as a window's surface may (plane_tolerance + max_support_rms): a scan's warp is no obstacle.
    band = surface_band(scan_noise(scene, raster, config.surface_depth + config.cell), config)
    lookahead = config.lookahead
    margin = max(prism_half, lookahead) + spacing + 2 * config.cell
    near = geometry_in_front(samples, index, raster, surface.face_indices, up, band, lookahead + spacing, margin,
                             max(band, config.plane_tolerance + config.max_support_rms))
    fall = free_fall(raster, near, up, floor_height, lookahead, column_margin, 2 * config.drone_radius,
                     spacing, surface.surface_class, any_yaw)
    fall_ok = fall >= config.min_recovery_height
    removal.recovery_height = float((inside & ~fall_ok).sum() * cell_area)
    alive = inside & fall_ok
    centres = erode_window(fall_ok, window)
    removal.perch_window = float((alive & ~centres).sum() * cell_area)
    alive &= centres
    clearance = approach_clearance(raster, near, half_u, half_v, lookahead, spacing, any_yaw)
    approach_ok = clearance > config.approach_distance
    removal.obstacle_clearance = float((alive & ~approach_ok).sum() * cell_area)
    alive &= approach_ok
    window_fall = _window_min(fall, window)
    return _Work(surface, raster, alive, removal, roughness, band,
                 {"approach_clearance": clearance, "free_fall": window_fall}, window if any_yaw else None)


def _turned_windows(kernel: np.ndarray, config: FilterConfig) -> list[np.ndarray]:
    """The window kernel turned by every ANY_YAW_STEP_DEG (after 0) up to the turn after which it repeats
    (a quarter turn for a square, half for a rectangle): support is asked in the worst yaw."""
    period = 90.0 if config.window_width == config.window_height else 180.0
    return turned_kernels(kernel, tuple(np.radians(np.arange(ANY_YAW_STEP_DEG, period - 1e-9, ANY_YAW_STEP_DEG))))


def any_yaw_window(config: FilterConfig) -> np.ndarray:
    """The window turned to every yaw about its centre: the disc of its half diagonal (of its larger
    half axis when elliptic), as the kernel of the cells whose centres lie in it."""
    radius = (0.5 * max(config.window_width, config.window_height) if config.window_ellipse
              else any_yaw_radius(0.5 * config.window_width, 0.5 * config.window_height))
    return disc_kernel(radius / config.cell)


def surface_band(noise: float, config: FilterConfig) -> float:
    """Depth (m) up to which geometry in front of a surface's plane is the scanned surface itself:
    plane_tolerance plus NOISE_SIGMAS of the surface's scan noise, at most surface_depth. A clean
    surface keeps a thin band (a 4 cm panel under a window is an obstacle); a noisy scan's walls are
    not blocked by their own scatter."""
    return float(np.clip(config.plane_tolerance + NOISE_SIGMAS * noise, config.plane_tolerance,
                         max(config.surface_depth, config.plane_tolerance)))


def _window_min(values: np.ndarray, kernel: np.ndarray) -> np.ndarray:
    """Smallest value under the window centred on each cell (raster.erode: a ceiling's disc by its rows)."""
    import cv2

    return erode(values.astype(np.float32, copy=False), kernel, cv2.BORDER_REPLICATE)


def _support(w: _Work, scene: RayScene, kernel: np.ndarray, config: FilterConfig) -> None:
    """Filter 'support': enough of the window lies on scanned surface close to its perch plane."""
    import cv2

    window = w.window if w.window is not None else kernel
    share = np.zeros(w.raster.shape, np.float32)
    rms = np.full(w.raster.shape, np.inf, np.float32)
    rows = np.flatnonzero(w.alive.any(axis=1))
    if len(rows):  # the statistics on the part of the raster the live windows cover
        cols = np.flatnonzero(w.alive.any(axis=0))
        reach_v, reach_u = window.shape[0] // 2, window.shape[1] // 2
        box = (slice(max(rows[0] - reach_v, 0), rows[-1] + reach_v + 1),
               slice(max(cols[0] - reach_u, 0), cols[-1] + reach_u + 1))
        under = cv2.dilate(w.alive[box].astype(np.uint8), window).astype(bool)
        depth = first_surface_depth(scene, w.raster, under, w.band + config.cell, box)
        # Only the live windows are judged (the others are gone whatever their support).
        local = local_window_support(depth, kernel, config.plane_tolerance + config.max_support_rms,
                                     config.plane_tolerance, SUPPORT_BIN * config.plane_tolerance,
                                     _turned_windows(kernel, config) if w.window is not None else (),
                                     centres=w.alive[box], min_share=config.min_support - 1e-6,
                                     max_rms=config.max_support_rms)
        share[box], rms[box] = local.share, local.rms
    ok = (share >= config.min_support - 1e-6) & (rms <= config.max_support_rms)
    w.removal.support = float((w.alive & ~ok).sum() * w.raster.cell_area)
    w.alive &= ok
    w.evidence.update(support_share=share, flatness_rms=rms)


def _reachability(work: list[_Work], grid: FlightGrid, mesh: Mesh,
                  config: FilterConfig) -> list[tuple[_Work, np.ndarray]]:
    """Filter 'reachability': the drone fits at the standoff point in front of the perch (a drone
    radius from the mesh, measured exactly, wherever in its cell the perch is) and that point is
    reachable by flight from the target.
    Every surface's standoff points are measured in one query (per-query costs are paid once)."""
    stands = [w.raster.cell_world(w.alive) + config.standoff * w.surface.frame.normal for w in work]
    # A kept cell stands for its whole square: a perch anywhere in it moves the standoff point by up to
    # half a cell diagonal from the centre's, and the distance to the mesh by as much (it is 1-Lipschitz).
    radius = config.drone_radius + CELL_HALF_DIAGONAL * config.cell
    nears = [grid.lookup(grid.reachable_near, stand) for stand in stands]
    asked = np.concatenate([stand[near] for stand, near in zip(stands, nears)]) if work else np.zeros((0, 3))
    if len(asked) >= LARGE_QUERY:
        clear = standoffs_clear(mesh, [(w.raster, w.alive, near) for w, near in zip(work, nears)], asked,
                                config.standoff, radius)
    else:  # the clearance test reuses the samples the filter drew (same spacing: kept with the mesh)
        clear = clear_of_mesh(mesh, asked, radius, config.voxel_size)
    fits = np.split(clear, np.cumsum([n.sum() for n in nears])[:-1])
    out = []
    for w, near, fit in zip(work, nears, fits):
        near[near] = fit
        kept = np.zeros(w.raster.shape, bool)
        kept[w.alive] = near
        w.removal.reachability = float((w.alive & ~kept).sum() * w.raster.cell_area)
        w.removal.area_kept = float(kept.sum() * w.raster.cell_area)
        out.append((w, kept))
    return out


def _observed(w: _Work, kept: np.ndarray, scene: RayScene, up: np.ndarray, config: FilterConfig,
              viewpoints: np.ndarray | None = None) -> None:
    """The observed-space rule (perch_filtering.observed): at most max_unobserved_share of a perch's
    approach prism and of its fall corridor (column below ceilings) may lie in space the scan does not
    enclose (in the fall's, also where nothing was scanned below). Runs on the cells every other filter
    kept (the rays are the costly part); the area it removes counts to obstacle_clearance (approach)
    and recovery_height (fall), whose volumes these are."""
    s = config
    start = s.surface_depth + s.cell  # in front of what counts as the surface itself
    half_u = 0.5 * s.window_width + s.approach_margin
    half_v = 0.5 * s.window_height + s.approach_margin
    if w.window is not None:  # any yaw: the square holding the disc every turned prism sweeps
        half_u = half_v = any_yaw_radius(half_u, half_v)
    views = viewpoints  # the cameras' evidence, when the mesh was reconstructed from posed frames
    prism = ((-half_u, half_u), (-half_v, half_v), (start, max(s.approach_distance, start + s.cell)))
    column = ((-half_u, half_u), (-half_v, half_v), (start, max(s.min_recovery_height, start + s.cell)))
    if w.surface.surface_class == SurfaceClass.WALL:  # the corridor below the window, 2 radii deep
        corridor = ((-half_u, half_u), (-(0.5 * s.window_height + s.min_recovery_height), 0.5 * s.window_height),
                    (start, max(2 * s.drone_radius, start + s.cell)))
        approach, fall = (unobserved_share(scene, w.raster, kept, *volume, s.enclosed_escape_share, down,
                                           viewpoints=views) for volume, down in ((prism, None), (corridor, -up)))
    elif float(w.surface.frame.normal @ up) < 0:  # the column below a ceiling (or a downward surface)
        # With the defaults (approach_distance = min_recovery_height) one box: its enclosure rays cast once.
        approach, fall = (unobserved_shares(scene, w.raster, kept, *prism, s.enclosed_escape_share, (None, -up),
                                            views) if column == prism else
                          (unobserved_share(scene, w.raster, kept, *volume, s.enclosed_escape_share, down,
                                            viewpoints=views) for volume, down in ((prism, None), (column, -up))))
    else:  # landing: no fall
        approach = unobserved_share(scene, w.raster, kept, *prism, s.enclosed_escape_share, viewpoints=views)
        fall = np.zeros(w.raster.shape, np.float32)
    limit = s.max_unobserved_share + 1e-6
    approach_bad = kept & (approach > limit)
    fall_bad = kept & ~approach_bad & (fall > limit)
    w.removal.obstacle_clearance += float(approach_bad.sum() * w.raster.cell_area)
    w.removal.recovery_height += float(fall_bad.sum() * w.raster.cell_area)
    kept &= ~(approach_bad | fall_bad)
    w.removal.area_kept = float(kept.sum() * w.raster.cell_area)
    w.evidence.update(approach_observed=1.0 - approach, fall_observed=1.0 - fall)


def _regions(w: _Work, kept: np.ndarray, first_id: int, frame_id: str, config: FilterConfig) -> list[PerchRegion]:
    """One region per connected piece of kept cells: polygons with holes, a triangulated mesh and the
    region's safety evidence (its worst cell's)."""
    import shapely

    out = []
    uv = w.raster.cell_uv(kept)
    for poly in mask_polygons(kept, w.raster):
        if poly.area >= config.min_region_area:
            mine = shapely.intersects_xy(poly, uv[:, 0], uv[:, 1])
            out.append(PerchRegion(
                id=first_id + len(out), source_surface=int(w.surface.id), surface_class=w.surface.surface_class,
                frame=w.surface.frame, polygons=from_shapely(poly), area=float(poly.area),
                mesh=triangulate(poly, w.raster, frame_id), evidence=_evidence(w, kept, mine)))
    return out


def _evidence(w: _Work, kept: np.ndarray, mine: np.ndarray) -> PerchEvidence:
    """Worst value over the region's cells of each evidence map (NOT_MEASURED when a map is missing)."""
    values = {}
    for name, worst in (("approach_clearance", np.min), ("free_fall", np.min), ("support_share", np.min),
                        ("flatness_rms", np.max), ("approach_observed", np.min), ("fall_observed", np.min)):
        cells = w.evidence[name][kept][mine] if name in w.evidence and mine.any() else np.zeros(0)
        values[name] = float(worst(cells)) if len(cells) else NOT_MEASURED
    return PerchEvidence(**values)


def _roughness(surface: Surface, mesh: Mesh) -> float:
    """RMS distance of the surface's vertices to its plane: the given one or, if larger, measured
    (noisy scans must not hide their own rays or count their own bumps as obstacles)."""
    if not len(surface.face_indices):
        return float(surface.rms_distance)
    vertices = mesh.vertices[np.unique(mesh.faces[surface.face_indices])]
    depth = project(vertices, surface.frame.normal, surface.frame.origin)[:, 0]
    return max(float(surface.rms_distance), float(np.sqrt(np.mean(depth ** 2))))


def _volume_groups(target: TargetVolume, points: np.ndarray, config: FilterConfig) -> np.ndarray | None:
    """(T, G) which target points lie in each of the target's G volumes; None for one volume (or when
    visibility_per_volume is off): the share is then of all points."""
    volumes = target.volumes()
    if len(volumes) == 1 or not config.visibility_per_volume:
        return None
    return np.column_stack([v.contains(points) for v in volumes])


def _visibility(work: list[_Work], scene: RayScene, patches: RayScene | None, target_points: np.ndarray,
                groups: np.ndarray | None, config: FilterConfig) -> None:
    """Filter 'line_of_sight': keep cells that see at least min_visible_share of the target points (of a
    target of several volumes, of the volume they see best: a building's volumes lie in different rooms
    and storeys, and no perch sees more than a few of them)."""
    live = [w for w in work if w.raster is not None and w.alive.any()]
    if not live:
        return
    # Start in front of the surface's own bumps: the configured offset plus three RMS deviations.
    enough = config.min_visible_share - 1e-6
    shares = visible_shares([w.raster for w in live], [w.alive for w in live],
                            [config.los_offset + 3.0 * w.roughness for w in live], target_points, scene, patches,
                            config.visibility_spacing, groups, threshold=enough)
    for w, share in zip(live, shares):
        seen = w.alive & (share >= enough)
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
