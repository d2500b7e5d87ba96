"""The support statistics read at the live window centres equal the whole-raster computation they replace.

`reference_support` is the plain computation (every depth bin's window sums over the whole raster, the
turned windows convolved bin by bin); `local_window_support` takes them only at the centres, the
turned windows only where the upright one passes and, there, only where a turned window can hold a cell
off the plane. Seeded random depth maps with holes, out-of-band cells, outliers and ties at the share
threshold.
"""

import cv2
import numpy as np
import pytest

from perch_common.types import PlaneFrame
from perch_filtering.raster import SurfaceRaster, turned_kernel, window_kernel
from perch_filtering.support import _near_limits, _ray_origins, local_window_support, turned_kernels

BAND, TOLERANCE, BIN = 0.05, 0.03, 0.003  # the filter's defaults: plane_tolerance + max_support_rms, 3 cm, 3 mm


def reference_support(depth, kernel, band, tolerance, bin_width, turned=()):
    """(offset, share, rms) of the window centred on every cell: the filter's computation before it was
    taken at the centres only."""
    def box_sum(values, k):
        v = values.astype(np.float32)
        if k.all():
            return cv2.boxFilter(v, -1, k.shape[::-1], normalize=False, borderType=cv2.BORDER_CONSTANT)
        return cv2.filter2D(v, -1, k.astype(np.float32), borderType=cv2.BORDER_CONSTANT)

    shape = depth.shape
    valid = np.isfinite(depth) & (np.abs(depth) <= band)
    d = np.where(valid, depth, 0.0).astype(np.float32)
    edges = np.arange(-band, band + bin_width, bin_width)
    bins = np.clip(np.floor((d + band) / bin_width).astype(np.int64), 0, len(edges) - 2)
    half = 0.5 * box_sum(valid, kernel)
    below = np.zeros(shape, np.float32)
    median = np.full(shape, np.nan, np.float32)
    counts = {}
    for b in np.unique(bins[valid]):
        mine = valid & (bins == b)
        counts[b] = (mine, box_sum(mine, kernel))
        crossed = np.isnan(median) & (below + counts[b][1] >= half) & (half > 0)
        position = np.clip((half - below) / np.maximum(counts[b][1], 1e-6), 0.0, 1.0)
        median[crossed] = (edges[b] + position * bin_width)[crossed]
        below += counts[b][1]
    m = np.nan_to_num(median, nan=0.0)
    count = np.zeros(shape, np.float32)
    squares = np.zeros(shape, np.float32)
    turned_counts = [np.zeros(shape, np.float32) for _ in turned]
    for b, (mine, n) in counts.items():
        near = np.abs(edges[b] + 0.5 * bin_width - m) <= tolerance
        if not near.any():
            continue
        dm = np.where(mine, d, 0.0)
        s1, s2 = box_sum(dm, kernel), box_sum(dm * dm, kernel)
        count += np.where(near, n, 0.0)
        squares += np.where(near, s2 - 2.0 * m * s1 + m * m * n, 0.0)
        for other, other_count in zip(turned, turned_counts):
            other_count += np.where(near, box_sum(mine, other), 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        rms = np.where(count > 0.5, np.sqrt(np.maximum(squares, 0.0) / np.maximum(count, 1.0)), np.inf)
    share = count / float(kernel.sum())
    for other, other_count in zip(turned, turned_counts):
        share = np.minimum(share, other_count / float(other.sum()))
    return m, share.astype(np.float32), rms.astype(np.float32)


def random_depth(rng, shape, noise, holes=0.02, outliers=0.02, tilt=0.0):
    """A scanned surface: a gentle warp and tilt, scan noise, holes (NaN), cells beyond the band and
    outliers in front within it, and a torn edge."""
    r, c = np.mgrid[0:shape[0], 0:shape[1]]
    depth = (0.008 * np.sin(r / 17.0) * np.cos(c / 23.0) + tilt * (c - shape[1] / 2) / shape[1]
             + rng.normal(0.0, noise, shape)).astype(np.float32)
    depth[rng.random(shape) < holes] = np.nan
    spots = rng.random(shape) < outliers
    depth[spots] = rng.uniform(-0.045, 0.045, int(spots.sum())).astype(np.float32)
    far = rng.random(shape) < 0.005
    depth[far] = 0.2  # beyond the band: not the surface
    depth[:, : shape[1] // 10] = np.where(rng.random((shape[0], shape[1] // 10)) < 0.5, np.nan, 0.04)  # torn edge
    return depth


def centres_of(rng, shape, share=0.6):
    return rng.random(shape) < share


def assert_equal_at_centres(depth, kernel, turned, centres, min_share, max_rms, exact_share):
    m, share, rms = reference_support(depth, kernel, BAND, TOLERANCE, BIN, turned)
    got = local_window_support(depth, kernel, BAND, TOLERANCE, BIN, turned, centres=centres,
                               min_share=min_share, max_rms=max_rms)
    np.testing.assert_array_equal(got.offset[centres], m[centres])
    # The squares are summed in float64: the reference's float32 cancellation is a few micrometres.
    np.testing.assert_allclose(got.rms[centres], rms[centres], rtol=1e-4, atol=1e-5)
    ok_reference = (share >= min_share) & (rms <= max_rms)
    ok = (got.share >= min_share) & (got.rms <= max_rms)
    np.testing.assert_array_equal(ok[centres], ok_reference[centres])
    passing = centres & ok_reference
    if exact_share:
        np.testing.assert_array_equal(got.share[passing], share[passing])
    else:  # the reference's DFT convolutions carry float noise; the counts are integers
        np.testing.assert_allclose(got.share[passing], share[passing], atol=1e-5)
    # Off the centres nothing is judged.
    assert (got.share[~centres] == 0).all() and np.isinf(got.rms[~centres]).all()
    return ok[centres].mean(), passing.sum()


@pytest.mark.parametrize("seed", range(6))
def test_small_windows_in_every_yaw_equal_the_whole_raster_computation(seed):
    """7 x 7 windows turned every 15 deg: OpenCV convolves kernels this small directly, so the
    reference's counts are exact: the same offsets, decisions and shares."""
    rng = np.random.default_rng(seed)
    kernel = window_kernel(0.14, 0.14, 0.02, False)
    turned = [turned_kernel(kernel, np.radians(yaw)) for yaw in (15, 30, 45, 60, 75)]
    depth = random_depth(rng, (60 + 7 * seed, 90), noise=(0.002, 0.006, 0.012)[seed % 3], tilt=0.01 * (seed % 2))
    kept, judged = assert_equal_at_centres(depth, kernel, turned, centres_of(rng, depth.shape), 0.9 - 1e-6, 0.02,
                                           exact_share=True)
    assert 0.05 < kept < 0.95 and judged > 50  # both answers occur


def test_oblong_windows_turned_to_half_a_turn_equal_the_whole_raster_computation():
    """A 9 x 5 window (a rectangle repeats after half a turn: 11 yaws) on a noisy tilted scan."""
    rng = np.random.default_rng(21)
    kernel = window_kernel(0.18, 0.1, 0.02, False)
    turned = turned_kernels(kernel, tuple(np.radians(np.arange(15.0, 180.0 - 1e-9, 15.0))))
    assert len(turned) == 11 and kernel.shape == (5, 9)
    depth = random_depth(rng, (70, 90), noise=0.006, tilt=0.02)
    kept, judged = assert_equal_at_centres(depth, kernel, turned, centres_of(rng, depth.shape), 0.9 - 1e-6, 0.02,
                                           exact_share=True)
    assert 0.05 < kept < 0.95 and judged > 50


def test_ties_at_the_share_threshold_are_decided_alike():
    """A threshold that many windows meet exactly: k of 49 cells, the same float32 share both ways."""
    rng = np.random.default_rng(11)
    kernel = window_kernel(0.14, 0.14, 0.02, False)
    turned = [turned_kernel(kernel, np.radians(yaw)) for yaw in (15, 30, 45, 60, 75)]
    depth = np.zeros((50, 70), np.float32)
    depth[rng.random(depth.shape) < 0.04] = np.nan
    m, share, rms = reference_support(depth, kernel, BAND, TOLERANCE, BIN, turned)
    centres = np.ones(depth.shape, bool)
    values, counts = np.unique(share[share > 0.5], return_counts=True)
    tie = float(values[np.argmax(counts * (values < 1))])  # the most common share below 1
    got = local_window_support(depth, kernel, BAND, TOLERANCE, BIN, turned, centres=centres, min_share=tie)
    at_tie = share == tie
    assert at_tie.sum() > 20
    np.testing.assert_array_equal(got.share >= tie, share >= tie)
    np.testing.assert_array_equal(got.share[share >= tie], share[share >= tie])


@pytest.mark.parametrize("seed", range(2))
def test_filter_sized_windows_equal_the_whole_raster_computation(seed):
    """The filter's 25 x 25 window and its 35 x 35 turns (convolved by DFT in the reference)."""
    rng = np.random.default_rng(100 + seed)
    kernel = window_kernel(0.5, 0.5, 0.02, False)
    turned = turned_kernels(kernel, tuple(np.radians([15.0, 30.0, 45.0, 60.0, 75.0])))
    depth = random_depth(rng, (110, 150), noise=0.006, holes=0.004, outliers=0.01)
    kept, judged = assert_equal_at_centres(depth, kernel, turned, centres_of(rng, depth.shape, 0.5), 0.9 - 1e-6,
                                           0.02, exact_share=False)
    assert 0.05 < kept < 0.95 and judged > 500


def test_walls_and_elliptic_windows_without_centres_equal_the_whole_raster_computation():
    """No turns (a wall), every cell a centre; and an elliptic window (a kernel that is no rectangle,
    small enough that the reference convolves it directly, so its counts are exact)."""
    rng = np.random.default_rng(5)
    depth = random_depth(rng, (70, 80), noise=0.008)
    for kernel in (window_kernel(0.3, 0.2, 0.02, False), window_kernel(0.2, 0.2, 0.02, True)):
        m, share, rms = reference_support(depth, kernel, BAND, TOLERANCE, BIN)
        got = local_window_support(depth, kernel, BAND, TOLERANCE, BIN)
        np.testing.assert_array_equal(got.offset, m)
        np.testing.assert_allclose(got.share, share, atol=1e-5)
        np.testing.assert_allclose(got.rms, rms, rtol=1e-4, atol=1e-5)


def test_outlier_bins_far_from_some_centres_and_rasters_without_depth():
    """A bin whose cells sit in one corner is summed only near it; centres at the raster's border;
    a raster with no depth in the band gives share 0 and an infinite RMS at every centre."""
    rng = np.random.default_rng(9)
    kernel = window_kernel(0.14, 0.14, 0.02, False)
    turned = [turned_kernel(kernel, np.radians(yaw)) for yaw in (15, 30, 45, 60, 75)]
    depth = rng.normal(0.0, 0.003, (40, 60)).astype(np.float32)
    depth[:6, :5] = 0.032  # a corner of outliers in bins no other cell has
    centres = np.zeros(depth.shape, bool)
    centres[::3, ::2] = True
    centres[0, :] = centres[-1, :] = centres[:, 0] = centres[:, -1] = True
    assert_equal_at_centres(depth, kernel, turned, centres, 0.9 - 1e-6, 0.02, exact_share=True)
    empty = local_window_support(np.full((20, 20), np.nan, np.float32), kernel, BAND, TOLERANCE, BIN, turned)
    assert (empty.share == 0).all() and np.isinf(empty.rms).all() and (empty.offset == 0).all()


def test_the_near_run_of_bins_is_the_per_bin_tolerance_test():
    """The float32 limits give exactly the bins whose centre is within tolerance of m in float64,
    also for m one float32 step either side of each limit."""
    rng = np.random.default_rng(3)
    edges = np.arange(-BAND, BAND + BIN, BIN)
    centres = edges[:-1] + 0.5 * BIN
    limits = np.array([_near_limits(c, TOLERANCE) for c in centres], np.float32)
    ms = [rng.uniform(-BAND, BAND, 2000).astype(np.float32)]
    for step in (-np.inf, np.inf):
        ms += [np.nextafter(limits[:, 0], np.float32(step)), np.nextafter(limits[:, 1], np.float32(step))]
    m = np.concatenate(ms + [limits[:, 0], limits[:, 1]])
    near = np.abs(centres[:, None] - m[None, :]) <= TOLERANCE
    np.testing.assert_array_equal((limits[:, :1] <= m) & (m <= limits[:, 1:]), near)


def test_ray_origins_are_the_cell_centres_in_front_in_float32():
    rng = np.random.default_rng(2)
    normal = rng.normal(size=3)
    normal /= np.linalg.norm(normal)
    u = np.cross(normal, [0.0, 0.0, 1.0])
    u /= np.linalg.norm(u)
    frame = PlaneFrame(rng.uniform(-20, 20, 3), u, np.cross(normal, u), normal)
    raster = SurfaceRaster(frame, 0.02, -3.117, 1.203, (300, 700), np.ones((300, 700), bool))
    cells = rng.random(raster.shape) < 0.7
    expected = np.asarray(raster.cell_world(cells) + 0.07 * normal, np.float32)
    np.testing.assert_array_equal(_ray_origins(raster, *np.nonzero(cells), 0.07), expected)


def test_turned_kernels_are_made_once_and_not_shared_writable():
    kernel = window_kernel(0.5, 0.3, 0.02, False)
    yaws = tuple(np.radians([15.0, 30.0, 45.0]))
    first, again = turned_kernels(kernel, yaws), turned_kernels(kernel.copy(), yaws)
    for a, b, yaw in zip(first, again, yaws):
        assert a is b
        np.testing.assert_array_equal(a, turned_kernel(kernel, yaw))
        assert not a.flags.writeable


def test_first_surface_depth_is_the_first_hit_in_front_of_each_cell():
    """Against RayScene.cast from the cells' world centres: a floor with a hole, a step within the
    probe, a slab beyond it; the same float32 depths and NaN where nothing lies within the probe."""
    from perch_common.mesh import Mesh
    from perch_common.raycast import RayScene
    from perch_filtering.support import first_surface_depth

    def quad(x0, y0, x1, y1, z):
        v = np.array([[x0, y0, z], [x1, y0, z], [x1, y1, z], [x0, y1, z]], np.float64)
        return v, np.array([[0, 1, 2], [0, 2, 3]])

    parts = [quad(0, 0, 1, 2, 0.0), quad(1.2, 0, 3, 2, 0.0), quad(0.5, 0.5, 1.5, 1.0, 0.013), quad(2, 1, 3, 2, -0.5)]
    vertices = np.concatenate([v for v, _ in parts])
    faces = np.concatenate([f + 4 * i for i, (_, f) in enumerate(parts)])
    scene = RayScene(Mesh(vertices, faces))
    frame = PlaneFrame(np.zeros(3), np.array([1.0, 0, 0]), np.array([0, 1.0, 0]), np.array([0, 0, 1.0]))
    raster = SurfaceRaster(frame, 0.02, 0.013, 0.007, (100, 150), np.ones((100, 150), bool))
    cells = np.random.default_rng(4).random(raster.shape) < 0.8
    probe = 0.06
    depth = first_surface_depth(scene, raster, cells, probe)
    normal = frame.normal
    hits = scene.cast(raster.cell_world(cells) + probe * normal, np.repeat(-normal[None], int(cells.sum()), axis=0))
    expected = np.full(raster.shape, np.nan, np.float32)
    expected[cells] = np.where(hits.hit & (hits.distance <= 2 * probe), probe - hits.distance, np.nan)
    np.testing.assert_array_equal(depth, expected)
    box = (slice(13, 71), slice(40, 150))
    np.testing.assert_array_equal(first_surface_depth(scene, raster, cells[box], probe, box), expected[box])
    assert np.isnan(depth[cells]).any() and (depth[cells] > 0.01).any() and (np.abs(depth) < 1e-6).any()
    np.testing.assert_array_equal(scene.first_hit_distance(raster.cell_world(cells) + probe * normal,
                                                           np.repeat(-normal[None], int(cells.sum()), axis=0)),
                                  hits.distance)


@pytest.mark.parametrize("seed", range(3))
def test_window_counts_from_row_prefix_sums_equal_the_rounded_convolution(seed):
    """The turned windows' counts read at some centres from row prefix sums are cv2.filter2D's (rounded)
    on near-bin masks of scanned-looking depth maps, for the filter's 25-cell window in every yaw and
    for ragged kernels whose rows hold several runs; windows reaching past the mask count nothing there."""
    from perch_filtering.support import _WindowCounts

    rng = np.random.default_rng(seed)
    depth = random_depth(rng, (150, 210), noise=(0.002, 0.006, 0.012)[seed])
    mask = (np.abs(depth) <= 0.01).astype(np.uint8) * 255  # a run of near bins (NaN: not near)
    kernel = window_kernel(0.5, 0.5, 0.02, False)
    kernels = turned_kernels(kernel, tuple(np.radians(np.arange(15.0, 90.0, 15.0))))
    kernels += [(rng.random((9, 13)) < 0.6).astype(np.uint8), (rng.random((35, 35)) < 0.3).astype(np.uint8)]
    reach = max(max(k.shape) for k in kernels) // 2
    rows, cols = np.nonzero(rng.random(mask.shape) < 0.3)  # the borders included
    counts = _WindowCounts(mask, reach, rows, cols)
    for k in kernels:
        plain = np.rint(cv2.filter2D((mask > 0).astype(np.float32), -1, k.astype(np.float32),
                                     borderType=cv2.BORDER_CONSTANT))[rows, cols]
        got = counts.of(k)
        assert got.dtype == np.float32
        np.testing.assert_array_equal(got, plain)
        assert 0 < (got / k.sum()).mean() < 1  # partial windows occur
