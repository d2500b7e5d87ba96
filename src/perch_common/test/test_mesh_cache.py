"""Each mesh sent once: content ids, the bounded LRU, and the caller's book of who holds what."""

from __future__ import annotations

import numpy as np

from perch_common.mesh import Mesh
from perch_common.mesh_cache import (
    MESH_NOT_CACHED,
    MeshBook,
    MeshCache,
    MeshNotCached,
    is_mesh_not_cached,
    mesh_content_id,
)
from perch_common.raycast import RayScene


def _mesh(n: int, shift: float = 0.0) -> Mesh:
    rng = np.random.default_rng(n)
    return Mesh(rng.random((n, 3)) + shift, rng.integers(0, n, (2 * n, 3)))


def test_content_id_is_stable_and_changes_with_any_array():
    a = _mesh(100)
    assert mesh_content_id(a) == mesh_content_id(Mesh(a.vertices.copy(), a.faces.copy()))
    moved = Mesh(a.vertices + 1e-3, a.faces)
    coloured = Mesh(a.vertices, a.faces, np.zeros((100, 3), np.uint8))
    assert len({mesh_content_id(a), mesh_content_id(moved), mesh_content_id(coloured)}) == 3
    assert len(mesh_content_id(a)) == 32


def test_lru_drops_least_recently_used_beyond_its_budget():
    meshes = [_mesh(1000, i) for i in range(3)]
    size = meshes[0].vertices.nbytes + meshes[0].faces.nbytes
    cache = MeshCache(budget_bytes=int(2.5 * size))
    cache.put("a", meshes[0])
    cache.put("b", meshes[1])
    assert cache.get("a") is meshes[0]          # a is now the most recent
    cache.put("c", meshes[2])                   # over budget: b goes
    assert "b" not in cache and "a" in cache and "c" in cache
    assert cache.used_bytes == 2 * size
    cache.put("huge", _mesh(10000))             # larger than the whole budget: not kept
    assert "huge" not in cache and len(cache) == 2


def test_budget_counts_the_face_data_stages_derive_from_a_held_mesh():
    """A held mesh whose face areas a stage computed (24 B per face of cross products, kept with the
    mesh and shared by the copies requests get) counts them: the cache stays within its budget."""
    import copy

    meshes = [_mesh(1000, i) for i in range(2)]
    arrays = meshes[0].vertices.nbytes + meshes[0].faces.nbytes
    cache = MeshCache(budget_bytes=int(2.5 * arrays))
    cache.put("a", meshes[0])
    cache.put("b", meshes[1])
    assert cache.used_bytes == 2 * arrays
    for key in ("a", "b"):
        copy.copy(cache.get(key)).face_areas()   # what a stage does with the mesh of a request
    derived = 24 * meshes[0].num_faces
    assert cache.used_bytes <= cache.budget_bytes and "b" in cache and "a" not in cache
    assert cache.used_bytes == arrays + derived
    cache.put("c", _mesh(1000, 2))                # the next put evicts by what the meshes hold now
    assert cache.used_bytes <= cache.budget_bytes


def test_a_held_mesh_has_one_ray_scene_for_every_stage_and_the_budget_counts_it():
    """Stages in one process get copies of a held mesh: they share one ray-cast scene (one BVH
    build), and the cache counts the scene's memory with the mesh."""
    import copy

    from perch_common.raycast import SCENE_BYTES_PER_FACE, ray_scene

    mesh = _mesh(1000)
    cache = MeshCache(budget_bytes=10**9)
    cache.put("a", mesh)
    first, second = copy.copy(cache.get("a")), copy.copy(cache.get("a"))   # two stages' requests
    scene = ray_scene(first)
    assert ray_scene(second) is scene
    assert ray_scene(_mesh(1000)) is not scene                            # another mesh, its own scene
    assert cache.used_bytes == mesh.vertices.nbytes + mesh.faces.nbytes + SCENE_BYTES_PER_FACE * mesh.num_faces
    origin, target = mesh.vertices.mean(axis=0) + [0, 0, 5], mesh.vertices.mean(axis=0) - [0, 0, 5]
    assert scene.occluded(origin[None], target[None]).tolist() == RayScene(mesh).occluded(origin[None],
                                                                                         target[None]).tolist()


def test_arrays_sent_again_give_the_held_mesh_and_what_stages_derived_from_it(monkeypatch):
    """A caller that sends a held mesh's arrays again (the operator rendering views of the optimise
    request it kept) gets the held mesh's derived data, e.g. its ray-cast scene, not a fresh copy."""
    import perch_common.mesh_cache
    from perch_common.raycast import ray_scene
    from perch_common.ros.conversions import mesh_from_request, mesh_to_msg

    monkeypatch.setattr(perch_common.mesh_cache, "PROCESS_CACHE", MeshCache(10**9))
    mesh = _mesh(500, 7.0)
    msg = mesh_to_msg(mesh)
    msg.header.frame_id = "odom"
    first = mesh_from_request(msg)                # a stage receives the arrays: kept, then derives
    scene = ray_scene(first)
    again = mesh_from_request(mesh_to_msg(mesh))  # the same numbers from another caller
    assert ray_scene(again) is scene and again.frame_id == "map" and first.frame_id == "odom"
    assert ray_scene(mesh_from_request(mesh_to_msg(_mesh(500, 8.0)))) is not scene


def test_book_sends_ids_only_where_held_and_forgets_on_a_miss():
    book = MeshBook()
    assert not book.send_id_only("/perch/segment", "m1")
    book.holds("/perch/crop", "m1")
    assert not book.send_id_only("/perch/segment", "m1")        # crop holding it says nothing of segment
    book.holds("/perch/segment", "m1")
    assert book.send_id_only("/perch/segment", "m1") and not book.send_id_only("/perch/segment", "")
    book.missed("/perch/segment", "m1")                         # it restarted
    assert not book.send_id_only("/perch/segment", "m1") and book.send_id_only("/perch/crop", "m1")


def test_not_cached_error_names_the_fix_and_is_recognised_inside_a_stage_error():
    error = MeshNotCached("abc", "request mesh")
    assert str(error).startswith(MESH_NOT_CACHED) and "send the mesh arrays again" in str(error)
    assert is_mesh_not_cached(str(error))
    assert is_mesh_not_cached(f"stage segment (/perch/segment): failed: {error}")
    assert not is_mesh_not_cached("mesh is empty")


def test_a_derived_value_asked_by_two_threads_at_once_is_built_once():
    """The background preparation and a stage may ask for the same derived data at once: the second
    waits for the first build instead of building it again (copies of a held mesh share it)."""
    import copy
    import threading
    from concurrent.futures import ThreadPoolExecutor

    mesh = _mesh(50)
    started, release, builds = threading.Event(), threading.Event(), []

    def build():
        builds.append(1)
        started.set()
        assert release.wait(30)
        return np.arange(3)

    with ThreadPoolExecutor(2) as pool:
        first = pool.submit(mesh.derived, "thing", build)
        assert started.wait(30)
        second = pool.submit(copy.copy(mesh).derived, "thing", build)   # a request's copy of the held mesh
        release.set()
        assert first.result(30) is second.result(30)
    assert len(builds) == 1
    import pickle
    assert np.array_equal(pickle.loads(pickle.dumps(mesh)).derived("thing", lambda: None), np.arange(3))


def test_a_reply_mesh_is_prepared_in_the_background_for_the_stages_that_get_it_by_id(monkeypatch):
    """In a one-process graph a stage's reply mesh (the cleaned scan) is prepared by the registered
    preparers (the filter's samples and ray scene) while the next stages run; the stage that then gets
    the mesh by id finds the data built; a removed preparer no longer runs."""
    import threading

    import perch_common.mesh_cache
    from perch_common.mesh_cache import add_preparer, remove_preparer
    from perch_common.ros.conversions import cached_mesh_to_msg, id_only_msg, mesh_from_request

    monkeypatch.setattr(perch_common.mesh_cache, "PROCESS_CACHE", MeshCache(10**9))
    prepared, done = [], threading.Event()

    import os

    niceness = []

    def preparer(mesh):
        prepared.append(mesh.derived("prepared", lambda: mesh.num_faces))
        niceness.append(os.getpriority(os.PRIO_PROCESS, threading.get_native_id()))
        done.set()

    add_preparer(preparer)
    try:
        reply = cached_mesh_to_msg(_mesh(300, 3.0))
        assert done.wait(30) and prepared == [600]
        # Behind the stages (Linux: niceness per thread); the test's own thread keeps its own.
        own = os.getpriority(os.PRIO_PROCESS, threading.get_native_id())
        assert niceness == [max(perch_common.mesh_cache.PREPARE_NICENESS, own)]
        stage_mesh = mesh_from_request(id_only_msg(reply))
        assert stage_mesh.derived("prepared", lambda: -1) == 600   # built by the preparer, shared
    finally:
        remove_preparer(preparer)
    done.clear()
    cached_mesh_to_msg(_mesh(200, 4.0))
    assert perch_common.mesh_cache.prepare(_mesh(10)) is None and prepared == [600]
