"""Filters 2 and 3 on one surface raster: recovery height (fall corridor) and obstacle clearance.

Both test the mesh samples in front of the surface. Samples are up to `spacing` apart and are
snapped to the nearest cell, so every radius is widened by a share of the spacing (GAP) and of a
cell (SNAP). Tuned on generated scenes against the independent checker in test/: these margins
keep precision >= 0.99 while the full worst-case margins cost ~5 points of recall.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from perch_common.types import SurfaceClass
from perch_filtering.raster import SurfaceRaster
from perch_filtering.sampling import MeshSamples, SampleIndex, project

CLEARANCE_BANDS = 10
SNAP = 0.35  # cells (the worst case, a point half a cell diagonal from its cell centre, is 0.71)
GAP = 0.25  # share of the sample spacing (points of a face lie within ~0.5 spacing of a sample)


@dataclass
class NearbyGeometry:
    """Mesh samples in front of one surface: depth along its normal, plane coords, height along up."""

    depth: np.ndarray
    uv: np.ndarray
    height: np.ndarray


def geometry_in_front(samples: MeshSamples, index: SampleIndex, raster: SurfaceRaster, own_faces: np.ndarray,
                      up: np.ndarray, min_depth: float, max_depth: float, margin: float) -> NearbyGeometry:
    """Samples not on the surface's own faces with min_depth < depth <= max_depth, whose plane
    coordinates lie within `margin` of the raster."""
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
    if len(own_faces):
        own = np.zeros(int(own_faces.max()) + 1, bool)
        own[own_faces[own_faces < len(own)]] = True
        candidate = np.flatnonzero(keep)
        face = samples.face[candidates[candidate]]
        inside = face < len(own)
        keep[candidate[inside]] = ~own[face[inside]]
    sel = local[keep]
    return NearbyGeometry(sel[:, 0], sel[:, 1:], project(samples.points[candidates[keep]], up)[:, 0])


def _in_image(pix: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """(N,2) (col, row) pixels inside an image of `shape` (rows, cols)."""
    return (pix[:, 0] >= 0) & (pix[:, 0] < shape[1]) & (pix[:, 1] >= 0) & (pix[:, 1] < shape[0])


def clearance_blocked(raster: SurfaceRaster, near: NearbyGeometry, radius: float, spacing: float) -> np.ndarray:
    """Cells within `radius` (3D) of a sample in front of the surface.

    A sample at depth h removes the disc of radius sqrt(r^2 - h^2) around its projection; depths
    are grouped in bands, each band using its smallest depth (so the disc is never too small).
    Band edges r*sin(k*pi/2K) keep the disc radii of consecutive bands at most r*pi/2K apart.
    """
    import cv2

    r = radius + spacing * GAP
    cell = raster.cell
    blocked = np.zeros(raster.shape, bool)
    if len(near.depth) == 0 or r <= 0:
        return blocked
    pad = int(np.ceil(r / cell)) + 1
    rows, cols = raster.shape
    shape = (rows + 2 * pad, cols + 2 * pad)
    pix = np.round(raster.to_pixels(near.uv)).astype(np.int64) + pad
    usable = _in_image(pix, shape) & (near.depth <= r)
    pix, depth = pix[usable], near.depth[usable]
    edges = r * np.sin(np.linspace(0.0, np.pi / 2, CLEARANCE_BANDS + 1))
    band = np.clip(np.searchsorted(edges, depth, side="right") - 1, 0, CLEARANCE_BANDS - 1)
    # A pixel's shallowest sample removes the largest disc: deeper samples there add nothing
    # (a perpendicular wall projects all its depths onto one line: one band instead of ten).
    order = np.lexsort((band, pix[:, 1], pix[:, 0]))
    key = pix[order, 0] * shape[0] + pix[order, 1]
    first = np.concatenate([[True], key[1:] != key[:-1]]) if len(key) else np.zeros(0, bool)
    pix, band = pix[order[first]], band[order[first]]
    for b in np.unique(band):
        cols_rows = pix[band == b]
        disc = np.sqrt(max(r * r - edges[b] ** 2, 0.0)) / cell + SNAP
        # Only the window around this band's samples (grown by the disc) can change.
        reach = int(np.ceil(disc)) + 1
        c0, r0 = np.maximum(cols_rows.min(axis=0) - reach, pad)
        c1, r1 = np.minimum(cols_rows.max(axis=0) + reach + 1, [pad + cols, pad + rows])
        if c0 >= c1 or r0 >= r1:
            continue
        # Crop with the seeds' own extent included, so distances inside the window are exact.
        s0 = np.minimum([c0, r0], cols_rows.min(axis=0))
        s1 = np.maximum([c1, r1], cols_rows.max(axis=0) + 1)
        seeds = np.ones((s1[1] - s0[1], s1[0] - s0[0]), np.uint8)
        seeds[cols_rows[:, 1] - s0[1], cols_rows[:, 0] - s0[0]] = 0
        dist = cv2.distanceTransform(seeds, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
        window = dist[r0 - s0[1]:r1 - s0[1], c0 - s0[0]:c1 - s0[0]]
        blocked[r0 - pad:r1 - pad, c0 - pad:c1 - pad] |= window <= disc
    return blocked


def recovery_blocked(raster: SurfaceRaster, near: NearbyGeometry, up: np.ndarray, floor_height: float,
                     fall: float, corridor_half_width: float, spacing: float,
                     surface_class: SurfaceClass = SurfaceClass.WALL) -> np.ndarray:
    """Cells from which a drone cannot fall `fall` metres without meeting geometry.

    Walls (the surface's class, by the configured class angle): the fall corridor is the box in front
    of the wall, 2 x half-width deep and wide, from the cell's height down by `fall`; any sample in it
    blocks. Ceilings (and intermediate surfaces facing down): the column below the cell, half-width
    wide, `fall` deep. Floors (and intermediate surfaces facing up: landing) need no fall. All cells
    must also be `fall` above the floor.
    """
    import cv2

    f = raster.frame
    cell = raster.cell
    rows, cols = raster.shape
    heights = (raster.frame.origin @ up) + (raster.v0 + np.arange(rows) * cell) * float(f.axis_v @ up)
    blocked = np.repeat((heights < floor_height + fall)[:, None], cols, axis=1)
    facing = float(f.normal @ up)
    if surface_class == SurfaceClass.WALL:
        upward = downward = False
    else:
        upward, downward = facing > 0, facing < 0
    if upward or len(near.depth) == 0:
        return np.zeros(raster.shape, bool) if upward else blocked
    half = int(np.ceil((corridor_half_width + spacing * GAP) / cell + SNAP))
    pix = np.round(raster.to_pixels(near.uv)).astype(np.int64)
    if downward:  # ceiling-like: the column below the cell
        seeds = np.zeros((rows + 2 * half, cols + 2 * half), np.uint8)
        pix = pix + half
        usable = _in_image(pix, seeds.shape) & (near.depth <= fall + spacing * GAP)
        seeds[pix[usable, 1], pix[usable, 0]] = 1
        grown = cv2.dilate(seeds, np.ones((2 * half + 1, 2 * half + 1), np.uint8))
        return blocked | grown[half:half + rows, half:half + cols].astype(bool)
    # Wall-like: a sample at height z blocks cells of this column band with z < cell height <= z + fall.
    slope = float(f.axis_v @ up) * cell  # height per row
    margin = spacing * GAP + SNAP * cell
    start = np.floor((near.height - margin - heights[0]) / slope).astype(np.int64)
    stop = np.ceil((near.height + fall + margin - heights[0]) / slope).astype(np.int64)
    col = pix[:, 0] + half
    ok = (stop >= 0) & (start < rows) & (col >= 0) & (col < cols + 2 * half)
    ok &= near.depth <= 2 * corridor_half_width + spacing * GAP
    start, stop, col = np.clip(start[ok], 0, rows), np.clip(stop[ok] + 1, 0, rows), col[ok]
    width = cols + 2 * half
    size = (rows + 1) * width
    diff = (np.bincount(start * width + col, minlength=size)
            - np.bincount(stop * width + col, minlength=size)).reshape(rows + 1, width)
    column_hits = (np.cumsum(diff, axis=0)[:rows] > 0).astype(np.uint8)
    grown = cv2.dilate(column_hits, np.ones((1, 2 * half + 1), np.uint8))
    return blocked | grown[:, half:half + cols].astype(bool)
