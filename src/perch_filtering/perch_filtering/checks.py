"""The safety model's geometric measures on one surface raster: free fall and approach clearance.

Both measure the mesh samples in front of the surface, beyond the band that counts as the scanned
surface itself (nearer geometry is judged by support; the surface's own faces get at least
plane_tolerance + max_support_rms, so that its warp is not its own obstacle). Samples are up to `spacing`
apart and are snapped to the nearest cell, so every radius is widened by a share of the spacing
(GAP) and of a cell (SNAP). Tuned on generated scenes against the independent checker in test/: these margins
keep precision >= 0.99 while the full worst-case margins cost ~5 points of recall.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from perch_common.mesh_samples import MeshSamples
from perch_common.types import SurfaceClass
from perch_filtering.raster import SurfaceRaster, any_yaw_radius, disc_kernel, erode
from perch_filtering.sampling import SampleIndex, read_runs, run_positions

SNAP = 0.35  # cells (the worst case, a point half a cell diagonal from its cell centre, is 0.71)
GAP = 0.25  # share of the sample spacing (points of a face lie within ~0.5 spacing of a sample)
DISC_SNAP = 0.71  # cells: a sample snapped to its nearest cell moves by up to half a cell diagonal


@dataclass
class NearbyGeometry:
    """Mesh samples in front of one surface (in no particular order): depth along its normal, plane
    coords, height along up, and the raster cell each is snapped to (col, row; both measures use it)."""

    depth: np.ndarray
    uv: np.ndarray
    height: np.ndarray
    pixels: np.ndarray


def geometry_in_front(samples: MeshSamples, index: SampleIndex, raster: SurfaceRaster, own_faces: np.ndarray,
                      up: np.ndarray, min_depth: float, max_depth: float, margin: float,
                      own_min_depth: float | None = None) -> NearbyGeometry:
    """Samples with min_depth < depth <= max_depth whose plane coordinates lie within `margin` of the
    raster; samples on the surface's own faces only beyond `own_min_depth` (never when None). The samples
    are read from `index` (built from `samples`), which keeps them in bucket order."""
    f = raster.frame
    rows, cols = raster.shape
    u_lo, u_hi = raster.u0 - margin, raster.u0 + (cols - 1) * raster.cell + margin
    v_lo, v_hi = raster.v0 - margin, raster.v0 + (rows - 1) * raster.cell + margin
    corners = [f.to_world(np.array([[u, v]]), np.array([d]))[0]
               for u in (u_lo, u_hi) for v in (v_lo, v_hi) for d in (min_depth, max_depth)]
    start, stop = index.runs_near_box(np.array(corners))
    # Depth first, then the plane coordinates of the samples within the depth range only (the
    # buckets' box holds the surface's own samples and those behind it): the same sums, a third of them.
    # Coordinates are slices of the index's bucket-ordered columns (a few dozen runs: no positions to
    # gather by), and every sum is project's: (p - origin) . axis, term by term in x, y, z order.
    x, y, z = (read_runs(column, start, stop) for column in (index.x, index.y, index.z))
    depth = _dot(x - f.origin[0], y - f.origin[1], z - f.origin[2], f.normal)
    in_range = (depth > min_depth) & (depth <= max_depth)
    x, y, z, depth = x[in_range], y[in_range], z[in_range], depth[in_range]
    ox, oy, oz = x - f.origin[0], y - f.origin[1], z - f.origin[2]
    u, v = _dot(ox, oy, oz, f.axis_u), _dot(ox, oy, oz, f.axis_v)
    del ox, oy, oz
    keep = (u >= u_lo) & (u <= u_hi) & (v >= v_lo) & (v <= v_hi)
    if len(own_faces):
        own = np.zeros(int(own_faces.max()) + 1, bool)
        own[own_faces[own_faces < len(own)]] = True
        # Beyond own_min_depth a sample is kept whoever's it is: only the nearer ones need their face.
        candidate = np.flatnonzero(keep & (depth <= own_min_depth) if own_min_depth is not None else keep)
        face = index.face[run_positions(np.flatnonzero(in_range)[candidate], start, stop)]
        inside = face < len(own)
        mine = candidate[inside][own[face[inside]]]
        keep[mine] = depth[mine] > own_min_depth if own_min_depth is not None else False
    depth, u, v, x, y, z = depth[keep], u[keep], v[keep], x[keep], y[keep], z[keep]
    height = _dot(x, y, z, up)
    pixels = np.empty((len(u), 2), np.int64)
    pixels[:, 0] = np.round((u - raster.u0) / raster.cell)  # raster.to_pixels, rounded
    pixels[:, 1] = np.round((v - raster.v0) / raster.cell)
    return NearbyGeometry(depth, np.column_stack([u, v]), height, pixels)


def _dot(x: np.ndarray, y: np.ndarray, z: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """x a0 + y a1 + z a2 in sampling.project's order of operations (the same float64 values)."""
    out = x * axis[0]
    out += y * axis[1]
    out += z * axis[2]
    return out


def _padded_flat(pixels: np.ndarray, pad_u: int, pad_v: int, shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Flat indices into an image of `shape` (rows, cols) padded by pad_v rows and pad_u columns on every
    side of the (col, row) `pixels`, and which of them land in it."""
    col = pixels[:, 0] + pad_u
    row = pixels[:, 1] + pad_v
    # Negative ones wrap to huge unsigned values: one comparison per axis.
    inside = col.view(np.uint64) < shape[1]
    inside &= row.view(np.uint64) < shape[0]
    row *= shape[1]
    row += col
    return row, inside


def scatter(ufunc: np.ufunc, image: np.ndarray, rows: np.ndarray, cols: np.ndarray, values: np.ndarray) -> None:
    """ufunc.at(image, (rows, cols), values) on the flat image with values in its dtype: numpy's fast
    path (4-7x; a float64 value into a float32 image took the casting loop). Same result: rounding to
    float32 keeps the order, so min / max of the rounded values is the rounded min / max."""
    scatter_flat(ufunc, image, rows * image.shape[1] + cols, values)


def scatter_flat(ufunc: np.ufunc, image: np.ndarray, flat: np.ndarray, values: np.ndarray) -> None:
    """scatter at flat indices into the image."""
    ufunc.at(image.reshape(-1), flat, values.astype(image.dtype, copy=False))


NO_OBSTACLE = -1e9  # height of "no obstacle below" in the wall fall image


def _disc(radius: float, cell: float) -> np.ndarray:
    """Kernel that makes a sample snapped to its nearest cell block every cell centre within `radius`."""
    return disc_kernel(radius / cell + DISC_SNAP)


def _box_cells(half: float, cell: float) -> int:
    """Cells to dilate by so that a sample snapped to its nearest cell blocks every cell centre within
    `half` of it along an axis (snapping moves a sample by at most half a cell)."""
    return int(np.floor(half / cell + 0.5 + 1e-9))


def free_fall(raster: SurfaceRaster, near: NearbyGeometry, up: np.ndarray, floor_height: float,
              lookahead: float, corridor_margin: float, corridor_depth: float, spacing: float,
              surface_class: SurfaceClass = SurfaceClass.WALL, any_yaw: bool = False) -> np.ndarray:
    """Free fall height (m, capped at `lookahead`) below every cell: the recovery-height measure.

    Each cell's corridor is its column grown by `corridor_margin` on either side; the perch window
    filter then asks it of every cell of the window, so a perch's corridor is the window (the drone's
    footprint plus position uncertainty) grown by the margin. Walls (the surface's class, by the
    configured class angle): the corridor runs below the cell in front of the wall, `corridor_depth`
    deep; the fall ends at the highest sample in it. Ceilings (and intermediate surfaces facing
    down): the column below the cell; it ends at the nearest sample. Both also end at the floor.
    Floors (and intermediate surfaces facing up: landing) need no fall: `lookahead` everywhere.
    `any_yaw` (ceilings): the column grows by `corridor_margin` in every direction (a disc), not along
    the raster's axes only.
    """
    import cv2

    f = raster.frame
    cell = raster.cell
    rows, cols = raster.shape
    heights = (f.origin @ up) + (raster.v0 + np.arange(rows) * cell) * float(f.axis_v @ up)
    facing = float(f.normal @ up)
    wall = surface_class == SurfaceClass.WALL
    if not wall and facing > 0:
        return np.full(raster.shape, lookahead, np.float32)
    fall = np.repeat(np.minimum(heights - floor_height, lookahead)[:, None], cols, axis=1).astype(np.float32)
    if len(near.depth) == 0:
        return fall
    half = _box_cells(corridor_margin + spacing * GAP, cell)
    pix = near.pixels
    if not wall:  # ceiling-like: the column below the cell ends at the nearest sample
        kernel = (_disc(corridor_margin + spacing * GAP, cell) if any_yaw
                  else np.ones((2 * half + 1, 2 * half + 1), np.uint8))
        half = kernel.shape[0] // 2
        depth = np.full((rows + 2 * half, cols + 2 * half), lookahead, np.float32)
        flat, usable = _padded_flat(pix, half, half, depth.shape)
        scatter_flat(np.minimum, depth, flat[usable], near.depth[usable] - spacing * GAP)
        column = erode(depth, kernel, cv2.BORDER_REPLICATE)
        return np.minimum(fall, column[half:half + rows, half:half + cols])
    slope = float(f.axis_v @ up) * cell  # height per row (> 0: oriented frames' v axis follows up)
    if slope <= 1e-9:
        return np.zeros(raster.shape, np.float32)
    # A sample at height z is below every cell from height z - margin up; the fall there ends at z + margin.
    margin = spacing * GAP + SNAP * cell
    width = cols + 2 * half
    col = pix[:, 0] + half
    ok = col.view(np.uint64) < width  # negative columns wrap to huge unsigned values
    ok &= near.depth <= corridor_depth + spacing * GAP
    height, col = near.height[ok], col[ok]  # the row of only the samples in the corridor's depth
    start = np.ceil((height - margin - heights[0]) / slope).astype(np.int64)
    below = start < rows
    start, col, height = start[below], col[below], height[below]
    np.clip(start, 0, rows - 1, out=start)
    start *= width
    start += col
    top = np.full((rows, width), NO_OBSTACLE, np.float32)
    scatter_flat(np.maximum, top, start, height + margin)
    top = cv2.dilate(top, np.ones((1, 2 * half + 1), np.uint8), borderType=cv2.BORDER_REPLICATE)
    highest_below = np.maximum.accumulate(top, axis=0)[:, half:half + cols]
    return np.minimum(fall, heights[:, None] - highest_below).astype(np.float32)


def approach_clearance(raster: SurfaceRaster, near: NearbyGeometry, half_u: float, half_v: float,
                       lookahead: float, spacing: float, any_yaw: bool = False) -> np.ndarray:
    """Free depth (m, capped at `lookahead`) of the approach prism centred on every cell.

    The prism is the rectangle +-half_u x +-half_v around the cell (the window grown by the lateral
    margin) swept along the normal; its free depth is the depth of the nearest sample inside it.
    Geometry beside the prism does not count, however close. `any_yaw` (ceilings): the prism is the
    rectangle turned to every yaw about the cell, the disc of its half diagonal.
    """
    import cv2

    cell = raster.cell
    rows, cols = raster.shape
    if any_yaw:
        kernel = _disc(any_yaw_radius(half_u, half_v) + spacing * GAP, cell)
        ku = kv = kernel.shape[0] // 2
    else:
        ku = _box_cells(half_u + spacing * GAP, cell)
        kv = _box_cells(half_v + spacing * GAP, cell)
        kernel = np.ones((2 * kv + 1, 2 * ku + 1), np.uint8)
    depth = np.full((rows + 2 * kv, cols + 2 * ku), lookahead, np.float32)
    if len(near.depth):
        flat, usable = _padded_flat(near.pixels, ku, kv, depth.shape)
        usable &= near.depth < lookahead
        scatter_flat(np.minimum, depth, flat[usable], near.depth[usable] - spacing * GAP)
    prism = erode(depth, kernel, cv2.BORDER_REPLICATE)
    return np.maximum(prism[kv:kv + rows, ku:ku + cols], 0.0)
