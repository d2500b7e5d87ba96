"""The safety model's real-scan rules on hand-built rooms: the fall corridor's width, support against
each window's own perch plane, and the band in front of a surface that counts as the surface itself."""

from __future__ import annotations

import numpy as np
import pytest
from filtering_scenes import structure
from test_filter_cases import TARGET, TOL, kept_points, names_by_id, room, run

from perch_common.mesh import Mesh
from perch_common.raycast import RayScene
from perch_common.types import PlaneFrame
from perch_filtering.core import FilterConfig, filter_surfaces, surface_band
from perch_filtering.raster import rasterise
from perch_filtering.support import scan_noise

UP = np.array([0.0, 0.0, 1.0])


def test_fall_corridor_is_the_window_grown_by_the_approach_margin():
    """A cabinet beside a perch blocks its fall only within window/2 + approach_margin (0.35 m) of the
    perch centre, not within window/2 + drone_radius (0.6 m) as when every window cell had its own
    drone-wide corridor."""
    b = room()
    b.box("cabinet", [2.0, 0.05, 0.0], [2.6, 0.5, 1.8])
    surfaces, result = run(b, TARGET)
    wall = kept_points(result, surfaces, names_by_id(b, surfaces), "room.wall0")
    low = wall[wall[:, 2] < 1.5]  # below the cabinet's top: only where the cabinet is not below
    assert len(low) > 0
    gap = np.maximum(2.0 - low[:, 0], low[:, 0] - 2.6)  # distance from the cabinet's side
    assert gap.min() >= 0.35 - TOL
    assert gap.min() <= 0.35 + 0.05  # perches 0.35-0.6 m beside the cabinet survive
    above = wall[(wall[:, 0] > 2.0 - 0.3) & (wall[:, 0] < 2.6 + 0.3)]
    assert len(above) == 0 or above[:, 2].min() >= 1.8 + 0.5 + 0.25 - TOL


def _sagging_ceiling(sag: float) -> tuple[Mesh, list]:
    """A 6 x 5 m room whose ceiling sags by `sag` in the middle (a scan's warp); the ceiling's given
    plane stays the flat one at 2.8 m."""
    b = room()
    surfaces = b.surfaces(structure(b), subdivisions=5)
    mesh = b.mesh(subdivisions=5)
    ceiling = next(s for s in surfaces if s.frame.normal @ UP < -0.9)
    ids = np.unique(mesh.faces[ceiling.face_indices])
    v = mesh.vertices.copy()
    v[ids, 2] -= sag * (1.0 - ((v[ids, 0] - 3.0) / 3.0) ** 2)
    return Mesh(v, mesh.faces), surfaces


def _grid_points(region, spacing: float = 0.05) -> np.ndarray:
    """World points of a 5 cm grid inside a region's polygons."""
    import shapely

    from perch_common.polygons import to_shapely

    shape = to_shapely(region.polygons)
    lo_u, lo_v, hi_u, hi_v = shape.bounds
    u, v = np.meshgrid(np.arange(lo_u, hi_u, spacing), np.arange(lo_v, hi_v, spacing))
    inside = shapely.contains_xy(shape, u.ravel(), v.ravel())
    return region.frame.to_world(np.column_stack([u.ravel(), v.ravel()])[inside])


def test_a_sagging_ceiling_is_supported_by_each_windows_own_plane():
    """A ceiling 4.5 cm low in the middle: against the fitted plane (3 cm tolerance) the middle would
    be unsupported; each window's perch plane follows the scan, so the middle stays a perch."""
    mesh, surfaces = _sagging_ceiling(0.045)
    result = filter_surfaces(mesh, surfaces, TARGET, UP, FilterConfig())
    ceiling = [r for r in result.regions if r.frame.normal @ UP < -0.9]
    assert ceiling
    removal = next(r for r in result.removals if r.surface_id == ceiling[0].source_surface)
    assert removal.support < 0.05 * removal.area_total
    points = np.concatenate([_grid_points(r) for r in ceiling])
    middle = np.abs(points[:, 0] - 3.0) < 1.5  # where the sag exceeds 3.4 cm
    assert middle.sum() * 0.05 ** 2 > 4.0  # m^2 kept there (the room's middle band is 7.5 m^2)


def test_placed_perches_sit_on_the_scanned_surface():
    """Placement seats each perch on the scan under the drone: on the sagging ceiling the drones hang
    where the mesh is, not on the flat fitted plane."""
    from perch_placement.config import PlacementConfig
    from perch_placement.core import optimise

    mesh, surfaces = _sagging_ceiling(0.045)
    result = filter_surfaces(mesh, surfaces, TARGET, UP, FilterConfig(allow_walls=False))
    scene = RayScene(mesh)
    for seat_depth, worst in ((0.05, 0.004), (0.0, None)):
        placed = optimise(mesh, result.regions, TARGET, 3, PlacementConfig(seat_depth=seat_depth))
        assert len(placed.placements) == 3
        positions = np.array([p.drone_pose[:3, 3] for p in placed.placements])
        off_mesh = scene.closest_points(positions)[2]
        if worst is not None:
            assert off_mesh.max() < worst, off_mesh
        else:  # unseated, they stay on the flat fitted plane, up to 4.5 cm below the scan
            assert np.allclose(positions[:, 2], 2.8)


def test_a_clean_walls_panel_is_an_obstacle_and_a_noisy_walls_scatter_is_not():
    """The band that counts as the surface itself is plane_tolerance plus three sigmas of the scan's
    noise, at most surface_depth: 3 cm on a clean wall (its 4 cm panel blocks the windows above it),
    up to surface_depth (4 cm) on a noisy one."""
    config = FilterConfig()
    assert surface_band(0.0, config) == pytest.approx(0.03)
    assert surface_band(0.003, config) == pytest.approx(0.039)
    assert surface_band(0.05, config) == pytest.approx(config.surface_depth)

    b = room()
    b.box("panel", [1.0, 0.0, 0.0], [5.0, 0.04, 1.2])
    surfaces, result = run(b, TARGET)
    wall = kept_points(result, surfaces, names_by_id(b, surfaces), "room.wall0")
    over = wall[(wall[:, 0] > 1.5) & (wall[:, 0] < 4.5)]
    assert len(over) > 0
    assert over[:, 2].min() >= 1.2 + 0.5 + 0.25 - TOL  # the panel's top ends the fall


def test_scan_noise_measures_scatter_not_warp():
    """The noise estimate is near the vertex scatter of a rough wall and near zero on a smooth sag."""
    rng = np.random.default_rng(3)
    u, v = np.meshgrid(np.linspace(0, 4, 161), np.linspace(0, 2.5, 101))
    flat = np.column_stack([u.ravel(), np.zeros(u.size), v.ravel()])
    cols = 161
    quads = [(r * cols + c, r * cols + c + 1, (r + 1) * cols + c + 1, (r + 1) * cols + c)
             for r in range(100) for c in range(160)]
    faces = np.array([[a, b, c] for a, b, c, _ in quads] + [[a, c, d] for a, _, c, d in quads])
    frame = PlaneFrame.from_normal(np.array([2.0, 0.0, 1.25]), np.array([0.0, -1.0, 0.0]), UP)
    raster = rasterise(frame, [[frame.to_plane(np.array([[0.2, 0, 0.2], [3.8, 0, 0.2], [3.8, 0, 2.3],
                                                          [0.2, 0, 2.3]]))]], 0.02, 1, 10**7)
    for displacement, low, high in ((rng.normal(0, 0.01, u.size), 0.007, 0.013),
                                    (0.05 * np.sin(u.ravel() / 4 * np.pi), 0.0, 0.004)):
        vertices = flat.copy()
        vertices[:, 1] = displacement
        noise = scan_noise(RayScene(Mesh(vertices, faces)), raster, 0.08)
        assert low <= noise <= high, noise
