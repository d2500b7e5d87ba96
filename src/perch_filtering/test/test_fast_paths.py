"""The filter's fast paths give the answers of the simple computations they replace.

Each fast path is checked against the plain version on seeded scenes and seeded random inputs; the
whole filter's answers before and after a speed-up are compared by filter_summary.py (region
summaries and per-filter removals on every generated kind and the shared real scans).
"""

import numpy as np
import pytest
from filter_summary import compare, summarise

from perch_common.mesh_samples import mesh_samples
from perch_common.proximity import clear_of_mesh
from perch_common.scene_generator import generate_scene
from perch_filtering.checks import geometry_in_front
from perch_filtering.raster import rasterise
from perch_filtering.sampling import SampleIndex, project
from perch_filtering.standoff import NODE_STEP, standoffs_clear
from perch_filtering.voxels import grid_rotation


@pytest.fixture(scope="module")
def room():
    return generate_scene(3, "two_rooms")


@pytest.mark.parametrize("standoff", [0.4, 0.5, 0.8])
def test_standoff_clearance_on_the_coarse_grid_equals_every_cell_measured(room, standoff):
    rng = np.random.default_rng(7)
    surfaces = [s for s in room.ground_truth_surfaces() if s.area > 2.0][:6]
    parts, points = [], []
    for s in surfaces:
        raster = rasterise(s.frame, s.boundary, 0.02, 3, 4_000_000)
        mask = raster.inside & (rng.random(raster.shape) < 0.7)
        asked = rng.random(int(mask.sum())) < 0.8
        parts.append((raster, mask, asked))
        points.append(raster.cell_world(mask)[asked] + standoff * s.frame.normal)
    points = np.concatenate(points)
    fast = standoffs_clear(room.mesh, parts, points, standoff, 0.35)
    # Every point asked of the closest-point scene: the filter's path from LARGE_QUERY points on.
    exact = clear_of_mesh(room.mesh, points, 0.35, 0.05, large_query=1)
    assert len(points) > 50_000 and 0 < exact.sum() < len(exact)  # both answers occur
    np.testing.assert_array_equal(fast, exact)


def test_standoff_clearance_cells_are_bounded_by_their_node():
    """The slack covers the farthest cell from its node: NODE_STEP / 2 cells on both axes."""
    rows = np.arange(40)
    node = (rows + NODE_STEP // 2) // NODE_STEP * NODE_STEP
    assert np.abs(rows - node).max() == NODE_STEP // 2


def test_summaries_compare_equal_to_themselves_and_name_a_changed_area():
    from perch_filtering.core import FilterConfig, filter_surfaces

    scene = generate_scene(1, "room")
    from filtering_accuracy import filter_input_surfaces

    result = filter_surfaces(scene.mesh, filter_input_surfaces(scene), scene.target, scene.up, FilterConfig())
    base = summarise(result)
    assert base["regions"] and compare(base, base) == []
    changed = summarise(result)
    changed["regions"][0]["area"] += 0.5
    first = next(iter(changed["removals"]))
    changed["removals"][first]["support"] += 0.5
    diffs = compare(base, changed)
    assert any("region 0" in d and "area" in d for d in diffs)
    assert any(f"surface {first} support" in d for d in diffs)


def _geometry_in_front_simple(samples, index, raster, own_faces, up, min_depth, max_depth, margin, own_min_depth):
    """All three plane coordinates of every candidate, then the tests (the code before the fast path)."""
    f = raster.frame
    rows, cols = raster.shape
    u_lo, u_hi = raster.u0 - margin, raster.u0 + (cols - 1) * raster.cell + margin
    v_lo, v_hi = raster.v0 - margin, raster.v0 + (rows - 1) * raster.cell + margin
    corners = [f.to_world(np.array([[u, v]]), np.array([d]))[0]
               for u in (u_lo, u_hi) for v in (v_lo, v_hi) for d in (min_depth, max_depth)]
    candidates = index.near_box(np.array(corners))
    local = project(samples.points[candidates], np.stack([f.normal, f.axis_u, f.axis_v]), f.origin)
    keep = (local[:, 0] > min_depth) & (local[:, 0] <= max_depth)
    keep &= (local[:, 1] >= u_lo) & (local[:, 1] <= u_hi) & (local[:, 2] >= v_lo) & (local[:, 2] <= v_hi)
    own = np.zeros(len(samples.face), bool)
    own[np.isin(samples.face, own_faces)] = True
    mine = keep & own[candidates]
    keep[mine] = local[mine, 0] > own_min_depth
    sel = local[keep]
    return sel[:, 0], sel[:, 1:], project(samples.points[candidates[keep]], up)[:, 0]


def test_geometry_in_front_equals_the_simple_selection(room):
    rng = np.random.default_rng(11)
    samples = mesh_samples(room.mesh, 0.05)
    index = SampleIndex(samples, grid_rotation(room.up))
    coarse_index = SampleIndex(samples, grid_rotation(room.up), bucket=0.5)
    checked = 0
    for s in room.ground_truth_surfaces():
        raster = rasterise(s.frame, s.boundary, 0.02, 20, 4_000_000)
        min_depth, own_min = rng.uniform(0.01, 0.06), rng.uniform(0.03, 0.08)
        max_depth, margin = rng.uniform(0.5, 1.2), rng.uniform(0.3, 1.0)
        fast = geometry_in_front(samples, index, raster, s.face_indices, room.up, min_depth, max_depth, margin, own_min)
        depth, uv, height = _geometry_in_front_simple(samples, index, raster, s.face_indices, room.up, min_depth,
                                                      max_depth, margin, own_min)
        np.testing.assert_array_equal(fast.depth, depth)
        np.testing.assert_array_equal(fast.uv, uv)
        np.testing.assert_array_equal(fast.height, height)
        checked += len(depth)
        coarse = geometry_in_front(samples, coarse_index, raster, s.face_indices, room.up, min_depth, max_depth,
                                   margin, own_min)
        # Another bucket size fetches the same samples in another order (the measures take maxima and minima).
        rows = np.column_stack([fast.depth, fast.uv, fast.height])
        other = np.column_stack([coarse.depth, coarse.uv, coarse.height])
        np.testing.assert_array_equal(rows[np.lexsort(rows.T)], other[np.lexsort(other.T)])
    assert checked > 10_000


def test_sight_shares_in_chunks_equal_one_batch_of_float64_rays(room, monkeypatch):
    """Chunked float32 sight lines give the shares of all pairs cast at once from float64 arrays."""
    from perch_common.raycast import ray_scene
    from perch_filtering import visibility

    rng = np.random.default_rng(5)
    scene = ray_scene(room.mesh)
    lo, hi = room.mesh.vertices.min(axis=0), room.mesh.vertices.max(axis=0)
    origins = lo + rng.random((3000, 3)) * (hi - lo)
    normals = rng.normal(size=(3000, 3))
    normals /= np.linalg.norm(normals, axis=1)[:, None]
    targets = room.target.sample(64, seed=0)
    facing = np.einsum("tk,ok->ot", targets, normals) > np.einsum("ok,ok->o", origins, normals)[:, None]
    o_idx, t_idx = np.nonzero(facing)
    seen = np.zeros(facing.shape, bool)
    seen[o_idx, t_idx] = ~scene.occluded(origins[o_idx], targets[t_idx])
    simple = (seen.sum(axis=1) / len(targets)).astype(np.float32)
    monkeypatch.setattr(visibility, "CHUNK_PAIRS", 1000)
    chunked = visibility._shares(origins, normals, targets, scene, None)
    np.testing.assert_array_equal(chunked, simple)
    assert 0.05 < (simple > 0).mean() < 0.95


def test_any_hit_equals_the_cast_hits(room):
    """The escape rays' occlusion query (any face) says hit exactly where the nearest-hit cast does."""
    from perch_common.raycast import RayScene, sphere_directions

    rng = np.random.default_rng(3)
    scene = RayScene(room.mesh)
    lo, hi = room.mesh.vertices.min(axis=0), room.mesh.vertices.max(axis=0)
    points = lo - 0.5 + rng.random((4000, 3)) * (hi - lo + 1.0)  # inside the rooms, in walls and outside
    directions = sphere_directions(32)
    origins, rays = np.repeat(points, len(directions), axis=0), np.tile(directions, (len(points), 1))
    hit = scene.cast(origins, rays).hit
    assert 0.2 < hit.mean() < 0.95  # both answers occur
    np.testing.assert_array_equal(scene.any_hit(origins, rays), hit)


@pytest.mark.parametrize("ufunc", [np.minimum, np.maximum])
def test_scatter_equals_ufunc_at_with_float64_values(ufunc):
    """The flat scatter of values rounded to the image's float32 equals ufunc.at with the float64 values."""
    from perch_filtering.checks import scatter

    rng = np.random.default_rng(9)
    image = rng.normal(size=(70, 90)).astype(np.float32)
    rows, cols = rng.integers(0, 70, 50_000), rng.integers(0, 90, 50_000)
    values = rng.normal(scale=2.0, size=50_000)  # float64, many per cell
    plain = image.copy()
    ufunc.at(plain, (rows, cols), values)
    scatter(ufunc, image, rows, cols, values)
    np.testing.assert_array_equal(image, plain)


def test_per_surface_threads_keep_the_order_and_stop_at_an_error(monkeypatch):
    """The per-surface phases return results in the surfaces' order, and an error stops the surfaces
    not yet started (a few run ahead of the one awaited)."""
    import threading

    from perch_filtering import core

    monkeypatch.setattr(core, "_surface_threads", lambda: 2)
    threads, started = set(), []

    def work(item):
        threads.add(threading.get_ident())
        started.append(item)
        if item == 5:
            raise ValueError("surface 5")
        return item * item + float(np.sum(np.sqrt(np.arange(200_000.0))))  # numpy work: releases the GIL

    expected = [i * i + float(np.sum(np.sqrt(np.arange(200_000.0)))) for i in range(5)]
    assert core._per_surface(work, list(range(5)), "test", 0.0, 1.0) == expected
    assert threading.get_ident() not in threads
    started.clear()
    with pytest.raises(ValueError, match="surface 5"):
        core._per_surface(work, list(range(40)), "test", 0.0, 1.0)
    assert 5 in started and max(started) < 5 + 2 * 2 + 1


@pytest.mark.parametrize("reachability_removes, observed_fails_in_child", [(False, False), (True, False), (True, True)])
def test_two_processes_give_the_one_process_answer(room, monkeypatch, reachability_removes, observed_fails_in_child):
    """The surfaces judged in two processes (a forked child takes half) give exactly the regions,
    evidence and removals of one process; also where reachability, which runs beside the second
    process's observed space, removes cells of the surfaces that process judged, and where that
    process fails and the caller takes its share."""
    import os

    from filtering_accuracy import filter_input_surfaces

    from perch_filtering import core

    caller = os.getpid()
    if observed_fails_in_child:
        observed = core._observed

        def failing_in_the_child(*args, **kwargs):
            if os.getpid() != caller:
                raise RuntimeError("observed space lost in the child")
            return observed(*args, **kwargs)
        monkeypatch.setattr(core, "_observed", failing_in_the_child)

    monkeypatch.setenv("OMP_NUM_THREADS", "2")
    monkeypatch.setattr(core, "SPLIT_MIN_CELLS", 0)  # split whatever the size (a fork pays from ~a building)
    monkeypatch.setattr(core, "SPLIT_MIN_OBSERVED_CELLS", 0)
    if reachability_removes:   # every surface loses its first row of live cells to reachability
        measured = core._reachability

        def removing(work, *args):
            out = measured(work, *args)
            for w, kept in out:
                rows = np.flatnonzero(kept.any(axis=1))
                if len(rows):
                    w.removal.reachability += float(kept[rows[0]].sum() * w.raster.cell_area)
                    kept[rows[0]] = False
                    w.removal.area_kept = float(kept.sum() * w.raster.cell_area)
            return out
        monkeypatch.setattr(core, "_reachability", removing)
    surfaces = filter_input_surfaces(room)
    # Strict about unobserved space, so that the rule removes cells where reachability removed some too.
    strict = dict(enclosed_escape_share=0.05, max_unobserved_share=0.0) if observed_fails_in_child else {}
    one = core.filter_surfaces(room.mesh, surfaces, room.target, room.up, core.FilterConfig(processes=1, **strict))
    two = core.filter_surfaces(room.mesh, surfaces, room.target, room.up, core.FilterConfig(processes=2, **strict))
    assert one.second_process == "" and "second_process" in two.timings
    assert two.second_process.startswith("failed: RuntimeError") if observed_fails_in_child else two.second_process == "done"
    assert len(one.regions) >= 4 and one.removals == two.removals
    assert [(r.source_surface, r.area, r.evidence) for r in one.regions] == \
        [(r.source_surface, r.area, r.evidence) for r in two.regions]
    for a, b in zip(one.regions, two.regions):
        np.testing.assert_array_equal(a.mesh.vertices, b.mesh.vertices)
        np.testing.assert_array_equal(a.mesh.faces, b.mesh.faces)


def test_a_prepared_mesh_has_its_closest_point_scene_only_when_its_cells_can_reach_a_large_query():
    from perch_common.mesh import Mesh
    from perch_common.proximity import LARGE_QUERY
    from perch_common.raycast import ray_scene
    from perch_filtering.core import prepare_mesh

    # A fresh copy: the module's room may have its scenes from other tests (Mesh.derived keeps them).
    room = generate_scene(3, "two_rooms").mesh
    area = float(room.face_areas().sum())
    small = Mesh(room.vertices.copy(), room.faces.copy())
    prepare_mesh(small, 0.05, raster_density=0.9 * np.sqrt(LARGE_QUERY / area))
    assert ray_scene(small)._closest is None
    large = Mesh(room.vertices.copy(), room.faces.copy())
    prepare_mesh(large, 0.05, raster_density=1.1 * np.sqrt(LARGE_QUERY / area))
    assert ray_scene(large)._closest is not None
    # The prepared scene answers as one built by the query itself.
    points = room.vertices[:50] + 0.3
    assert np.allclose(ray_scene(large).closest_points(points)[2], ray_scene(small).closest_points(points)[2])


def test_judging_batches_hold_one_large_surface_or_several_small_ones_largest_first():
    from perch_filtering.core import _batches

    # Total 12, a batch closes once it holds a fifth (2.4): the large ones alone, the small ones packed.
    assert _batches([1.0, 5.0, 1.0, 0.0, 1.0, 3.0, 1.0], 0.2) == [[1], [5], [0, 2, 4], [6, 3]]
    assert _batches([], 0.2) == []
