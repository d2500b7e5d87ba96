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
ROUND_POINTS = 8       # target points each undecided node casts per round of the bounded shares (middle rounds)
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
    comparison of every cell as with the exact shares), for far fewer rays. Each raster's answer
    depends on it alone: any split of the rasters over calls gives the same maps."""
    layouts = [_Layout.of(mask, max(1, int(round(spacing / raster.cell)))) for raster, mask in zip(rasters, masks)]
    origins, normals, first = [], [], 0
    for raster, offset, layout in zip(rasters, offsets, layouts):
        nr, nc = np.nonzero(layout.need)
        step = layout.step
        uv = np.column_stack([raster.u0 + nc * step * raster.cell, raster.v0 + nr * step * raster.cell])
        origins.append(raster.frame.to_world(uv) + offset * raster.frame.normal)
        normals.append(np.repeat(raster.frame.normal[None], len(uv), axis=0))
        layout.first, first = first, first + len(uv)
    origins, normals = np.concatenate(origins), np.concatenate(normals)
    if threshold is None or len(target_points) == 0:
        share = _shares(origins, normals, target_points, scene, patches, groups)
        return _interpolated(share, rasters, masks, [(layout.step, layout.need) for layout in layouts])
    return _bounded_shares(origins, normals, target_points, scene, patches, groups, layouts, masks, threshold)


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
class _Layout:
    """One raster's coarse nodes (cell (i * step, j * step) is node (i, j)): `need`, every node its
    masked cells interpolate from (the full computation's node grid), `weighed`, those some cell
    weighs by more than nothing (the rest never change a cell), `first`, its first node's index in
    the nodes of all rasters (each raster's in `need`'s order)."""

    step: int
    need: np.ndarray
    weighed: np.ndarray
    filled: np.ndarray   # (need's shape - 1) the blocks holding masked cells
    first: int = 0

    @classmethod
    def of(cls, mask: np.ndarray, step: int) -> "_Layout":
        rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
        if not len(rows):
            return cls(step, np.zeros((0, 0), bool), np.zeros((0, 0), bool), np.zeros((0, 0), bool))
        height, width = rows[-1] // step + 2, cols[-1] // step + 2
        # Cells by their position (r, c) in their block: block (i, j) holds the cells that node (i, j) starts.
        padded = np.zeros(((height - 1) * step, (width - 1) * step), bool)
        padded[:rows[-1] + 1, :cols[-1] + 1] = mask[:rows[-1] + 1, :cols[-1] + 1]
        at = [[padded[r::step, c::step] for c in range(step)] for r in range(step)]
        corner = at[0][0].copy()
        right = np.logical_or.reduce([at[0][c] for c in range(1, step)]) if step > 1 else np.zeros_like(corner)
        below = np.logical_or.reduce([at[r][0] for r in range(1, step)]) if step > 1 else np.zeros_like(corner)
        both = (np.logical_or.reduce([at[r][c] for r in range(1, step) for c in range(1, step)])
                if step > 1 else np.zeros_like(corner))
        right |= both     # cells with a weight on node (i, j + 1)
        below |= both     # on node (i + 1, j)
        own = corner | right | below
        need, weighed = np.zeros((height, width), bool), np.zeros((height, width), bool)
        for dr in (0, 1):
            for dc in (0, 1):
                need[dr:height - 1 + dr, dc:width - 1 + dc] |= own
        weighed[:-1, :-1] = own
        weighed[:-1, 1:] |= right
        weighed[1:, :-1] |= below
        weighed[1:, 1:] |= both
        return cls(step, need, weighed, own)

    def node_grid(self, values: np.ndarray) -> np.ndarray:
        """(need's shape) float32: this raster's nodes' `values` (of all nodes) at their nodes, 0 elsewhere."""
        grid = np.zeros(self.need.shape, np.float32)
        grid[self.need] = values[self.first:self.first + int(self.need.sum())]
        return grid

    def block_values(self, grid: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """(B, step, step) float32 bilinear values of node `grid` at every cell of blocks (rows, cols):
        `_bilinear`'s arithmetic (float64 weights times float32 shares, summed in its order), so bit
        for bit its values."""
        fr = (np.arange(self.step) / self.step)[:, None]
        fc = (np.arange(self.step) / self.step)[None, :]
        a, b, c, d = (grid[rows + dr, cols + dc][:, None, None] for dr, dc in ((0, 0), (0, 1), (1, 0), (1, 1)))
        return ((1 - fr) * (1 - fc) * a + (1 - fr) * fc * b + fr * (1 - fc) * c + fr * fc * d).astype(np.float32)


def _facing_by_raster(origins: np.ndarray, normals: np.ndarray, targets: np.ndarray,
                      layouts: list["_Layout"]) -> np.ndarray:
    """(T, O) `_facing(origins, normals, targets).T`: a raster's nodes share its normal, so each target's
    side is one product per raster (its first node's row: einsum's arithmetic of every row) against
    each node's own product."""
    facing = np.empty((len(targets), len(origins)), bool)
    for layout in layouts:
        part = slice(layout.first, layout.first + int(layout.need.sum()))
        if part.start == part.stop:
            continue
        along = np.einsum("tk,ok->ot", targets, normals[part][:1])[0]
        facing[:, part] = along[:, None] > np.einsum("ok,ok->o", origins[part], normals[part])[None]
    return facing


def _counts(flags: np.ndarray, member: np.ndarray) -> np.ndarray:
    """(G, A) = (G, K) 0/1 `member` times (K, A) 0/1 `flags`: per group, how many flags are set; exact in
    float32 (counts < 2^24). A matrix product: Perch's entry points give BLAS one thread
    (`perch_common.threads`); a threaded OpenBLAS would spin after each of these small products."""
    return member @ flags.astype(np.float32)


def _passing_counts(sizes: np.ndarray, threshold: float) -> np.ndarray:
    """(G, 1) float32: per group, the fewest points seen whose share (`_shares`' arithmetic: count / size in
    float64, rounded to float32) reaches `threshold` (compared as `_shares`' values are); size + 1 if none."""
    counts = np.arange(int(sizes.max()) + 2, dtype=np.float64)[:, None]
    reaches = (counts / sizes).astype(np.float32) >= threshold   # monotonic in the count
    first = np.where(reaches.any(axis=0), reaches.argmax(axis=0), sizes.astype(np.int64) + 1)
    return first.astype(np.float32)[:, None]


def _bounded_shares(origins: np.ndarray, normals: np.ndarray, targets: np.ndarray,
                    scene: RayScene, patches: RayScene | None, groups: np.ndarray | None,
                    layouts: list[_Layout], masks: list[np.ndarray], threshold: float) -> list[np.ndarray]:
    """Per raster a float32 map, at each masked cell on the same side of `threshold` as `_shares`
    interpolated there (`_bilinear`'s arithmetic), 0 elsewhere.

    Each node keeps, per group, the points seen so far and those seen plus the facing points not yet
    cast: `_shares`' arithmetic on them gives a lower and an upper bound of its share (division by a
    fixed size, max and rounding to float32 are monotonic in each count). Each round (`_round_windows`,
    target points in a fixed order; groups interleaved, so a perch seeing one volume finds its points
    early) a node casts those of the groups that can still reach `threshold`, until some group's seen count
    reaches it or no group's upper count can. Bilinear weights are fixed and non-negative, so a cell
    is decided when its interpolated lower bound reaches `threshold` or its upper bound falls below
    it. The nodes of cells still undecided cast all their points anew, which makes their bounds exact
    and so decides those cells too. Nodes no cell weighs cast nothing."""
    count = len(origins)
    order = np.random.default_rng(ORDER_SEED).permutation(len(targets))
    member = (np.ones((len(targets), 1), bool) if groups is None else np.asarray(groups, bool))[order]
    member32 = member.T.astype(np.float32)   # (G, T)
    sizes = np.maximum(member.sum(axis=0), 1).astype(np.float64)  # `_shares`' len(targets) for one group
    passing = _passing_counts(sizes, threshold)
    facing = _facing_by_raster(origins, normals, targets[order], layouts)   # (T, O)
    possible = np.empty((member.shape[1], count), np.float32)
    for first in range(0, count, FACING_NODES):
        possible[:, first:first + FACING_NODES] = _counts(facing[:, first:first + FACING_NODES], member32)
    seen = np.zeros_like(possible)
    origins32, targets32 = origins.astype(np.float32), targets[order].astype(np.float32)

    def free(nodes: np.ndarray, points: np.ndarray) -> np.ndarray:
        return _visible(scene, patches, origins32, targets32, nodes, points)

    weighed = np.concatenate([layout.weighed[layout.need] for layout in layouts])
    active = np.flatnonzero(weighed & _undecided(seen, possible, passing))
    seen_a, possible_a = seen[:, active], possible[:, active]
    for window in _round_windows(len(targets)):
        if not len(active):
            break
        position = window.start
        # Points of groups that can still reach the threshold (points of no group change no share).
        useful = _counts(possible_a >= passing, member32[:, window].T) > 0
        cast = np.take(facing[window], active, axis=1) & useful
        # Point by point (cast's order): neighbouring nodes' rays traverse alike (~8 % faster). Flat
        # indices and each row's count: a third of the cost of a 2-D nonzero (or of a divmod).
        flat = np.flatnonzero(cast)
        points = np.repeat(np.arange(cast.shape[0]), np.count_nonzero(cast, axis=1))
        columns = flat - points * len(active)
        visible = np.zeros(cast.size, np.float32)
        visible[flat] = free(np.take(active, columns), points + position)
        visible = visible.reshape(cast.shape)
        seen_now = _counts(visible, member32[:, window])
        seen_a += seen_now
        possible_a -= _counts(cast, member32[:, window]) - seen_now   # the blocked ones
        still = _undecided(seen_a, possible_a, passing)
        done = active[~still]
        seen[:, done], possible[:, done] = seen_a[:, ~still], possible_a[:, ~still]
        active, seen_a, possible_a = active[still], seen_a[:, still], possible_a[:, still]
    seen[:, active], possible[:, active] = seen_a, possible_a
    lower, upper = _group_shares(seen, sizes), _group_shares(possible, sizes)
    out, undecided = _decided_cells(layouts, masks, lower, upper, threshold)
    if undecided:
        nodes = np.unique(np.concatenate([_weighing_nodes(layouts[k], cells) for k, cells in undecided.items()]))
        nodes = nodes[lower[nodes] < upper[nodes]]
        points, columns = np.nonzero(np.take(facing, nodes, axis=1))
        visible = np.zeros((len(targets), len(nodes)), np.float32)
        visible[points, columns] = free(np.take(nodes, columns), points)
        lower[nodes] = upper[nodes] = _group_shares(_counts(visible, member32), sizes)
        again, still_undecided = _decided_cells([layouts[k] for k in undecided], [masks[k] for k in undecided],
                                                lower, upper, threshold)
        if still_undecided:
            raise AssertionError("sight line bounds left a cell undecided")  # cast in full, they are equal
        for k, grid in zip(undecided, again):
            out[k] = grid
    return out


def _round_windows(total: int) -> list[slice]:
    """The target positions cast per round: twice ROUND_POINTS first (no node can be decided before a
    few rays per group), ROUND_POINTS up to three quarters, then half of it: a failing node decides only
    when nearly all its points are cast, so the last rounds are fine, less cast beyond the deciding
    ray (on the building's 64 points 7.94 -> 7.65 M sight lines, and fewer node rounds)."""
    windows, position = [], 0
    while position < total:
        size = 2 * ROUND_POINTS if not windows else ROUND_POINTS if position < 0.75 * total else ROUND_POINTS // 2
        windows.append(slice(position, min(position + size, total)))
        position += size
    return windows


def _undecided(seen: np.ndarray, possible: np.ndarray, passing: np.ndarray) -> np.ndarray:
    """(A,) whether each node's share may still reach the threshold and has not yet: no group's seen
    count reaches its passing count, some group's upper count does (a loop over the few groups: numpy
    reduces a short axis slowly)."""
    reached, reachable = seen[0] >= passing[0], possible[0] >= passing[0]
    for g in range(1, len(passing)):
        reached |= seen[g] >= passing[g]
        reachable |= possible[g] >= passing[g]
    return reachable & ~reached


def _group_shares(counts: np.ndarray, sizes: np.ndarray) -> np.ndarray:
    """(N,) float32 `_shares` of (G, N) per-group counts: the best group's count / size."""
    best = counts[0].astype(np.float64) / sizes[0]
    for g in range(1, len(sizes)):
        np.maximum(best, counts[g].astype(np.float64) / sizes[g], out=best)
    return best.astype(np.float32)


def _decided_cells(layouts: list[_Layout], masks: list[np.ndarray], lower: np.ndarray, upper: np.ndarray,
                   threshold: float) -> tuple[list[np.ndarray], dict[int, tuple[np.ndarray, np.ndarray]]]:
    """Per raster a map of its masked cells on the side of `threshold` their interpolated bounds
    decide (a value reaching it where the interpolated lower bound does, else one below it where the
    upper bound is below it, else the upper bound); and per raster with undecided cells (lower below,
    upper reaching) their rows and columns.

    A block whose four nodes' lower bounds all reach `threshold` has every cell's reach it, and one
    whose upper bounds are all below it, every cell's below it: a cell's value is its nodes' values
    times float64 weights that are non-negative and sum to 1 within a few float64 roundings, so
    rounded to float32 it is no less than the least of them and no more than the largest (float32
    values 2^-24 apart). Only the other blocks are interpolated cell by cell."""
    out, undecided = [], {}
    for k, (layout, mask) in enumerate(zip(layouts, masks)):
        grid = np.zeros(mask.shape, np.float32)
        out.append(grid)
        if not layout.need.size:
            continue
        step, (height, width) = layout.step, layout.need.shape
        low, high = layout.node_grid(lower), layout.node_grid(upper)
        least = np.minimum(np.minimum(low[:-1, :-1], low[:-1, 1:]), np.minimum(low[1:, :-1], low[1:, 1:]))
        most = np.maximum(np.maximum(high[:-1, :-1], high[:-1, 1:]), np.maximum(high[1:, :-1], high[1:, 1:]))
        reached, below = least >= threshold, most < threshold
        blocks = np.where(reached, least, most)
        cells = np.broadcast_to(blocks[:, None, :, None], (height - 1, step, width - 1, step))
        cells = cells.reshape((height - 1) * step, (width - 1) * step)[:mask.shape[0], :mask.shape[1]]
        np.copyto(grid[:cells.shape[0], :cells.shape[1]], cells, where=mask[:cells.shape[0], :cells.shape[1]])
        rows, cols = np.nonzero(~(reached | below) & layout.filled)
        if not len(rows):
            continue
        low_cells, high_cells = layout.block_values(low, rows, cols), layout.block_values(high, rows, cols)
        r = rows[:, None, None] * step + np.arange(step)[None, :, None]
        c = cols[:, None, None] * step + np.arange(step)[None, None, :]
        r, c = np.broadcast_arrays(r, c)
        inside = (r < mask.shape[0]) & (c < mask.shape[1])
        inside[inside] = mask[r[inside], c[inside]]
        value = np.where(low_cells >= threshold, low_cells, high_cells)
        grid[r[inside], c[inside]] = value[inside]
        open_ = inside & (low_cells < threshold) & (high_cells >= threshold)
        if open_.any():
            undecided[k] = (r[open_], c[open_])
    return out, undecided


def _weighing_nodes(layout: _Layout, cells: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """Indices (of all nodes) of the nodes the cells at `cells` (rows, columns) weigh by more than nothing."""
    index = np.full(layout.need.shape, -1, np.int64)
    index[layout.need] = np.arange(layout.first, layout.first + int(layout.need.sum()))
    rows, cols = cells
    i, j, r, c = rows // layout.step, cols // layout.step, rows % layout.step > 0, cols % layout.step > 0
    return np.concatenate([index[i, j], index[i, j + 1][c], index[i + 1, j][r], index[i + 1, j + 1][r & c]])


def _bilinear(grid: np.ndarray, step: int, shape: tuple[int, int], mask: np.ndarray) -> np.ndarray:
    """Values of the coarse `grid` (node (i, j) at cell (i * step, j * step)) at the cells in `mask`."""
    out = np.zeros(shape, np.float32)
    rows, cols = np.nonzero(mask)
    i, j = rows // step, cols // step
    fr, fc = (rows % step) / step, (cols % step) / step
    out[rows, cols] = ((1 - fr) * (1 - fc) * grid[i, j] + (1 - fr) * fc * grid[i, j + 1]
                       + fr * (1 - fc) * grid[i + 1, j] + fr * fc * grid[i + 1, j + 1])
    return out
