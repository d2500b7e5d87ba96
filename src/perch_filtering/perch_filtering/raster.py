"""One raster per surface in its plane frame: cell centres, polygon fill, window erosion."""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from perch_common.types import PlaneFrame

SUBPIXEL_BITS = 8
WINDOW_SLACK = 0.4  # cells added to the window half-sizes before rounding down (0.5 m at 50 px/m: 25 cells)


@dataclass
class SurfaceRaster:
    """Cell (r, c) has its centre at plane coordinates (u0 + c * cell, v0 + r * cell)."""

    frame: PlaneFrame
    cell: float
    u0: float
    v0: float
    shape: tuple[int, int]
    inside: np.ndarray  # bool (rows, cols): cell centre inside the surface boundary

    def cell_uv(self, mask: np.ndarray | None = None) -> np.ndarray:
        """(N,2) plane coordinates of the cells in `mask` (all cells without one), row-major."""
        rows, cols = np.nonzero(mask) if mask is not None else np.indices(self.shape).reshape(2, -1)
        return np.column_stack([self.u0 + cols * self.cell, self.v0 + rows * self.cell])

    def cell_world(self, mask: np.ndarray | None = None) -> np.ndarray:
        """(M,3) world positions of the cells (all, or those in `mask`)."""
        return self.frame.to_world(self.cell_uv(mask))

    def to_pixels(self, uv: np.ndarray) -> np.ndarray:
        """(N,2) plane coordinates to fractional (col, row)."""
        return np.column_stack([(uv[:, 0] - self.u0) / self.cell, (uv[:, 1] - self.v0) / self.cell])

    @property
    def cell_area(self) -> float:
        """Area of one raster cell (m^2)."""
        return self.cell * self.cell


def rasterise(frame: PlaneFrame, boundary: list, cell: float, pad: int, max_cells: int,
              what: str = "surface") -> SurfaceRaster:
    """Cells whose centres lie inside the polygons (with holes), padded by `pad` empty cells."""
    import cv2

    rings = [np.asarray(r, np.float64).reshape(-1, 2) for poly in boundary for r in poly]
    if not rings or not any(len(r) >= 3 for r in rings):
        raise ValueError(f"{what}: boundary has no polygon with 3 or more points")
    allpts = np.concatenate(rings)
    if not np.isfinite(allpts).all():
        raise ValueError(f"{what}: boundary has NaN or infinite coordinates")
    lo, hi = allpts.min(axis=0), allpts.max(axis=0)
    cols, rows = (np.ceil((hi - lo) / cell).astype(np.int64) + 1 + 2 * pad)
    if rows * cols > max_cells:
        raise ValueError(f"{what}: raster of {rows} x {cols} cells exceeds max_cells_per_surface={max_cells} "
                         f"(extent {hi - lo} m at {1 / cell:g} px/m)")
    u0, v0 = lo[0] - pad * cell, lo[1] - pad * cell
    raster = SurfaceRaster(frame, cell, float(u0), float(v0), (int(rows), int(cols)), np.zeros(0, bool))
    img = np.zeros((rows, cols), np.uint8)
    # Outer rings first, large before small, then holes: islands inside holes get filled again.
    order = sorted(range(len(boundary)), key=lambda i: -_ring_area(boundary[i][0]) if boundary[i] else 0)
    scale = float(1 << SUBPIXEL_BITS)
    for i in order:
        poly = [np.asarray(r, np.float64).reshape(-1, 2) for r in boundary[i] if len(r) >= 3]
        if not poly:
            continue
        pix = [np.round(raster.to_pixels(r) * scale).astype(np.int32) for r in poly]
        cv2.fillPoly(img, [pix[0]], 1, lineType=cv2.LINE_8, shift=SUBPIXEL_BITS)
        if len(pix) > 1:
            cv2.fillPoly(img, pix[1:], 0, lineType=cv2.LINE_8, shift=SUBPIXEL_BITS)
    raster.inside = _exact_edges(img.astype(bool), raster, boundary)
    return raster


def _ring_area(ring) -> float:
    r = np.asarray(ring, np.float64).reshape(-1, 2)
    if len(r) < 3:
        return 0.0
    x, y = r[:, 0], r[:, 1]
    return 0.5 * abs(float(x @ np.roll(y, -1) - y @ np.roll(x, -1)))


def _exact_edges(filled: np.ndarray, raster: SurfaceRaster, boundary: list) -> np.ndarray:
    """OpenCV fills cells the outline merely touches; decide cells near the outline exactly."""
    import cv2
    import shapely

    from perch_common.polygons import to_shapely

    kernel = np.ones((3, 3), np.uint8)
    f8 = filled.astype(np.uint8)
    band = cv2.dilate(f8, kernel).astype(bool) & ~cv2.erode(f8, kernel, borderValue=0).astype(bool)
    geom = to_shapely(boundary)
    shapely.prepare(geom)
    uv = raster.cell_uv(band)
    out = filled.copy()
    out[band] = shapely.contains_xy(geom, uv[:, 0], uv[:, 1])
    return out


def window_kernel(width: float, height: float, cell: float, ellipse: bool) -> np.ndarray:
    """Structuring element of the cells whose squares make up the window (u: width, v: height).

    A 0.5 m window at 0.02 m cells is 25 cells: centres within +-0.24 m, each cell standing for its
    own +-0.01 m square."""
    half_u = int(np.floor((width / 2 + cell * WINDOW_SLACK) / cell + 1e-9))
    half_v = int(np.floor((height / 2 + cell * WINDOW_SLACK) / cell + 1e-9))
    if not ellipse:
        return np.ones((2 * half_v + 1, 2 * half_u + 1), np.uint8)
    r, c = np.mgrid[-half_v:half_v + 1, -half_u:half_u + 1]
    a, b = max(half_u, 0.5), max(half_v, 0.5)
    return ((c / a) ** 2 + (r / b) ** 2 <= 1.0 + 1e-9).astype(np.uint8)


def disc_kernel(radius_cells: float) -> np.ndarray:
    """Structuring element of the cell offsets within `radius_cells` of the centre (a disc)."""
    half = int(np.floor(radius_cells + 1e-9))
    r, c = np.mgrid[-half:half + 1, -half:half + 1]
    return (r * r + c * c <= radius_cells * radius_cells + 1e-9).astype(np.uint8)


def turned_kernel(kernel: np.ndarray, yaw: float) -> np.ndarray:
    """The cell offsets whose centres, turned back by `yaw`, fall on a cell of `kernel` (a window
    kernel turned about its centre; its size grows to hold the turned corners)."""
    rows, cols = kernel.shape
    half_v, half_u = rows // 2, cols // 2
    reach = int(np.ceil(np.hypot(half_u, half_v)))
    r, c = np.mgrid[-reach:reach + 1, -reach:reach + 1]
    u = np.rint(np.cos(yaw) * c + np.sin(yaw) * r).astype(np.int64)
    v = np.rint(-np.sin(yaw) * c + np.cos(yaw) * r).astype(np.int64)
    inside = (np.abs(u) <= half_u) & (np.abs(v) <= half_v)
    out = np.zeros(r.shape, np.uint8)
    out[inside] = kernel[v[inside] + half_v, u[inside] + half_u]
    return out


def any_yaw_radius(half_u: float, half_v: float) -> float:
    """Radius of the disc that a half_u x half_v rectangle sweeps when turned about its centre: its
    half diagonal. A ceiling's gravity fixes no in-plane axis, so a drone may settle there in any yaw
    (and other checks judge the window in their own axes): the window must be safe in every one."""
    return float(np.hypot(half_u, half_v))


def erode_window(alive: np.ndarray, kernel: np.ndarray) -> np.ndarray:
    """Cells where the whole window fits on alive cells; outside the raster counts as not alive."""
    import cv2

    out = erode(alive.astype(np.uint8), kernel, cv2.BORDER_CONSTANT, 0)
    return out.astype(bool)


RUN_CELLS = 64  # kernel cells per level from which erode takes a disc's minima level by level


def erode(image: np.ndarray, kernel: np.ndarray, border: int, border_value: float | None = None) -> np.ndarray:
    """cv2.erode(image, kernel, borderType=border, borderValue=border_value): the same minima.

    A disc (every row of the kernel a run centred on its middle column, no wider than the rows nearer
    the middle) is the union of the rectangles of its distinct row widths, so its minimum is taken from
    1-D minima (`centred_runs`): O(radius) passes over the image instead of OpenCV's one per kernel
    cell (the ceilings' 1 m approach disc: 2,000 cells, 15 levels, 2.5x faster). Minima compose
    exactly, and a replicated or constant border composes like the whole kernel's."""
    import cv2

    extra = {} if border_value is None else {"borderValue": border_value}
    # A rectangle is OpenCV's own separable case; a disc's levels are worked out once per kernel.
    levels = None if kernel.all() else _centred_runs(kernel.tobytes(), kernel.shape, kernel.dtype.str)
    # Three passes a level against one vectorised pass per kernel cell: measured even at ~50 cells a level.
    if levels is None or np.count_nonzero(kernel) < RUN_CELLS * len(levels) or image.size == 0:
        return cv2.erode(image, kernel, borderType=border, **extra)

    def along(values, reach, axis):  # the minimum over +-reach cells along one axis
        if reach == 0:
            return values
        shape = (1, 2 * reach + 1) if axis == 1 else (2 * reach + 1, 1)
        return cv2.erode(values, np.ones(shape, np.uint8), borderType=border, **extra)

    # Narrowest (tallest) level first: C = min(H_w, V_(h_prev - h)(C)); the answer is V_(h_widest)(C).
    width, height = levels[0]
    rows_min = along(image, width, 1)
    combined = rows_min
    for w, h in levels[1:]:
        rows_min = along(rows_min, w - width, 1)
        combined = np.minimum(rows_min, along(combined, height - h, 0))
        width, height = w, h
    return along(combined, height, 0)


@lru_cache(maxsize=16)
def _centred_runs(data: bytes, shape: tuple[int, int], dtype: str) -> tuple[tuple[int, int], ...] | None:
    levels = centred_runs(np.frombuffer(data, dtype).reshape(shape))
    return None if levels is None else tuple(levels)


def centred_runs(kernel: np.ndarray) -> list[tuple[int, int]] | None:
    """The kernel as a union of centred rectangles: (half width, half height) per distinct row width,
    narrowest first; None unless every row is a run centred on the middle column, mirrored about the
    middle row and no wider than the rows nearer it (a disc, an ellipse, a rectangle)."""
    rows, cols = kernel.shape
    if rows % 2 == 0 or cols % 2 == 0:
        return None
    half_v, half_u = rows // 2, cols // 2
    on = kernel != 0
    widths = on.sum(axis=1)
    if widths[half_v] == 0 or not np.array_equal(widths, widths[::-1]):
        return None
    half = (widths - 1) // 2
    expected = np.abs(np.arange(cols) - half_u)[None, :] <= half[:, None]
    if np.any(widths % 2 == 0) or not np.array_equal(on, expected):
        return None
    if np.any(np.diff(half[half_v:]) > 0):
        return None
    levels = []
    for w in np.unique(half[half_v:]):
        levels.append((int(w), int(np.flatnonzero(half[half_v:] >= w).max())))
    return levels
