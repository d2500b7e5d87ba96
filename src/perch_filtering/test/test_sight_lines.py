"""Line of sight cast in rounds (`visible_shares(..., threshold=...)`) decides every cell exactly as
the shares of every sight line do, with fewer sight lines; its parts keep the full computation's
arithmetic."""

import numpy as np
import pytest

from perch_common.raycast import RayScene, ray_scene
from perch_common.scene_generator import generate_scene
from perch_filtering import visibility
from perch_filtering.raster import rasterise


@pytest.fixture(scope="module")
def room():
    return generate_scene(3, "two_rooms")


def _surfaces(room, seed: int, keep: float):
    """Rasters of the room's larger surfaces with seeded random masks (holes and ragged edges)."""
    rng = np.random.default_rng(seed)
    rasters, masks, offsets = [], [], []
    for s in [s for s in room.ground_truth_surfaces() if s.area > 1.0][:8]:
        raster = rasterise(s.frame, s.boundary, 0.02, 3, 4_000_000)
        rasters.append(raster)
        masks.append(raster.inside & (rng.random(raster.shape) < keep))
        offsets.append(float(rng.uniform(0.02, 0.1)))
    return rasters, masks, offsets


def _count_sight_lines(monkeypatch) -> list[int]:
    cast = []
    occlusion = visibility.patched_occlusion

    def counted(scene, patches, origins, targets):
        cast.append(len(origins))
        return occlusion(scene, patches, origins, targets)

    monkeypatch.setattr(visibility, "patched_occlusion", counted)
    return cast


def _assert_same_decisions(full, bounded, masks, threshold):
    for exact, fast, mask in zip(full, bounded, masks):
        np.testing.assert_array_equal(fast >= threshold, exact >= threshold)
        assert not fast[~mask].any()


@pytest.mark.parametrize("per_volume", [False, True])
def test_rounds_decide_every_cell_of_a_room_as_every_sight_line(room, per_volume, monkeypatch):
    scene = ray_scene(room.mesh)
    rasters, masks, offsets = _surfaces(room, 1, 0.8)
    targets = room.target.sample(64, seed=0)
    groups = None
    if per_volume:   # three overlapping "volumes" and a few points in none, as a target's volumes may be
        rng = np.random.default_rng(2)
        groups = rng.random((len(targets), 3)) < 0.4
    full = visibility.visible_shares(rasters, masks, offsets, targets, scene, None, 0.06, groups)
    values = np.concatenate([f[m] for f, m in zip(full, masks)])
    cast = _count_sight_lines(monkeypatch)
    # Thresholds at shares the cells have exactly (ties), between them, and the filter's own.
    for threshold in [0.2 - 1e-6, float(np.quantile(values, 0.3)), float(np.quantile(values, 0.7)), 0.5, 1e-9]:
        cast.clear()
        bounded = visibility.visible_shares(rasters, masks, offsets, targets, scene, None, 0.06, groups,
                                            threshold=threshold)
        _assert_same_decisions(full, bounded, masks, threshold)
        assert (sum(cast) > 0) == (threshold > 0)   # every share reaches 0: no sight line needed
    assert 0.1 < (values >= 0.2 - 1e-6).mean() < 0.9
    # Some cells sit exactly on a threshold asked above, so ties are decided too.
    assert (values == np.float32(np.quantile(values, 0.3))).any()


@pytest.mark.parametrize("seed", [3, 4, 5])
def test_rounds_decide_random_rasters_with_patches_as_every_sight_line(room, seed, monkeypatch):
    """Sparse random masks (isolated cells, lone nodes), random shares of points per group, and a
    patch scene that blocks some of the rays the mesh lets through."""
    rng = np.random.default_rng(seed)
    scene = ray_scene(room.mesh)
    if seed == 5:   # facing points and sight lines found in many small batches give the same answers
        monkeypatch.setattr(visibility, "FACING_NODES", 257)
        monkeypatch.setattr(visibility, "CHUNK_PAIRS", 1000)
    rasters, masks, offsets = _surfaces(room, seed, rng.uniform(0.05, 0.9))
    targets = room.target.sample(int(rng.integers(20, 80)), seed=seed)
    groups = rng.random((len(targets), int(rng.integers(1, 5)))) < rng.uniform(0.2, 0.8)
    lo, hi = room.mesh.vertices.min(axis=0), room.mesh.vertices.max(axis=0)
    centre = lo + rng.random((40, 3)) * (hi - lo)
    patch_vertices = np.concatenate([c + rng.normal(scale=0.4, size=(3, 3)) for c in centre])
    patches = RayScene(type(room.mesh)(patch_vertices, np.arange(len(patch_vertices)).reshape(-1, 3)))
    full = visibility.visible_shares(rasters, masks, offsets, targets, scene, patches, 0.06, groups)
    values = np.unique(np.concatenate([f[m] for f, m in zip(full, masks)]))
    cast = _count_sight_lines(monkeypatch)
    for threshold in [float(values[len(values) // 3]), float(values[-1]), 0.2 - 1e-6]:
        bounded = visibility.visible_shares(rasters, masks, offsets, targets, scene, patches, 0.06, groups,
                                            threshold=threshold)
        _assert_same_decisions(full, bounded, masks, threshold)
    assert len(cast)


def test_rounds_cast_fewer_sight_lines_than_every_one(room, monkeypatch):
    scene = ray_scene(room.mesh)
    rasters, masks, offsets = _surfaces(room, 6, 1.0)
    targets = room.target.sample(64, seed=0)
    cast = _count_sight_lines(monkeypatch)
    visibility.visible_shares(rasters, masks, offsets, targets, scene, None, 0.06)
    every = sum(cast)
    cast.clear()
    visibility.visible_shares(rasters, masks, offsets, targets, scene, None, 0.06, threshold=0.2 - 1e-6)
    assert sum(cast) < 0.8 * every


def _layout_case(rng, step):
    """A random mask, its node grid and weighed nodes built the plain way, and its `_Layout`."""
    mask = rng.random((int(rng.integers(5, 40)), int(rng.integers(5, 40)))) < rng.uniform(0.05, 0.9)
    mask[rng.integers(mask.shape[0]), rng.integers(mask.shape[1])] = True
    rows, cols = np.nonzero(mask)
    need = np.zeros((rows.max() // step + 2, cols.max() // step + 2), bool)
    weighed = np.zeros_like(need)
    for dr in (0, 1):
        for dc in (0, 1):
            need[rows // step + dr, cols // step + dc] = True
            weight = ((rows % step) if dr else (step - rows % step)) * ((cols % step) if dc else (step - cols % step))
            weighed[(rows // step + dr)[weight > 0], (cols // step + dc)[weight > 0]] = True
    return mask, need, weighed, visibility._Layout.of(mask, step)


def test_block_values_are_the_bilinear_interpolation_bit_for_bit():
    """Cells near the threshold are decided with `_Layout.block_values`, which must be `_bilinear`'s
    arithmetic exactly, on the full computation's node grid; the nodes it calls weighed are those
    some cell weighs."""
    rng = np.random.default_rng(8)
    for step in (1, 2, 3, 4):
        for _ in range(3):
            mask, need, weighed, layout = _layout_case(rng, step)
            np.testing.assert_array_equal(layout.need, need)
            np.testing.assert_array_equal(layout.weighed, weighed)
            grid = np.where(need, rng.integers(0, 65, need.shape) / 64, 0).astype(np.float32)
            rows, cols = np.nonzero(layout.filled)
            values = layout.block_values(grid, rows, cols)
            expected = visibility._bilinear(grid, step, mask.shape, mask)
            r = rows[:, None, None] * step + np.arange(step)[None, :, None]
            c = cols[:, None, None] * step + np.arange(step)[None, None, :]
            r, c = np.broadcast_arrays(r, c)
            inside = (r < mask.shape[0]) & (c < mask.shape[1])
            inside[inside] = mask[r[inside], c[inside]]
            np.testing.assert_array_equal(values[inside], expected[r[inside], c[inside]])
            assert inside.sum() == mask.sum()


def test_cells_decided_by_their_blocks_as_by_their_own_values():
    """Whole blocks decided from their four nodes' bounds decide every cell as its interpolated bounds
    do, with node values on and next to the threshold (float32 neighbours of it)."""
    rng = np.random.default_rng(14)
    threshold = 0.2 - 1e-6
    edge = np.float32(threshold)
    near = np.array([np.nextafter(edge, np.float32(0)), edge, np.nextafter(edge, np.float32(1)), 0.0, 1.0,
                     0.25, 0.15], np.float32)
    for step in (1, 2, 3, 4):
        layouts, masks, first = [], [], 0
        for _ in range(4):
            mask, need, _, layout = _layout_case(rng, step)
            layout.first, first = first, first + int(need.sum())
            layouts.append(layout)
            masks.append(mask)
        lower = rng.choice(near, first)
        upper = np.maximum(lower, rng.choice(near, first))
        exact = rng.random(first) < 0.3   # nodes cast in full: bounds equal
        upper[exact] = lower[exact]
        maps, undecided = visibility._decided_cells(layouts, masks, lower, upper, threshold)
        for k, (layout, mask, grid) in enumerate(zip(layouts, masks, maps)):
            low = visibility._bilinear(layout.node_grid(lower), step, mask.shape, mask)
            high = visibility._bilinear(layout.node_grid(upper), step, mask.shape, mask)
            open_ = mask & (low < threshold) & (high >= threshold)
            np.testing.assert_array_equal((grid >= threshold)[mask & ~open_], (low >= threshold)[mask & ~open_])
            rows, cols = undecided.get(k, (np.zeros(0, int), np.zeros(0, int)))
            np.testing.assert_array_equal(np.sort(rows * mask.shape[1] + cols), np.flatnonzero(open_))
            assert not grid[~mask].any()
        assert any(undecided.values())


def test_facing_per_raster_is_the_full_computation_bit_for_bit(room):
    """Each raster's targets side found once with its normal equals every node's own product."""
    rng = np.random.default_rng(10)
    rasters, masks, _ = _surfaces(room, 11, 0.5)
    layouts, origins, normals, first = [], [], [], 0
    for raster, mask in zip(rasters, masks):
        layout = visibility._Layout.of(mask, 3)
        layout.first, count = first, int(layout.need.sum())
        first += count
        layouts.append(layout)
        normal = rng.normal(size=3)   # also oblique normals: every rounding of the products counts
        normals.append(np.repeat((normal / np.linalg.norm(normal))[None], count, axis=0))
        origins.append(rng.normal(scale=3.0, size=(count, 3)))
    origins, normals = np.concatenate(origins), np.concatenate(normals)
    targets = rng.normal(scale=3.0, size=(70, 3))
    np.testing.assert_array_equal(visibility._facing_by_raster(origins, normals, targets, layouts),
                                  visibility._facing(origins, normals, targets).T)


@pytest.mark.parametrize("threshold", [None, 0.2 - 1e-6])
def test_surfaces_split_over_calls_get_the_maps_of_one_call(room, threshold):
    """A raster's map depends on it alone: the filter may ask for its surfaces in parts (processes)."""
    rng = np.random.default_rng(12)
    scene = ray_scene(room.mesh)
    rasters, masks, offsets = _surfaces(room, 13, 0.7)
    targets = room.target.sample(64, seed=0)
    groups = rng.random((len(targets), 3)) < 0.4
    whole = visibility.visible_shares(rasters, masks, offsets, targets, scene, None, 0.06, groups, threshold=threshold)
    for part in (slice(0, None, 2), slice(1, None, 2), slice(0, 3), slice(3, None)):
        alone = visibility.visible_shares(rasters[part], masks[part], offsets[part], targets, scene, None, 0.06, groups,
                                          threshold=threshold)
        for one, other in zip(whole[part], alone):
            np.testing.assert_array_equal(one, other)


def test_occluded_in_blocks_equals_each_segment_alone(room):
    """`occluded` prepares its segments in blocks: more than a few blocks give each segment's own answer."""
    from perch_common import raycast

    rng = np.random.default_rng(9)
    scene = ray_scene(room.mesh)
    lo, hi = room.mesh.vertices.min(axis=0), room.mesh.vertices.max(axis=0)
    count = 3 * raycast.SEGMENT_BLOCK + 17
    origins, targets = lo + rng.random((count, 3)) * (hi - lo), lo + rng.random((count, 3)) * (hi - lo)
    whole = scene.occluded(origins, targets)
    alone = np.concatenate([scene.occluded(origins[i:i + 999], targets[i:i + 999]) for i in range(0, count, 999)])
    np.testing.assert_array_equal(whole, alone)
    assert 0.1 < whole.mean() < 0.9
