"""Projections and a bucket index of a mesh's surface samples (perch_common.mesh_samples), for the
filters that test perches against the other geometry."""

from __future__ import annotations

import numpy as np

from perch_common.mesh_samples import MeshSamples
from perch_common.threads import side_by_side

PROJECT_SPLIT = 1 << 20  # points from which a projection's two halves run on two threads


def project(points: np.ndarray, axes: np.ndarray, origin: np.ndarray | None = None) -> np.ndarray:
    """(N,3) points (minus origin) dotted with each row of `axes` (A,3) -> (N,A), column-major (each
    projection contiguous: the callers reduce and bucket per axis).

    Written out per axis: BLAS matmul of a tall (N,3) by a 3x3 is 40x slower here (threading).
    """
    p = points if origin is None else points - origin
    axes = np.atleast_2d(axes)
    out = np.empty((len(axes), len(p))).T
    # Each row is its own: a large projection's two halves run side by side (numpy releases the GIL).
    half = len(p) // 2 if len(p) >= PROJECT_SPLIT else len(p)
    side_by_side(*(lambda lo=lo, hi=hi: _project_rows(p[lo:hi], axes, out[lo:hi])
                   for lo, hi in ((0, half), (half, len(p))) if hi > lo))
    return out


def _project_rows(p: np.ndarray, axes: np.ndarray, out: np.ndarray) -> None:
    term = np.empty(len(p))
    for a, axis in enumerate(axes):  # (p0 a0 + p1 a1) + p2 a2, as written out before
        column = out[:, a]
        np.multiply(p[:, 0], axis[0], out=column)
        np.multiply(p[:, 1], axis[1], out=term)
        column += term
        np.multiply(p[:, 2], axis[2], out=term)
        column += term


def floor_cells(local: np.ndarray, lo: np.ndarray, size: float) -> np.ndarray:
    """np.floor((local - lo) / size).astype(np.int64) with one float temporary instead of three (the
    building's 8 M samples: 190 MB each; the flight grid and the sample index do this side by side)."""
    scaled = local - lo
    scaled /= size
    np.floor(scaled, out=scaled)
    return scaled.astype(np.int64)


FLOOR_CHUNK = 1 << 16  # points per chunk of cell_keys: its temporaries stay in cache, not fresh pages


def cell_keys(local: np.ndarray, lo: np.ndarray, size: float, dims: tuple) -> np.ndarray:
    """np.ravel_multi_index(floor_cells(local, lo, size).T, dims), a chunk at a time (no (N,3) temporaries:
    the building's 8 M samples would take two of 190 MB)."""
    out = np.empty(len(local), np.int64)
    for start in range(0, len(local), FLOOR_CHUNK):
        part = slice(start, start + FLOOR_CHUNK)
        out[part] = np.ravel_multi_index(floor_cells(local[part], lo, size).T, dims)
    return out


# m: a box's candidates overshoot it by up to a bucket on every side (at 0.5 m a wall's 1 m deep box
# fetched the samples of the wall itself and of the room behind it as well).
BUCKET = 0.25


class SampleIndex:
    """Samples bucketed on a coarse grid (in a rotated frame) to fetch those near a box quickly. The
    index keeps the samples' coordinates and faces in bucket order (`x`, `y`, `z`, `face`): a box's
    candidates are then runs of neighbouring memory, not scattered rows."""

    def __init__(self, samples: MeshSamples, rotation: np.ndarray, bucket: float = BUCKET,
                 local: np.ndarray | None = None):
        """`local`: the samples already projected onto the rows of `rotation` (the flight grid's)."""
        local = project(samples.points, rotation) if local is None else local
        self.rotation, self.bucket = rotation, bucket
        self.lo = local.min(axis=0)
        # The largest cell is the cell of the largest coordinate (floor and the scaling are monotonic).
        self.dims = np.floor((local.max(axis=0) - self.lo) / bucket).astype(np.int64) + 1
        key = cell_keys(local, self.lo, bucket, tuple(self.dims))
        self.order, self.sorted_key = stable_sort(key)
        self.x, self.y, self.z = (np.ascontiguousarray(samples.points[self.order, axis]) for axis in range(3))
        self.face = samples.face[self.order]

    def near_box(self, corners: np.ndarray) -> np.ndarray:
        """Indices of samples in buckets overlapping the (rotated-frame) bounds of world `corners`."""
        return self.order[self.positions_near_box(corners)]

    def positions_near_box(self, corners: np.ndarray) -> np.ndarray:
        """near_box as positions in the index's bucket order (into x, y, z, face), ascending."""
        start, stop = self.runs_near_box(corners)
        lengths = stop - start
        total = int(lengths.sum())
        if total == 0:
            return np.zeros(0, np.int64)
        offsets = np.repeat(start - np.concatenate([[0], np.cumsum(lengths)[:-1]]), lengths)
        return offsets + np.arange(total)

    def runs_near_box(self, corners: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """positions_near_box as runs [start, stop) of positions, ascending, touching runs joined (a
        box's candidates are a few dozen runs: read as slices, not gathered one by one)."""
        none = np.zeros(0, np.int64)
        local = project(np.asarray(corners, np.float64).reshape(-1, 3), self.rotation)
        b0 = np.clip(np.floor((local.min(axis=0) - self.lo) / self.bucket).astype(np.int64), 0, self.dims - 1)
        b1 = np.clip(np.floor((local.max(axis=0) - self.lo) / self.bucket).astype(np.int64), 0, self.dims - 1)
        if np.any(local.max(axis=0) < self.lo) or np.any(b0 > b1):
            return none, none
        ix, iy = np.meshgrid(np.arange(b0[0], b1[0] + 1), np.arange(b0[1], b1[1] + 1), indexing="ij")
        ix, iy = ix.ravel(), iy.ravel()
        first = np.ravel_multi_index((ix, iy, np.full_like(ix, b0[2])), tuple(self.dims))
        last = np.ravel_multi_index((ix, iy, np.full_like(ix, b1[2])), tuple(self.dims))
        start = np.searchsorted(self.sorted_key, first, side="left")
        stop = np.searchsorted(self.sorted_key, last, side="right")
        filled = stop > start
        start, stop = start[filled], stop[filled]
        if len(start) == 0:
            return none, none
        join = np.flatnonzero(start[1:] != stop[:-1]) + 1  # where a run does not start at the last's stop
        return start[np.r_[0, join]], stop[np.r_[join - 1, len(stop) - 1]]


def read_runs(column: np.ndarray, start: np.ndarray, stop: np.ndarray) -> np.ndarray:
    """column[positions] of the runs [start, stop): the slices joined."""
    if len(start) == 0:
        return column[:0].copy()
    return np.concatenate([column[a:b] for a, b in zip(start.tolist(), stop.tolist())])


def run_positions(where: np.ndarray, start: np.ndarray, stop: np.ndarray) -> np.ndarray:
    """Positions (into the index) of the elements `where` of the joined runs [start, stop)."""
    ends = np.cumsum(stop - start)
    run = np.searchsorted(ends, where, side="right")
    return start[run] + where - (ends[run] - (stop[run] - start[run]))


def stable_sort(key: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(np.argsort(key, kind="stable"), the sorted keys) of non-negative int keys below 2^32: two passes of
    numpy's radix sort (its stable sort of 16-bit keys), low half then high. On the building's 3.1 M sample
    buckets 0.05 s, against 0.07 s for argsort of the int64 keys and 0.21 s for sorting keys packed with
    their index (numpy 2.4); as many keys in random order: 0.10 s against argsort's 0.18 s. Other keys: argsort."""
    if len(key) == 0 or int(key.min()) < 0 or int(key.max()) >= 1 << 32:
        order = np.argsort(key, kind="stable")
        return order, key[order]
    order = np.argsort((key & 0xFFFF).astype(np.uint16), kind="stable")
    if int(key.max()) >= 1 << 16:
        order = order[np.argsort((key[order] >> 16).astype(np.uint16), kind="stable")]
    return order, key[order]
