"""The flight grid's, sample index's and observed rule's fast paths give the answers of the plain
computations they replace (issue 25): the plain versions are written out here and compared exactly on
seeded random grids and a generated scene."""

import numpy as np
import pytest
from scipy import ndimage

from perch_common.mesh_samples import mesh_samples
from perch_common.raycast import ray_scene, sphere_directions
from perch_common.scene_generator import generate_scene
from perch_filtering import voxels
from perch_filtering.observed import down_cone, escape_shares, escapes
from perch_filtering.sampling import SampleIndex, cell_keys, floor_cells, project, stable_sort


@pytest.fixture(scope="module")
def room():
    return generate_scene(3, "two_rooms")


def _free_distance_plain(occupied: np.ndarray, reach: int) -> np.ndarray:
    """The transform before the slabs: whole-grid passes, slices stacked along x."""
    import cv2

    nx, ny, nz = occupied.shape
    sep = reach + 2
    stack = np.ones((nz, nx + sep, ny), np.uint8)
    stack[:, :nx, :] = ~np.moveaxis(occupied, 2, 0)
    d2 = cv2.distanceTransform(stack.reshape(-1, ny), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    d2 = np.minimum(d2.reshape(nz, nx + sep, ny)[:, :nx, :], reach).astype(np.float32) ** 2
    best = d2.copy()
    for dz in range(1, reach + 1):
        np.minimum(best[:-dz], d2[dz:] + dz * dz, out=best[:-dz])
        np.minimum(best[dz:], d2[:-dz] + dz * dz, out=best[dz:])
    return np.moveaxis(np.sqrt(best), 0, 2)


def _random_occupancy(seed: int, shape=(37, 29, 23), fill=0.02) -> np.ndarray:
    rng = np.random.default_rng(seed)
    occupied = rng.random(shape) < fill
    occupied[5:30, 12, 3:20] = True  # a wall, so that components and long distances both occur
    return occupied


@pytest.mark.parametrize("threads", [1, 2])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_free_distance_equals_the_whole_grid_transform(seed, threads, monkeypatch):
    import contextlib

    from perch_common.threads import one_thread, work_threads

    occupied = _random_occupancy(seed)
    monkeypatch.setattr(voxels, "SLAB_BYTES", 4 * 23 * 37 * 3)  # several slabs, one shorter
    with one_thread() if threads == 1 else contextlib.nullcontext():   # two: the slabs in two halves
        if work_threads() != threads:
            pytest.skip(f"{threads} threads are not allowed here (OMP_NUM_THREADS)")
        for reach in (3, 8, 10):
            np.testing.assert_array_equal(voxels.free_distance(occupied, reach), _free_distance_plain(occupied, reach))


@pytest.mark.parametrize("seed", [0, 1])
def test_the_hover_reach_decides_every_threshold_as_a_longer_reach(seed):
    """build_flight_grid asks distances up to the hover threshold only: every comparison it makes reads
    the same as with the former reach (drone radius + 3 voxels)."""
    occupied = _random_occupancy(seed, fill=0.004)
    radius_voxels = 0.35 / 0.05
    hover = radius_voxels + np.sqrt(3.0) / 2
    short = voxels.free_distance(occupied, int(np.floor(hover)) + 1)
    long = _free_distance_plain(occupied, int(np.ceil(radius_voxels)) + 3)
    assert (long > hover).any() and (long < radius_voxels).any()
    for threshold in (voxels.OPEN_SPACE_VOXELS, radius_voxels, hover):
        np.testing.assert_array_equal(short >= threshold, long >= threshold)
        np.testing.assert_array_equal(short > threshold, long > threshold)


SIX_CONNECTED = ndimage.generate_binary_structure(3, 1)


@pytest.mark.parametrize("seed, shape, density, most_seeds", [
    (0, (30, 20, 10), 0.55, 8), (1, (30, 20, 10), 0.55, 8), (2, (30, 20, 10), 0.55, 8),
    (3, (160, 160, 80), 0.15, 200)])  # > 65,535 components; seeds in more than PICK_BY_COMPARISON of them
def test_connected_to_and_grown_equal_isin_and_binary_dilation(seed, shape, density, most_seeds):
    rng = np.random.default_rng(seed)
    free = rng.random(shape) < density
    seeds = rng.integers(0, shape, size=(int(rng.integers(0, most_seeds)), 3))
    labels, _ = ndimage.label(free, structure=SIX_CONNECTED)
    hit = np.unique(labels[seeds[:, 0], seeds[:, 1], seeds[:, 2]])
    plain = np.isin(labels, hit[hit > 0])
    np.testing.assert_array_equal(voxels._connected_to(free, seeds), plain)
    np.testing.assert_array_equal(voxels._grown(plain), ndimage.binary_dilation(plain, SIX_CONNECTED))


def test_stable_sort_equals_numpy_stable():
    rng = np.random.default_rng(3)
    for n, top in ((0, 1), (1, 1), (1000, 7), (100_000, 50_000), (100_000, 1 << 32), (1000, 1 << 40), (10, 1 << 60)):
        key = rng.integers(0, top, n)
        order, sorted_key = stable_sort(key)
        np.testing.assert_array_equal(order, np.argsort(key, kind="stable"))
        np.testing.assert_array_equal(sorted_key, np.sort(key))


def test_cell_keys_equal_the_raveled_cells(monkeypatch):
    from perch_filtering import sampling

    monkeypatch.setattr(sampling, "FLOOR_CHUNK", 1000)  # several chunks, the last one shorter
    local = np.asfortranarray(np.random.default_rng(8).normal(size=(4321, 3)) * 5)
    lo = local.min(axis=0) - 0.05
    cells = floor_cells(local, lo, 0.05)
    dims = tuple(cells.max(axis=0) + 1)
    np.testing.assert_array_equal(cell_keys(local, lo, 0.05, dims), np.ravel_multi_index(cells.T, dims))
    # SampleIndex sizes its grid from the largest coordinate alone: the largest cell.
    assert tuple(np.floor((local.max(axis=0) - local.min(axis=0)) / 0.25).astype(np.int64) + 1) == \
        tuple(floor_cells(local, local.min(axis=0), 0.25).max(axis=0) + 1)


@pytest.mark.parametrize("count", [1000, 5001])
def test_project_equals_the_row_sums(count, monkeypatch):
    from perch_filtering import sampling

    monkeypatch.setattr(sampling, "PROJECT_SPLIT", 2000)   # 5001 points: two halves on two threads
    rng = np.random.default_rng(4)
    points, axes, origin = rng.normal(size=(count, 3)) * 10, rng.normal(size=(3, 3)), rng.normal(size=3)
    p = points - origin
    plain = np.column_stack([p[:, 0] * a[0] + p[:, 1] * a[1] + p[:, 2] * a[2] for a in axes])
    np.testing.assert_array_equal(project(points, axes, origin), plain)


def test_index_columns_hold_the_samples_of_near_box(room):
    samples = mesh_samples(room.mesh, 0.05)
    index = SampleIndex(samples, voxels.grid_rotation(room.up))
    rng = np.random.default_rng(5)
    lo, hi = samples.points.min(axis=0), samples.points.max(axis=0)
    for _ in range(5):
        corners = lo + rng.random((8, 3)) * (hi - lo)
        at = index.positions_near_box(corners)
        found = index.near_box(corners)
        assert len(found) > 0
        np.testing.assert_array_equal(np.column_stack([index.x[at], index.y[at], index.z[at]]), samples.points[found])
        np.testing.assert_array_equal(index.face[at], samples.face[found])


def test_escapes_equal_the_shares_of_every_ray(room):
    scene = ray_scene(room.mesh)
    rng = np.random.default_rng(6)
    lo, hi = room.mesh.vertices.min(axis=0), room.mesh.vertices.max(axis=0)
    points = lo - 1.0 + rng.random((3000, 3)) * (hi - lo + 2.0)  # inside the rooms and outside them
    for directions in (sphere_directions(32), down_cone(np.array([0, 0, -1.0]))):
        shares = escape_shares(scene, points, directions)
        assert 0 < (shares > 0.5).mean() < 1
        for share in (0.25, 0.5, 0.75):
            np.testing.assert_array_equal(escapes(scene, points, directions, share), shares > share)
