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
from functools import lru_cache

import numpy as np

from perch_common.raycast import RayScene
from perch_filtering.raster import SurfaceRaster, turned_kernel


def first_surface_depth(scene: RayScene, raster: SurfaceRaster, cells: np.ndarray, probe: float) -> np.ndarray:
    """Signed depth (m, + towards free space) of the first scanned surface under each cell in `cells`:
    a ray cast along the inverted normal from `probe` in front of the plane; NaN where it finds nothing
    within `probe` of the plane on either side."""
    depth = np.full(raster.shape, np.nan, np.float32)
    if not cells.any():
        return depth
    normal = raster.frame.normal
    origins = _ray_origins(raster, cells, probe)
    directions = np.empty_like(origins)
    directions[:] = -normal
    hits = scene.cast(origins, directions)
    ok = hits.hit & (hits.distance <= 2.0 * probe)
    depth[cells] = np.where(ok, probe - hits.distance, np.nan)
    return depth


ORIGIN_CHUNK = 1 << 16  # cells whose float64 temporaries stay in cache


def _ray_origins(raster: SurfaceRaster, cells: np.ndarray, probe: float) -> np.ndarray:
    """float32 (N,3) points `probe` in front of the cells' centres (row-major): raster.cell_world(cells)
    + probe * normal with the same float64 operations, taken in chunks and rounded to float32 (what the
    ray caster takes)."""
    frame = raster.frame
    rows, cols = np.nonzero(cells)
    u, v = raster.u0 + cols * raster.cell, raster.v0 + rows * raster.cell
    lift, step = np.asarray(0.0)[..., None] * frame.normal, probe * frame.normal  # to_world's height, the probe
    out = np.empty((len(rows), 3), np.float32)
    for start in range(0, len(rows), ORIGIN_CHUNK):
        part = slice(start, start + ORIGIN_CHUNK)
        world = frame.origin + u[part, None] * frame.axis_u + v[part, None] * frame.axis_v + lift
        out[part] = world + step
    return out


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
                         bin_width: float, turned: list[np.ndarray] = (), centres: np.ndarray | None = None,
                         min_share: float = -np.inf, max_rms: float = np.inf) -> LocalSupport:
    """Support of the window centred on each cell of `centres` (every cell without it) against its
    own perch plane.

    The perch plane lies at the median of the window's first-surface depths within `band` of the
    fitted plane; the share counts the window's cells within `tolerance` of it (holes count as
    unsupported) and the RMS is their distance to it. Depths are binned by `bin_width`, so every
    statistic is a window sum over bins (the median is interpolated inside its bin). With `turned` (the
    window turned to other yaws), the share is the smallest over all of them against the same plane,
    taken where the upright window passes (share >= `min_share`, RMS <= `max_rms`); where it fails, the
    window fails in any yaw and the share is the upright one's. Off `centres` the offset and share are
    0 and the RMS infinite.

    The sums are taken only where a centre's window can hold a bin's cells and read at the centres;
    window counts are exact integers, so the median, share and RMS are those of the same sums taken
    over the whole raster."""
    shape = depth.shape
    offset, share = np.zeros(shape, np.float32), np.zeros(shape, np.float32)
    rms = np.full(shape, np.inf, np.float32)
    at = _Centres(np.ones(shape, bool) if centres is None else centres)
    if at.count == 0:
        return LocalSupport(offset, share, rms)
    valid = np.isfinite(depth) & (np.abs(depth) <= band)
    d = np.where(valid, depth, np.float32(0.0)).astype(np.float32, copy=False)
    edges = np.arange(-band, band + bin_width, bin_width)
    # One byte per cell (a few tens of bins); cells without a depth in the band get NO_BIN.
    bins = np.clip(np.floor((d + band) / bin_width), 0, len(edges) - 2).astype(np.uint8)
    bins[~valid] = NO_BIN
    present = np.flatnonzero(np.bincount(bins.ravel(), minlength=NO_BIN + 1)[:NO_BIN])
    area = float(kernel.sum())
    spans = [_bin_span(bins == b, kernel.shape) for b in present]
    # n[i]: the cells of bin present[i] under each centre's window.
    n = np.zeros((len(present), at.count), np.float32)
    for i, (b, span) in enumerate(zip(present, spans)):
        n[i] = at.window_sums(bins[span] == b, span, kernel)
    # The median lies in the first bin whose running count reaches half the window's valid cells.
    running = np.cumsum(n, axis=0, dtype=np.float32)
    half = 0.5 * running[-1] if len(present) else np.zeros(at.count, np.float32)
    first = (running < half).sum(axis=0)
    pick = first * at.count + np.arange(at.count)
    crossed_count = np.take(n, pick) if len(present) else half
    below = np.take(running, pick) - crossed_count if len(present) else half
    position = np.clip((half - below) / np.maximum(crossed_count, 1e-6), 0.0, 1.0)
    crossing_edge = edges[present[first]] if len(present) else np.zeros(at.count)
    median = np.where(half > 0, (crossing_edge + position * bin_width).astype(np.float32), np.float32(np.nan))
    m = np.nan_to_num(median, nan=0.0)
    # Cells within tolerance of the plane: per centre the run of bins present[lo..hi] (the distance to m
    # is unimodal); lo > hi where none is.
    limits = np.array([_near_limits(edges[b] + 0.5 * bin_width, tolerance) for b in present], np.float32)
    lo = np.searchsorted(limits[:, 1], m, "left") if len(present) else np.zeros(at.count, np.int64)
    hi = np.searchsorted(limits[:, 0], m, "right") - 1 if len(present) else lo - 1
    # Integer counts: the running sums' difference is the bins' sum.
    ahead = np.concatenate([np.zeros((1, at.count), np.float32), running]) if len(present) else None
    count = (np.take(ahead, (hi + 1) * at.count + np.arange(at.count))
             - np.take(ahead, lo * at.count + np.arange(at.count))) if len(present) else half
    count = np.where(hi >= lo, count, np.float32(0.0))
    squares = np.zeros(at.count, np.float32)
    for i, (b, span) in enumerate(zip(present, spans)):
        # Only the centres whose window holds cells of the bin add to the squares (in bin order).
        adds = np.flatnonzero(n[i])
        adds = adds[(lo[adds] <= i) & (hi[adds] >= i)]
        if len(adds) == 0:
            continue
        dm = np.where(bins[span] == b, d[span], np.float32(0.0))
        s1, s2 = at.window_sums(dm, span, kernel, adds), at.window_sums(dm * dm, span, kernel, adds)
        mm = m[adds]
        squares[adds] += s2 - 2.0 * mm * s1 + mm * mm * n[i, adds]
    with np.errstate(divide="ignore", invalid="ignore"):
        window_rms = np.where(count > 0.5, np.sqrt(np.maximum(squares, 0.0) / np.maximum(count, 1.0)), np.inf)
    window_share = count / area
    judged = (window_share >= min_share) & (window_rms <= max_rms) & (hi >= lo)
    if len(turned) and judged.any():
        runs = np.where(hi >= lo, present[np.minimum(lo, len(present) - 1)] * (NO_BIN + 1) + present[hi], -1)
        window_share = np.minimum(window_share, _turned_share(bins, turned, at, judged, runs))
    offset[at.rows, at.cols], share[at.rows, at.cols], rms[at.rows, at.cols] = m, window_share, window_rms
    return LocalSupport(offset, share, rms)


NO_BIN = 255  # bin of the cells without a depth within the band


def turned_kernels(kernel: np.ndarray, yaws: tuple[float, ...]) -> list[np.ndarray]:
    """`kernel` turned to each of `yaws` (radians; raster.turned_kernel), made once per kernel and yaws."""
    return list(_turned_kernels(kernel.tobytes(), kernel.shape, kernel.dtype.str, yaws))


@lru_cache(maxsize=8)
def _turned_kernels(data: bytes, shape: tuple[int, int], dtype: str, yaws: tuple[float, ...]) -> tuple[np.ndarray, ...]:
    kernel = np.frombuffer(data, dtype).reshape(shape)
    out = tuple(turned_kernel(kernel, yaw) for yaw in yaws)
    for k in out:
        k.flags.writeable = False  # shared by every call
    return out


class _Centres:
    """The window centres of a raster (row-major) and reads of window sums at them."""

    def __init__(self, mask: np.ndarray):
        self.shape = mask.shape
        self.rows, self.cols = np.nonzero(mask)
        self.count = len(self.rows)
        self.flat = self.rows * mask.shape[1] + self.cols

    def inside(self, span: tuple[slice, slice]) -> tuple[np.ndarray | slice, np.ndarray, np.ndarray]:
        """The centres in `span` (an index or a slice into the centres) and their (row, col) in it."""
        r0, r1 = span[0].indices(self.shape[0])[:2]
        c0, c1 = span[1].indices(self.shape[1])[:2]
        which = slice(*np.searchsorted(self.rows, [r0, r1]))  # rows are sorted
        if c0 > 0 or c1 < self.shape[1]:
            cols = self.cols[which]
            which = np.flatnonzero((cols >= c0) & (cols < c1)) + which.start
        return which, self.rows[which] - r0, self.cols[which] - c0

    def window_sums(self, values: np.ndarray, span: tuple[slice, slice], kernel: np.ndarray,
                    subset: np.ndarray | None = None) -> np.ndarray:
        """Per centre (of `subset`, all without it), the sum under the kernel of a raster that holds
        `values` in `span` and zero elsewhere."""
        sums = _box_sum(values, kernel)
        if subset is not None:  # centres whose windows hold cells of `values`: all inside the span
            r0, c0 = span[0].indices(self.shape[0])[0], span[1].indices(self.shape[1])[0]
            return np.take(sums.ravel(), (self.rows[subset] - r0) * sums.shape[1] + self.cols[subset] - c0)
        out = np.zeros(self.count, np.float32)
        if sums.shape == self.shape:
            return np.take(sums.ravel(), self.flat, out=out)
        which, rows, cols = self.inside(span)
        out[which] = np.take(sums.ravel(), rows * sums.shape[1] + cols)
        return out


def _bin_span(mine: np.ndarray, kernel_shape: tuple[int, int]) -> tuple[slice, slice]:
    """The part of the raster holding the cells of `mine` grown by the kernel's half sizes: windows
    centred outside it hold none of them."""
    r = np.flatnonzero(mine.any(axis=1))
    c = np.flatnonzero(mine.any(axis=0))
    hv, hu = kernel_shape[0] // 2, kernel_shape[1] // 2
    return slice(max(r[0] - hv, 0), r[-1] + hv + 1), slice(max(c[0] - hu, 0), c[-1] + hu + 1)


def _turned_share(bins: np.ndarray, turned: list[np.ndarray], at: _Centres, judged: np.ndarray,
                  runs: np.ndarray) -> np.ndarray:
    """Per centre, the smallest share over the turned windows of the cells whose bin lies in its run
    (lo * (NO_BIN + 1) + hi; 1 where not `judged`). Centres sharing a bin run are taken together; where every turned window
    lies on such cells (one erosion by their union), each holds its whole area."""
    import cv2

    reach = max(max(k.shape) for k in turned) // 2
    union = np.zeros((2 * reach + 1,) * 2, np.uint8)
    for k in turned:
        pr, pc = reach - k.shape[0] // 2, reach - k.shape[1] // 2
        union[pr:pr + k.shape[0], pc:pc + k.shape[1]] |= k
    out = np.ones(at.count, np.float32)
    for run in np.unique(runs[judged]):
        mine = np.flatnonzero(judged & (runs == run))
        span = _grown_span(at.rows[mine], at.cols[mine], reach)
        good = cv2.inRange(bins[span], int(run // (NO_BIN + 1)), int(run % (NO_BIN + 1)))  # 255 on the run's cells
        r, c = at.rows[mine] - span[0].start, at.cols[mine] - span[1].start
        eroded = cv2.erode(good, union, borderType=cv2.BORDER_CONSTANT, borderValue=0)
        partial = np.flatnonzero(eroded[r, c] == 0)
        if len(partial) == 0:
            continue
        mine, r, c = mine[partial], r[partial], c[partial]
        sub = _grown_span(r, c, reach)
        r, c = r - sub[0].start, c - sub[1].start
        good = (good[sub] > 0).astype(np.float32)
        worst = np.full(len(mine), np.inf, np.float32)
        for k in turned:
            # Counts are integers: rounding removes the DFT convolution's float noise.
            counts = np.rint(cv2.filter2D(good, -1, k.astype(np.float32), borderType=cv2.BORDER_CONSTANT)[r, c])
            worst = np.minimum(worst, counts / float(k.sum()))
        out[mine] = worst
    return out


def _near_limits(centre: float, tolerance: float) -> tuple[np.float32, np.float32]:
    """The smallest and largest float32 m with abs(centre - m) <= tolerance in float64 (the bin at
    `centre` is near a plane at m exactly between them: the rounded difference is monotone in m)."""
    def near_low(m):  # the lower limit's side of the test
        return centre - np.float64(m) <= tolerance

    def near_high(m):
        return centre - np.float64(m) >= -tolerance

    low, high = np.float32(centre - tolerance), np.float32(centre + tolerance)
    while not near_low(low):
        low = np.nextafter(low, np.float32(np.inf))
    while near_low(np.nextafter(low, np.float32(-np.inf))):
        low = np.nextafter(low, np.float32(-np.inf))
    while not near_high(high):
        high = np.nextafter(high, np.float32(-np.inf))
    while near_high(np.nextafter(high, np.float32(np.inf))):
        high = np.nextafter(high, np.float32(np.inf))
    return low, high


def _grown_span(rows: np.ndarray, cols: np.ndarray, reach: int) -> tuple[slice, slice]:
    """The bounding box of the cells grown by `reach` (clipped at 0; slicing clips the far ends)."""
    return (slice(max(int(rows.min()) - reach, 0), int(rows.max()) + reach + 1),
            slice(max(int(cols.min()) - reach, 0), int(cols.max()) + reach + 1))


def _box_sum(values: np.ndarray, kernel: np.ndarray) -> np.ndarray:
    """Sum of `values` under the kernel centred on every cell (zero outside the raster), float32; a
    boolean raster's sums are its exact counts."""
    import cv2

    v = values.view(np.uint8) if values.dtype == bool else values.astype(np.float32, copy=False)
    if kernel.all():  # a rectangle: OpenCV's running box sum
        return cv2.boxFilter(v, cv2.CV_32F, kernel.shape[::-1], normalize=False, borderType=cv2.BORDER_CONSTANT)
    sums = cv2.filter2D(v, cv2.CV_32F, kernel.astype(np.float32), borderType=cv2.BORDER_CONSTANT)
    return np.rint(sums, out=sums) if values.dtype == bool else sums  # counts: no DFT float noise
