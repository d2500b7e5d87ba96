"""Support on the scan: how much of a perch window has scanned surface on its perch plane, and how flat.

One ray per raster cell, cast along the inverted normal from in front of everything that counts as
the surface (`surface_depth`), finds the first scanned surface under that cell. A window's perch
plane is parallel to the surface's fitted plane, at the median depth of the window's first hits:
on a noisy scan the fitted plane is centimetres off locally (a ceiling warped by 10 cm over a
room), and the drone perches on what it touches. A cell is supported when its first hit lies
within `plane_tolerance` of that perch plane; holes, edges and ragged geometry in front leave
cells unsupported. Window statistics are box sums over depth bins.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from perch_common.raycast import RayScene
from perch_filtering.raster import SurfaceRaster


def first_surface_depth(scene: RayScene, raster: SurfaceRaster, cells: np.ndarray, probe: float) -> np.ndarray:
    """Signed depth (m, + towards free space) of the first scanned surface under each cell in `cells`:
    a ray cast along the inverted normal from `probe` in front of the plane; NaN where it finds nothing
    within `probe` of the plane on either side."""
    depth = np.full(raster.shape, np.nan, np.float32)
    if not cells.any():
        return depth
    normal = raster.frame.normal
    origins = raster.cell_world(cells) + probe * normal
    hits = scene.cast(origins, np.repeat(-normal[None], len(origins), axis=0))
    ok = hits.hit & (hits.distance <= 2.0 * probe)
    depth[cells] = np.where(ok, probe - hits.distance, np.nan)
    return depth


NOISE_PAIRS = 4000  # cell pairs sampled per surface for its scan noise
NOISE_LAG = 0.1  # m between the cells of a pair (about a scan triangle: adjacent cells share one)


def scan_noise(scene: RayScene, raster: SurfaceRaster, probe: float) -> float:
    """Scan noise (m, one sigma) of a surface: the spread of first-surface depths between cells
    NOISE_LAG apart along u, from a robust MAD over up to NOISE_PAIRS evenly strided pairs. Such
    differences see scatter, not the surface's steps, warp or tilt (those change depth slowly or
    only along a few edges). 0 when too few pairs land on the surface."""
    lag = max(1, int(round(NOISE_LAG / raster.cell)))
    if raster.shape[1] <= lag:
        return 0.0
    rows, cols = np.nonzero(raster.inside[:, :-lag] & raster.inside[:, lag:])
    if len(rows) == 0:
        return 0.0
    stride = max(1, len(rows) // NOISE_PAIRS)
    rows, cols = rows[::stride], cols[::stride]
    cells = np.zeros(raster.shape, bool)
    cells[rows, cols] = True
    cells[rows, cols + lag] = True
    depth = first_surface_depth(scene, raster, cells, probe)
    a, b = depth[rows, cols], depth[rows, cols + lag]
    ok = np.isfinite(a) & np.isfinite(b)
    if ok.sum() < 20:
        return 0.0
    return float(1.4826 * np.median(np.abs(a[ok] - b[ok])) / np.sqrt(2.0))


@dataclass
class LocalSupport:
    """Per window centre: the local perch plane's offset along the normal, the share of the window
    within tolerance of it and the RMS distance there."""

    offset: np.ndarray  # float32 (rows, cols), m
    share: np.ndarray
    rms: np.ndarray


def local_window_support(depth: np.ndarray, kernel: np.ndarray, band: float, tolerance: float,
                         bin_width: float, turned: list[np.ndarray] = ()) -> LocalSupport:
    """Support of the window centred on every cell against its own perch plane.

    The perch plane lies at the median of the window's first-surface depths within `band` of the
    fitted plane; the share counts the window's cells within `tolerance` of it (holes count as
    unsupported) and the RMS is their distance to it. Depths are binned by `bin_width`, so every
    statistic is a box sum over bins (the median is interpolated inside its bin). With `turned` (the
    window turned to other yaws), the share is the smallest over all of them against the same plane."""
    shape = depth.shape
    valid = np.isfinite(depth) & (np.abs(depth) <= band)
    d = np.where(valid, depth, 0.0).astype(np.float32)
    edges = np.arange(-band, band + bin_width, bin_width)
    bins = np.clip(np.floor((d + band) / bin_width).astype(np.int64), 0, len(edges) - 2)
    area = float(kernel.sum())
    half = 0.5 * _box_sum(valid, kernel)
    below = np.zeros(shape, np.float32)
    median = np.full(shape, np.nan, np.float32)
    counts = {}  # bin -> window counts, kept for the second pass
    for b in np.unique(bins[valid]):
        mine = valid & (bins == b)
        counts[b] = (mine, _box_sum(mine, kernel))
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
        s1, s2 = _box_sum(dm, kernel), _box_sum(dm * dm, kernel)
        count += np.where(near, n, 0.0)
        squares += np.where(near, s2 - 2.0 * m * s1 + m * m * n, 0.0)
        for other, other_count in zip(turned, turned_counts):
            other_count += np.where(near, _box_sum(mine, other), 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        rms = np.where(count > 0.5, np.sqrt(np.maximum(squares, 0.0) / np.maximum(count, 1.0)), np.inf)
    share = count / area
    for other, other_count in zip(turned, turned_counts):
        share = np.minimum(share, other_count / float(other.sum()))
    return LocalSupport(m, share.astype(np.float32), rms.astype(np.float32))


def _box_sum(values: np.ndarray, kernel: np.ndarray) -> np.ndarray:
    """Sum of `values` under the kernel centred on every cell (zero outside the raster)."""
    import cv2

    v = values.astype(np.float32)
    if kernel.all():  # a rectangle: OpenCV's running box sum
        return cv2.boxFilter(v, -1, kernel.shape[::-1], normalize=False, borderType=cv2.BORDER_CONSTANT)
    return cv2.filter2D(v, -1, kernel.astype(np.float32), borderType=cv2.BORDER_CONSTANT)
