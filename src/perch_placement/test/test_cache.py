"""The placement cache keeps recent ray-cast scenes for re-plans, within its face budget."""

from __future__ import annotations

import trimesh

from perch_common.mesh import Mesh
from perch_placement.cache import PlacementCache


def sphere(subdivisions: int, radius: float = 1.0) -> Mesh:
    """An icosphere: 20 * 4**subdivisions faces."""
    s = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    return Mesh(s.vertices, s.faces)


def test_a_scene_within_the_budget_is_kept_and_one_beyond_it_is_built_each_time():
    cache = PlacementCache(max_scene_faces=2000)
    small, big = sphere(3), sphere(4)            # 1280 and 5120 faces
    assert cache.scene(small) is cache.scene(small)
    assert cache.scene_faces == 1280
    first = cache.scene(big)
    assert cache.scene(big) is not first         # not kept: freed after its request
    assert cache.scene_faces == 1280 and cache.scene(small) is cache.scene(small)


def test_the_least_recently_used_scene_goes_when_the_faces_exceed_the_budget():
    cache = PlacementCache(max_scene_faces=2000)
    a, b = sphere(3, 1.0), sphere(3, 2.0)        # 1280 faces each: one fits
    scene_a = cache.scene(a)
    cache.scene(b)
    assert cache.scene_faces == 1280
    assert cache.scene(a) is not scene_a         # a was dropped for b


def test_without_a_budget_the_two_most_recent_scenes_stay():
    cache = PlacementCache()
    a, b, c = sphere(3, 1.0), sphere(3, 2.0), sphere(3, 3.0)
    scene_a, scene_b = cache.scene(a), cache.scene(b)
    assert cache.scene(a) is scene_a and cache.scene(b) is scene_b
    cache.scene(c)
    assert cache.scene(b) is scene_b and cache.scene(a) is not scene_a
