"""The placement cache keeps recent ray-cast scenes for re-plans, within its face budget."""

from __future__ import annotations

import trimesh

from perch_common.mesh import Mesh
from perch_placement.cache import PlacementCache


def sphere(subdivisions: int, radius: float = 1.0) -> Mesh:
    """An icosphere: 20 * 4**subdivisions faces. Each call is a new mesh object (as each request
    without the mesh cache is): only the placement cache can give it an earlier scene."""
    s = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    return Mesh(s.vertices, s.faces)


def test_a_scene_within_the_budget_is_kept_and_one_beyond_it_is_built_each_time():
    cache = PlacementCache(max_scene_faces=2000)
    assert cache.scene(sphere(3)) is cache.scene(sphere(3))      # 1280 faces: kept for the re-plan
    assert cache.scene_faces == 1280
    assert cache.scene(sphere(4)) is not cache.scene(sphere(4))  # 5120 faces: not kept, freed after its request
    assert cache.scene_faces == 1280 and cache.scene(sphere(3)) is cache.scene(sphere(3))


def test_the_same_mesh_object_keeps_its_own_scene_beyond_the_budget():
    """Stages in one process share the held mesh's scene (perch_common.raycast.ray_scene); the
    placement cache does not count it (the process's mesh cache does)."""
    cache, big = PlacementCache(max_scene_faces=2000), sphere(4)
    assert cache.scene(big) is cache.scene(big)
    assert cache.scene_faces == 0


def test_the_least_recently_used_scene_goes_when_the_faces_exceed_the_budget():
    cache = PlacementCache(max_scene_faces=2000)
    scene_a = cache.scene(sphere(3, 1.0))        # 1280 faces each: one fits
    cache.scene(sphere(3, 2.0))
    assert cache.scene_faces == 1280
    assert cache.scene(sphere(3, 1.0)) is not scene_a         # a was dropped for b


def test_without_a_budget_the_two_most_recent_scenes_stay():
    cache = PlacementCache()
    scene_a, scene_b = cache.scene(sphere(3, 1.0)), cache.scene(sphere(3, 2.0))
    assert cache.scene(sphere(3, 1.0)) is scene_a and cache.scene(sphere(3, 2.0)) is scene_b
    cache.scene(sphere(3, 3.0))
    assert cache.scene(sphere(3, 2.0)) is scene_b and cache.scene(sphere(3, 1.0)) is not scene_a
