"""Observed space from the cameras that saw it: in a closed room whose west half alone was looked at,
a perch over the east half is refused (by the filter, and by the project checker with its reason),
one over the west half is kept; the same room without viewpoints (a bare mesh) keeps both."""

from __future__ import annotations

import numpy as np
from filtering_scenes import Builder

from perch_common.raycast import RayScene
from perch_common.target import TargetVolume
from perch_common.viewpoints import seen_free, viewpoint_rows
from perch_filtering.core import FilterConfig, filter_surfaces
from perch_filtering.perch_check import check_perches

UP = np.array([0.0, 0.0, 1.0])
TARGET = TargetVolume(center=[3.0, 2.5, 1.0], size=[2.0, 2.0, 1.0])


def closed_room() -> Builder:
    """A 6 x 5 x 3 m room, every wall, floor and ceiling scanned."""
    b = Builder()
    b.quad("floor", [[0, 0, 0], [6, 0, 0], [6, 5, 0], [0, 5, 0]], [0, 0, 1])
    b.quad("ceiling", [[0, 0, 3], [6, 0, 3], [6, 5, 3], [0, 5, 3]], [0, 0, -1])
    b.quad("wall_south", [[0, 0, 0], [6, 0, 0], [6, 0, 3], [0, 0, 3]], [0, 1, 0])
    b.quad("wall_north", [[0, 5, 0], [6, 5, 0], [6, 5, 3], [0, 5, 3]], [0, -1, 0])
    b.quad("wall_west", [[0, 0, 0], [0, 5, 0], [0, 5, 3], [0, 0, 3]], [1, 0, 0])
    b.quad("wall_east", [[6, 0, 0], [6, 5, 0], [6, 5, 3], [6, 0, 3]], [-1, 0, 0])
    return b


def west_views() -> np.ndarray:
    """Cameras on the line x = 3 m looking west (yaw -60..60 deg about -x), 3 heights x 3 positions: they
    saw the west half of the room and nothing east of x ~ 3 m."""
    centres, axes = [], []
    for y in (0.6, 2.5, 4.4):
        for z in (0.5, 1.5, 2.5):
            for yaw in np.radians([-60, -30, 0, 30, 60]):
                centres.append([3.0, y, z])
                axes.append([-np.cos(yaw), np.sin(yaw), 0.0])
    return viewpoint_rows(centres, axes, 5.0, 30.0)


def _south_kept_x(mesh, surfaces, south_id) -> np.ndarray:
    result = filter_surfaces(mesh, surfaces, TARGET, UP, FilterConfig())
    pts = [r.frame.to_world(r.polygons[0][0]) for r in result.regions if r.source_surface == south_id]
    return np.concatenate(pts)[:, 0] if pts else np.zeros(0)


def test_seen_free_needs_a_camera_that_looked_through_the_point():
    mesh = closed_room().mesh()
    scene, views = RayScene(mesh), west_views()
    points = np.array([[1.5, 2.5, 1.5],    # west half, in front of the cameras
                       [4.5, 2.5, 1.5],    # east half, behind every camera
                       [1.5, 2.5, 1.5]])
    np.testing.assert_array_equal(seen_free(scene, views, points), [True, False, True])
    # Range: a camera whose range ends before the wall behind the point measured nothing there.
    short = views.copy()
    short[:, 6] = 1.0
    assert not seen_free(scene, short, points[:1])[0]
    # Occlusion: a wall between the cameras and the point hides it.
    b = closed_room()
    b.quad("screen", [[2.5, -0.1, -0.1], [2.5, 5.1, -0.1], [2.5, 5.1, 3.1], [2.5, -0.1, 3.1]], [1, 0, 0])
    assert not seen_free(RayScene(b.mesh()), views, points[:1])[0]


def test_a_perch_over_space_no_camera_saw_is_refused_and_one_over_seen_space_is_kept():
    b = closed_room()
    names = b.names()
    surfaces = b.surfaces(names)
    south = surfaces[names.index("wall_south")].id
    bare = b.mesh()
    seen = b.mesh()
    seen.viewpoints = west_views()
    # A bare mesh: the closed room encloses everything, so the south wall keeps perches east too.
    assert _south_kept_x(bare, surfaces, south).max() > 4.5
    # With the cameras: perches only over the west half (plus the volumes' half-widths and a grid node).
    x = _south_kept_x(seen, surfaces, south)
    assert len(x) and x.min() < 2.0, "the west half keeps its perches"
    assert x.max() <= 3.0 + 0.35 + 0.15, x.max()
    # The project checker says why, and agrees on the west.
    east, west = check_perches(seen, [[5.0, 0.0, 1.8], [1.2, 0.0, 1.8]], [[0, 1.0, 0], [0, 1.0, 0]], UP)
    assert not east.safe and any(r.endswith("% unobserved (no camera saw it)") for r in east.reasons), east.reasons
    assert east.observed_share < 0.2
    assert west.observed_share >= 0.8 and not any("unobserved" in r for r in west.reasons), west.reasons
    # The same perch on the bare mesh is observed (the reason comes from the cameras, not the geometry).
    assert check_perches(bare, [[5.0, 0.0, 1.8]], [[0, 1.0, 0]], UP)[0].observed_share == 1.0
