"""Target visibility: the share of the target's sample points a perch sees, for many perches at once.

Shares are ray cast on a coarse grid of each surface's raster (every `spacing` metres) covering the
cells asked for, all surfaces in one batch, and interpolated bilinearly to the cells: a share over
many target points varies smoothly across a surface, so the coarse grid costs almost nothing in
accuracy and cuts the rays by the square of the grid step.
"""

from __future__ import annotations

import numpy as np

from perch_common.raycast import RayScene
from perch_filtering.holes import patched_occlusion
from perch_filtering.raster import SurfaceRaster

CHUNK_PAIRS = 1 << 22  # origin-target pairs cast at once (~100 MB of float32 segments and temporaries)


def visible_shares(rasters: list[SurfaceRaster], masks: list[np.ndarray], offsets: list[float],
                   target_points: np.ndarray, scene: RayScene, patches: RayScene | None,
                   spacing: float, groups: np.ndarray | None = None) -> list[np.ndarray]:
    """Per raster, a float32 map of the share of `target_points` seen from each cell in its mask
    (rays start `offset` in front of the plane; points behind the plane are not seen); 0 elsewhere.
    With `groups` ((T, G) bool: which points belong to each of G target volumes), the share of the
    volume seen best."""
    nodes = []
    for k, (raster, mask) in enumerate(zip(rasters, masks)):
        step = max(1, int(round(spacing / raster.cell)))
        rows, cols = np.nonzero(mask)
        need = np.zeros((rows.max() // step + 2, cols.max() // step + 2), bool) if len(rows) else np.zeros((0, 0), bool)
        for dr in (0, 1):
            for dc in (0, 1):
                need[rows // step + dr, cols // step + dc] = True
        nodes.append((step, need))
    origins, normals = [], []
    for raster, offset, (step, need) in zip(rasters, offsets, nodes):
        nr, nc = np.nonzero(need)
        uv = np.column_stack([raster.u0 + nc * step * raster.cell, raster.v0 + nr * step * raster.cell])
        origins.append(raster.frame.to_world(uv) + offset * raster.frame.normal)
        normals.append(np.repeat(raster.frame.normal[None], len(uv), axis=0))
    share = _shares(np.concatenate(origins), np.concatenate(normals), target_points, scene, patches, groups)
    out, first = [], 0
    for raster, mask, (step, need) in zip(rasters, masks, nodes):
        grid = np.zeros(need.shape, np.float32)
        count = int(need.sum())
        grid[need] = share[first:first + count]
        first += count
        out.append(_bilinear(grid, step, raster.shape, mask))
    return out


def _shares(origins: np.ndarray, normals: np.ndarray, targets: np.ndarray, scene: RayScene,
            patches: RayScene | None, groups: np.ndarray | None = None) -> np.ndarray:
    """Share of `targets` in front of each origin's plane with a free segment to it (with `groups`:
    the largest share of one group's targets)."""
    if len(origins) == 0:
        return np.zeros(0, np.float32)
    facing = np.einsum("tk,ok->ot", targets, normals) > np.einsum("ok,ok->o", origins, normals)[:, None]
    seen = np.zeros(facing.shape, bool)
    # The rays go to Embree in float32: gathered in float32 (what the ray scene converts them to) and
    # CHUNK_PAIRS at a time, a building's millions of sight lines cost a bounded few hundred MB.
    origins32, targets32 = origins.astype(np.float32), targets.astype(np.float32)
    step = max(1, CHUNK_PAIRS // max(len(targets), 1))
    for first in range(0, len(origins), step):
        o_idx, t_idx = np.nonzero(facing[first:first + step])
        o_idx += first
        seen[o_idx, t_idx] = ~patched_occlusion(scene, patches, origins32[o_idx], targets32[t_idx])
    if groups is None:
        return (seen.sum(axis=1) / len(targets)).astype(np.float32)
    counts = seen.astype(np.float64) @ groups.astype(np.float64)
    return (counts / np.maximum(groups.sum(axis=0), 1)).max(axis=1).astype(np.float32)


def _bilinear(grid: np.ndarray, step: int, shape: tuple[int, int], mask: np.ndarray) -> np.ndarray:
    """Values of the coarse `grid` (node (i, j) at cell (i * step, j * step)) at the cells in `mask`."""
    out = np.zeros(shape, np.float32)
    rows, cols = np.nonzero(mask)
    i, j = rows // step, cols // step
    fr, fc = (rows % step) / step, (cols % step) / step
    out[rows, cols] = ((1 - fr) * (1 - fc) * grid[i, j] + (1 - fr) * fc * grid[i, j + 1]
                       + fr * (1 - fc) * grid[i + 1, j] + fr * fc * grid[i + 1, j + 1])
    return out
