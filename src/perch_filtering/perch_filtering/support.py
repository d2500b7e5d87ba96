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


def first_surface_depth(scene: RayScene, raster: SurfaceRaster, cells: np.ndarray, probe: float,
                        box: tuple[slice, slice] | None = None) -> np.ndarray:
    """Signed depth (m, + towards free space) of the first scanned surface under each cell in `cells`:
    a ray cast along the inverted normal from `probe` in front of the plane; NaN where it finds nothing
    within `probe` of the plane on either side. `cells` (and the answer) cover the raster, or its part
    `box` when given."""
    depth = np.full(cells.shape, np.nan, np.float32)
    if not cells.any():
        return depth
    normal = raster.frame.normal
    rows, cols = np.nonzero(cells)
    origins = _ray_origins(raster, rows, cols, probe, box)
    directions = np.empty_like(origins)
    directions[:] = -normal
    distance = scene.first_hit_distance(origins, directions)
    rows *= cells.shape[1]
    rows += cols  # flat indices: a boolean mask's assignment costs 8x a flat one
    depth.reshape(-1)[rows] = np.where(distance <= 2.0 * probe, probe - distance, np.nan)
    return depth


ORIGIN_CHUNK = 1 << 14  # cells whose float64 temporaries stay in cache


def _ray_origins(raster: SurfaceRaster, rows: np.ndarray, cols: np.ndarray, probe: float,
                 box: tuple[slice, slice] | None = None) -> np.ndarray:
    """float32 (N,3) points `probe` in front of the centres of the cells (rows, cols) (of `box` when
    given): raster.cell_world + probe * normal with the same float64 operations (origin + u * axis_u
    per column, v * axis_v per row), taken in chunks and rounded to float32 (what the ray caster takes)."""
    frame = raster.frame
    if box is not None:
        rows, cols = rows + box[0].start, cols + box[1].start
    by_col = frame.origin + (raster.u0 + np.arange(raster.shape[1]) * raster.cell)[:, None] * frame.axis_u
    by_row = (raster.v0 + np.arange(raster.shape[0]) * raster.cell)[:, None] * frame.axis_v
    lift, step = np.asarray(0.0)[..., None] * frame.normal, probe * frame.normal  # to_world's height, the probe
    out = np.empty((len(rows), 3), np.float32)
    for start in range(0, len(rows), ORIGIN_CHUNK):
        part = slice(start, start + ORIGIN_CHUNK)
        world = by_col[cols[part]] + by_row[rows[part]]
        world += lift
        world += step
        out[part] = world
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


NO_BIN = 255  # bin of the cells without a depth within the band


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

    Window sums are read at the centres only. Counts are exact integers, so the median and share are
    those of per-bin sums over the whole raster; the cells near a centre's plane are a run of bins, and
    the centres sharing a run are summed together."""
    shape = depth.shape
    offset, share = np.zeros(shape, np.float32), np.zeros(shape, np.float32)
    rms = np.full(shape, np.inf, np.float32)
    at = _Centres(np.ones(shape, bool) if centres is None else centres)
    valid = np.isfinite(depth) & (np.abs(depth) <= band)
    d = np.where(valid, depth, np.float32(0.0)).astype(np.float32, copy=False)
    edges = np.arange(-band, band + bin_width, bin_width)
    # One byte per cell (a few tens of bins); cells without a depth in the band get NO_BIN.
    bins = np.clip(np.floor((d + band) / bin_width), 0, len(edges) - 2).astype(np.uint8)
    bins[~valid] = NO_BIN
    present = np.flatnonzero(np.bincount(bins.ravel(), minlength=NO_BIN + 1)[:NO_BIN])
    if at.count == 0 or len(present) == 0:  # nothing judged, or no depth in the band: no support
        return LocalSupport(offset, share, rms)
    # running[i]: the cells of bins present[..i] under each centre's window.
    running = np.empty((len(present), at.count), np.float32)
    for i, b in enumerate(present):
        at.window_sums(bins == b, kernel, out=running[i])
    np.cumsum(running, axis=0, out=running)
    m = _median_in_bins(running, edges[present], bin_width)
    lo, hi = _near_runs(m, edges[present] + 0.5 * bin_width, tolerance)
    runs = _Runs(lo, hi, len(present))
    # The cells near the plane: an exact count (running sums' difference), and their squared distances.
    count = np.take(running, hi * at.count + at.index, mode="clip")
    count -= np.take(running, (lo - 1) * at.count + at.index, mode="clip") * (lo > 0)
    count[runs.none] = 0.0
    squares = np.zeros(at.count)
    hv, hu = kernel.shape[0] // 2, kernel.shape[1] // 2
    for first, last, mine in runs:
        part = _grown_span(at.rows[mine], at.cols[mine], hv, hu)
        near = np.where(_in_bins(bins[part], present[first], present[last]), d[part], np.float32(0.0))
        near = near.astype(np.float64)
        flat = at.flat_in(mine, part, near.shape[1])
        s1, s2 = np.take(_box_sum(near, kernel).ravel(), flat), np.take(_box_sum(near * near, kernel).ravel(), flat)
        mm = m[mine].astype(np.float64)
        squares[mine] = s2 - 2.0 * mm * s1 + mm * mm * count[mine]
    with np.errstate(divide="ignore", invalid="ignore"):
        window_rms = np.where(count > 0.5, np.sqrt(np.maximum(squares, 0.0) / np.maximum(count, 1.0)), np.inf)
    window_rms = window_rms.astype(np.float32)  # judged as the caller judges the map
    window_share = count / float(kernel.sum())
    if len(turned):
        judged = (window_share >= min_share) & (window_rms <= max_rms)
        window_share = np.minimum(window_share, _turned_share(bins, turned, at, runs, judged, present))
    offset.reshape(-1)[at.flat], share.reshape(-1)[at.flat], rms.reshape(-1)[at.flat] = m, window_share, window_rms
    return LocalSupport(offset, share, rms)


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
        self.rows, self.cols = np.nonzero(mask)
        self.count = len(self.rows)
        self.index = np.arange(self.count)
        self.flat = self.rows * mask.shape[1] + self.cols

    def flat_in(self, which: np.ndarray, part: tuple[slice, slice], width: int) -> np.ndarray:
        """Flat indices of centres `which` in the part of the raster `part` (`width` columns wide)."""
        return (self.rows[which] - part[0].start) * width + self.cols[which] - part[1].start

    def window_sums(self, values: np.ndarray, kernel: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """Per centre, the sum of `values` under the kernel."""
        return np.take(_box_sum(values, kernel).ravel(), self.flat, out=out)


def _median_in_bins(running: np.ndarray, lower_edges: np.ndarray, bin_width: float) -> np.ndarray:
    """Per centre (column), the median of its window's depths from its running bin counts: in the first
    bin whose running count reaches half the window's depths, interpolated by the count there
    (float32 throughout, as the counts); 0 where the window holds none."""
    count = running.shape[1]
    half = 0.5 * running[-1]
    first = (running < half).sum(axis=0)
    at_first = first * count + np.arange(count)
    below = np.take(running, at_first - count, mode="clip") * (first > 0)
    crossed = np.take(running, at_first) - below
    position = np.clip((half - below) / np.maximum(crossed, 1e-6), 0.0, 1.0)
    median = (lower_edges[first] + position * bin_width).astype(np.float32)
    median[half <= 0] = 0.0
    return median


def _near_runs(m: np.ndarray, centres: np.ndarray, tolerance: float) -> tuple[np.ndarray, np.ndarray]:
    """Per plane offset m (float32), the first and last of the bins (centred at `centres`, ascending)
    with abs(centre - m) <= tolerance (in float64); first > last where none is. The test is monotone in
    m on either side, so each bin is near the m between two float32 limits."""
    limits = np.array([_near_limits(c, tolerance) for c in centres], np.float32)
    return np.searchsorted(limits[:, 1], m, "left"), np.searchsorted(limits[:, 0], m, "right") - 1


def _near_limits(centre: float, tolerance: float) -> tuple[np.float32, np.float32]:
    """The smallest and largest float32 m with abs(centre - m) <= tolerance in float64."""
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


class _Runs:
    """The centres grouped by their run of near bins [lo, hi] (indices into the present bins)."""

    def __init__(self, lo: np.ndarray, hi: np.ndarray, bins: int):
        self.none = hi < lo
        code = np.where(self.none, -1, lo * bins + hi).astype(np.int16 if bins * bins < 1 << 15 else np.int32)
        self.order = np.argsort(code, kind="stable")
        codes, starts = np.unique(code[self.order], return_index=True)
        ends = np.append(starts[1:], len(code))
        self.groups = [(int(c) // bins, int(c) % bins, self.order[s:e])
                       for c, s, e in zip(codes, starts, ends) if c >= 0]

    def __iter__(self):
        """(lo, hi, centres) of each run, centres ascending."""
        return iter(self.groups)


def _in_bins(bins: np.ndarray, low: int, high: int) -> np.ndarray:
    """Whether each cell's bin lies in [low, high] (a byte mask, 255 where it does)."""
    import cv2

    return cv2.inRange(bins, int(low), int(high))


def _turned_share(bins: np.ndarray, turned: list[np.ndarray], at: _Centres, runs: _Runs, judged: np.ndarray,
                  present: np.ndarray) -> np.ndarray:
    """Per centre, the smallest share over the turned windows of the cells in its run of near bins (1
    where not `judged`). Where every turned window lies on such cells (an erosion by their union finds
    it), each holds its whole area; elsewhere the run's cells are convolved with each turned window."""
    import cv2

    reach = max(max(k.shape) for k in turned) // 2
    union = np.zeros((2 * reach + 1,) * 2, np.uint8)
    for k in turned:
        pr, pc = reach - k.shape[0] // 2, reach - k.shape[1] // 2
        union[pr:pr + k.shape[0], pc:pc + k.shape[1]] |= k
    out = np.ones(at.count, np.float32)
    for first, last, mine in runs:
        mine = mine[judged[mine]]
        if len(mine) == 0:
            continue
        part = _grown_span(at.rows[mine], at.cols[mine], reach)
        good = _in_bins(bins[part], present[first], present[last])
        eroded = cv2.erode(good, union, borderType=cv2.BORDER_CONSTANT, borderValue=0)
        partial = np.take(eroded.ravel(), at.flat_in(mine, part, good.shape[1])) == 0
        if not partial.any():
            continue
        mine = mine[partial]
        sub = _grown_span(at.rows[mine], at.cols[mine], reach)  # inside `part`
        good = good[sub[0].start - part[0].start:sub[0].stop - part[0].start,
                    sub[1].start - part[1].start:sub[1].stop - part[1].start]
        worst = np.full(len(mine), np.inf, np.float32)
        counts = _WindowCounts(good, reach, at.rows[mine] - sub[0].start, at.cols[mine] - sub[1].start)
        for k in turned:
            worst = np.minimum(worst, counts.of(k) / float(k.sum()))
        out[mine] = worst
    return out


class _WindowCounts:
    """Exact counts of the cells of a mask under windows centred on some of its cells, read from its row
    prefix sums: each window row's runs of cells are two reads per centre. The partial centres are a
    small share of a large ceiling's raster, where a whole-raster convolution per turned window took
    five DFTs of the raster (the same integers, from cv2.filter2D rounded)."""

    CHUNK = 1 << 10  # centres per gather: their (centres, reads) index block stays in L2 (1 << 12: 10 % slower)

    def __init__(self, mask: np.ndarray, reach: int, rows: np.ndarray, cols: np.ndarray):
        """`mask` (nonzero: counted), windows up to `reach` cells from their centres (rows, cols), which
        lie in the mask (outside it counts nothing)."""
        height, width = mask.shape
        self.width = width + 2 * reach + 1  # padded by `reach` on every side and one leading column
        # float32 holds every prefix (a row's count) and every signed sum of them exactly (< 2^24): BLAS sums.
        self.prefix = np.zeros((height + 2 * reach, self.width), np.float32)
        np.cumsum(mask != 0, axis=1, dtype=np.float32, out=self.prefix[reach:reach + height, reach + 1:reach + 1 + width])
        self.prefix[reach:reach + height, reach + 1 + width:] = self.prefix[reach:reach + height, reach + width:reach + width + 1]
        self.prefix = self.prefix.ravel()
        self.base = (rows + reach) * self.width + cols + reach

    def of(self, kernel: np.ndarray) -> np.ndarray:
        """Per centre, the mask's cells under `kernel` (odd sides, centred on the centre), float32."""
        half_v, half_u = kernel.shape[0] // 2, kernel.shape[1] // 2
        on = np.zeros((kernel.shape[0], kernel.shape[1] + 2), np.int8)
        on[:, 1:-1] = kernel != 0
        step = np.diff(on, axis=1)  # +1 where a run starts, -1 one past where it ends
        rows, cols = np.nonzero(step)
        offsets = (rows - half_v) * self.width + cols - half_u  # prefix column = cell column + 1
        signs = -step[rows, cols].astype(np.float32)  # a run adds prefix(end + 1) and subtracts prefix(start)
        out = np.empty(len(self.base), np.float32)
        for start in range(0, len(self.base), self.CHUNK):
            part = slice(start, start + self.CHUNK)
            reads = np.take(self.prefix, self.base[part, None] + offsets[None, :])
            out[part] = reads @ signs
        return out


def _grown_span(rows: np.ndarray, cols: np.ndarray, reach: int, reach_cols: int | None = None) -> tuple[slice, slice]:
    """The bounding box of the cells grown by `reach` (`reach_cols` along rows when given; clipped at 0,
    slicing clips the far ends)."""
    reach_cols = reach if reach_cols is None else reach_cols
    return (slice(max(int(rows.min()) - reach, 0), int(rows.max()) + reach + 1),
            slice(max(int(cols.min()) - reach_cols, 0), int(cols.max()) + reach_cols + 1))


def _box_sum(values: np.ndarray, kernel: np.ndarray) -> np.ndarray:
    """Sum of `values` under the kernel centred on every cell (zero outside the raster): float64 for
    float64 values, else float32; a boolean raster's sums are its exact counts."""
    import cv2

    depth = cv2.CV_64F if values.dtype == np.float64 else cv2.CV_32F
    v = values.view(np.uint8) if values.dtype == bool else values.astype(np.float32, copy=False) \
        if depth == cv2.CV_32F else values
    if kernel.all():  # a rectangle: OpenCV's running box sum
        return cv2.boxFilter(v, depth, kernel.shape[::-1], normalize=False, borderType=cv2.BORDER_CONSTANT)
    sums = cv2.filter2D(v, depth, kernel.astype(np.float32 if depth == cv2.CV_32F else np.float64),
                        borderType=cv2.BORDER_CONSTANT)
    return np.rint(sums, out=sums) if values.dtype == bool else sums  # counts: no DFT float noise
