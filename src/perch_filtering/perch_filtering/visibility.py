"""Target visibility: the share of the target's sample points a perch sees, for many perches at once.

Shares are ray cast on a coarse grid of each surface's raster (every `spacing` metres) covering the
cells asked for, all surfaces in one batch, and interpolated bilinearly to the cells: a share over
many target points varies smoothly across a surface, so the coarse grid costs almost nothing in
accuracy and cuts the rays by the square of the grid step.

When only whether a cell's share reaches a threshold counts (the filter's line of sight), the sight
lines are cast in rounds (`_bounded_shares`): each node keeps a lower bound (points seen so far) and
an upper bound (seen plus facing points not yet cast) of its share, and casts more only while a cell
interpolated from it is undecided. The thresholded map is exactly that of casting every sight line.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from perch_common.raycast import RayScene
from perch_filtering.holes import patched_occlusion
from perch_filtering.raster import SurfaceRaster

CHUNK_PAIRS = 1 << 18  # origin-target pairs gathered and cast at once (3 MB of float32 segments)
ROUND_POINTS = 8       # target points each undecided node casts per round of the bounded shares
FACING_NODES = 1 << 14  # nodes whose facing targets are found at once (temporaries of a few MB)
ORDER_SEED = 0         # the fixed order in which a node's target points are cast (cost only, not answers)


def visible_shares(rasters: list[SurfaceRaster], masks: list[np.ndarray], offsets: list[float],
                   target_points: np.ndarray, scene: RayScene, patches: RayScene | None,
                   spacing: float, groups: np.ndarray | None = None,
                   threshold: float | None = None) -> list[np.ndarray]:
    """Per raster, a float32 map of the share of `target_points` seen from each cell in its mask
    (rays start `offset` in front of the plane; points behind the plane are not seen); 0 elsewhere.
    With `groups` ((T, G) bool: which points belong to each of G target volumes), the share of the
    volume seen best. With `threshold`, a map exact only as to `share >= threshold` (the same
    comparison of every cell as with the exact shares), for far fewer rays."""
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
    origins, normals = np.concatenate(origins), np.concatenate(normals)
    if threshold is None or len(target_points) == 0:
        share = _shares(origins, normals, target_points, scene, patches, groups)
        return _interpolated(share, rasters, masks, nodes)
    cells = _Cells.of(masks, nodes)
    values = _bounded_shares(origins, normals, target_points, scene, patches, groups, cells, threshold)
    out, first = [], 0
    for mask in masks:   # the cells are in the rasters' order, each raster's in its mask's
        count = int(mask.sum())
        grid = np.zeros(mask.shape, np.float32)
        grid[mask] = values[first:first + count]
        first += count
        out.append(grid)
    return out


def _interpolated(share: np.ndarray, rasters: list[SurfaceRaster], masks: list[np.ndarray],
                  nodes: list[tuple[int, np.ndarray]]) -> list[np.ndarray]:
    """Per raster, the node shares (in node order) interpolated to the cells of its mask."""
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
    facing = _facing(origins, normals, targets)
    seen = np.zeros(facing.shape, bool)
    origins32, targets32 = origins.astype(np.float32), targets.astype(np.float32)
    step = max(1, CHUNK_PAIRS // max(len(targets), 1))
    for first in range(0, len(origins), step):
        o_idx, t_idx = np.nonzero(facing[first:first + step])
        o_idx += first
        seen[o_idx, t_idx] = _visible(scene, patches, origins32, targets32, o_idx, t_idx)
    if groups is None:
        return (seen.sum(axis=1) / len(targets)).astype(np.float32)
    counts = seen.astype(np.float64) @ groups.astype(np.float64)
    return (counts / np.maximum(groups.sum(axis=0), 1)).max(axis=1).astype(np.float32)


def _facing(origins: np.ndarray, normals: np.ndarray, targets: np.ndarray) -> np.ndarray:
    """(O, T) whether each target lies in front of each origin's plane."""
    return np.einsum("tk,ok->ot", targets, normals) > np.einsum("ok,ok->o", origins, normals)[:, None]


def _visible(scene: RayScene, patches: RayScene | None, origins32: np.ndarray, targets32: np.ndarray,
             o_idx: np.ndarray, t_idx: np.ndarray) -> np.ndarray:
    """Whether each pair's segment origins32[o_idx] -> targets32[t_idx] is free of the mesh and the
    hole patches. The rays go to Embree in float32: gathered in float32 (what the ray scene converts
    them to) and CHUNK_PAIRS at a time, a building's millions of sight lines cost a few MB."""
    out = np.empty(len(o_idx), bool)
    for first in range(0, len(o_idx), CHUNK_PAIRS):
        part = slice(first, first + CHUNK_PAIRS)
        # np.take gathers whole rows several times faster than fancy indexing.
        out[part] = ~patched_occlusion(scene, patches, np.take(origins32, o_idx[part], axis=0),
                                       np.take(targets32, t_idx[part], axis=0))
    return out


@dataclass
class _Cells:
    """Masked cells of every raster as their bilinear weights and the global indices of the nodes
    they weigh, in `_bilinear`'s order of terms, so a cell's value from node shares is bit for bit
    `_bilinear`'s. A weight of 0 refers to the cell's first node (0 times any share adds the same 0)."""

    nodes: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]
    weights: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]

    @classmethod
    def of(cls, masks: list[np.ndarray], nodes: list[tuple[int, np.ndarray]]) -> "_Cells":
        ids, weights, first = [[], [], [], []], [[], [], [], []], 0
        for mask, (step, need) in zip(masks, nodes):
            index = np.full(need.shape, -1, np.int64)
            count = int(need.sum())
            index[need] = np.arange(first, first + count)
            first += count
            rows, cols = np.nonzero(mask)
            i, j = rows // step, cols // step
            fr, fc = (rows % step) / step, (cols % step) / step
            own = index[i, j]
            for k, (node, weight) in enumerate([(own, (1 - fr) * (1 - fc)), (index[i, j + 1], (1 - fr) * fc),
                                                (index[i + 1, j], fr * (1 - fc)), (index[i + 1, j + 1], fr * fc)]):
                ids[k].append(np.where(weight > 0, node, own))
                weights[k].append(weight)
        return cls(tuple(np.concatenate(a) for a in ids),
                   tuple(np.concatenate(w) for w in weights))

    def values(self, share: np.ndarray) -> np.ndarray:
        """float32 interpolated node `share` at every cell (the arithmetic of `_bilinear`)."""
        (a, b, c, d), (wa, wb, wc, wd) = self.nodes, self.weights
        return (wa * share[a] + wb * share[b] + wc * share[c] + wd * share[d]).astype(np.float32)

    def subset(self, which: np.ndarray) -> "_Cells":
        return _Cells(tuple(n[which] for n in self.nodes), tuple(w[which] for w in self.weights))

    def weighed_nodes(self, count: int) -> np.ndarray:
        """(count,) bool: the nodes these cells weigh by more than nothing."""
        out = np.zeros(count, bool)
        for node in self.nodes:
            out[node] = True
        return out


class _Bounds:
    """Per node, lower and upper bounds of `_shares` from the sight lines cast so far: `_shares`'
    arithmetic on the points seen (lower) and on those plus the facing points not yet cast (upper).
    Every step of that arithmetic (division by a fixed size, max, rounding to float32) is monotonic
    in each count, so the exact share lies between the bounds, and equals both once they meet."""

    def __init__(self, origins: np.ndarray, normals: np.ndarray, targets: np.ndarray,
                 groups: np.ndarray | None, scene: RayScene, patches: RayScene | None):
        # Groups interleaved in the casting order: a perch seeing one volume finds its points early.
        order = np.random.default_rng(ORDER_SEED).permutation(len(targets))
        self.member = (np.ones((len(targets), 1), bool) if groups is None else np.asarray(groups, bool))[order]
        self.sizes = np.maximum(self.member.sum(axis=0), 1).astype(np.float64)  # `_shares`' len(targets) for one group
        self.facing = np.empty((len(origins), len(targets)), bool)
        self.possible = np.empty((len(origins), self.member.shape[1]))
        member32 = self.member.astype(np.float32)
        for first in range(0, len(origins), FACING_NODES):
            part = slice(first, first + FACING_NODES)
            self.facing[part] = _facing(origins[part], normals[part], targets)[:, order]
            self.possible[part] = _counts(self.facing[part], member32)
        self.seen = np.zeros(self.possible.shape)
        self.lower, _ = self._shares(self.seen)
        self.upper, self.group_upper = self._shares(self.possible)
        self.origins32, self.targets32 = origins.astype(np.float32), targets[order].astype(np.float32)
        self.scene, self.patches = scene, patches

    def _shares(self, counts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        per_group = counts / self.sizes
        return per_group.max(axis=1).astype(np.float32), per_group

    def open(self, nodes: np.ndarray) -> np.ndarray:
        """Whether each node's bounds differ."""
        return self.lower[nodes] < self.upper[nodes]

    def cast(self, nodes: np.ndarray, window: slice, deciding: float | None = None) -> None:
        """Cast the sight lines from `nodes` to their facing points at positions `window` of groups that
        can still raise the node's share (with `deciding`: and reach it)."""
        member = self.member[window].astype(np.float32)
        cast = np.take(self.facing[:, window], nodes, axis=0)
        if deciding is not None:
            group_upper = np.take(self.group_upper, nodes, axis=0).astype(np.float32)
            # A group whose upper bound is no more than the node's lower bound cannot raise its share.
            useful = (group_upper > np.take(self.lower, nodes)[:, None]) & (group_upper >= deciding)
            cast &= _counts(useful, member.T) > 0
        points, rows = np.nonzero(cast.T)   # point by point: neighbouring nodes' rays traverse alike (~8 % faster)
        visible = np.zeros(cast.shape, np.float32)
        visible[rows, points] = _visible(self.scene, self.patches, self.origins32, self.targets32,
                                         np.take(nodes, rows), points + window.start)
        seen = np.take(self.seen, nodes, axis=0) + _counts(visible, member)
        possible = np.take(self.possible, nodes, axis=0) - _counts(cast.astype(np.float32) - visible, member)
        self.seen[nodes], self.possible[nodes] = seen, possible
        self.lower[nodes], _ = self._shares(seen)
        self.upper[nodes], self.group_upper[nodes] = self._shares(possible)

    def cast_all(self, nodes: np.ndarray) -> None:
        """Cast every facing sight line from `nodes` anew: their bounds become exact."""
        self.seen[nodes] = 0
        self.possible[nodes] = _counts(self.facing[nodes], self.member.astype(np.float32))
        self.cast(nodes, slice(0, self.facing.shape[1]))


def _counts(flags: np.ndarray, member: np.ndarray) -> np.ndarray:
    """(A, G) = (A, K) 0/1 flags summed per group of `member` ((K, G) 0/1), exact in float32 (counts
    < 2^24). A matrix product: Perch's entry points give BLAS one thread (`perch_common.threads`);
    a threaded OpenBLAS would spin after each of these small products."""
    return flags.astype(np.float32) @ member


def _bounded_shares(origins: np.ndarray, normals: np.ndarray, targets: np.ndarray, scene: RayScene,
                    patches: RayScene | None, groups: np.ndarray | None, cells: _Cells,
                    threshold: float) -> np.ndarray:
    """Per cell (in `cells`' order) a float32 value on the same side of `threshold` as `_shares`
    interpolated there (`_bilinear`'s arithmetic).

    Each node casts ROUND_POINTS target points a round (in a fixed order, of the groups that can
    still decide it) until its own bounds lie on one side of `threshold`; a cell is then decided when
    its interpolated lower bound reaches it or its upper bound falls below it (products with fixed
    non-negative weights and sums are monotonic too, so the exact interpolated share lies between).
    The nodes of cells still undecided cast all their points anew, which makes their bounds exact
    and so decides those cells too."""
    count, total = len(origins), len(targets)
    if count == 0:
        return np.zeros(len(cells.nodes[0]), np.float32)
    bounds = _Bounds(origins, normals, targets, groups, scene, patches)
    active = np.flatnonzero(bounds.open(np.arange(count)))
    for position in range(0, total, ROUND_POINTS):
        if not len(active):
            break
        bounds.cast(active, slice(position, position + ROUND_POINTS), deciding=threshold)
        lower, upper = bounds.lower[active], bounds.upper[active]
        active = active[(lower < threshold) & (upper >= threshold) & (lower < upper)]
    low, high = cells.values(bounds.lower), cells.values(bounds.upper)
    undecided = np.flatnonzero((low < threshold) & (high >= threshold))
    if len(undecided):
        rest = cells.subset(undecided)
        nodes = np.flatnonzero(rest.weighed_nodes(count))
        bounds.cast_all(nodes[bounds.open(nodes)])
        low[undecided], high[undecided] = rest.values(bounds.lower), rest.values(bounds.upper)
    if not ((low >= threshold) | (high < threshold)).all():
        raise AssertionError("sight line bounds left a cell undecided")  # cast in full, they are equal
    return np.where(low >= threshold, low, high)


def _bilinear(grid: np.ndarray, step: int, shape: tuple[int, int], mask: np.ndarray) -> np.ndarray:
    """Values of the coarse `grid` (node (i, j) at cell (i * step, j * step)) at the cells in `mask`."""
    out = np.zeros(shape, np.float32)
    rows, cols = np.nonzero(mask)
    i, j = rows // step, cols // step
    fr, fc = (rows % step) / step, (cols % step) / step
    out[rows, cols] = ((1 - fr) * (1 - fc) * grid[i, j] + (1 - fr) * fc * grid[i, j + 1]
                       + fr * (1 - fc) * grid[i + 1, j] + fr * fc * grid[i + 1, j + 1])
    return out
