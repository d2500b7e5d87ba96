"""Projections and a bucket index of a mesh's surface samples (perch_common.mesh_samples), for the
filters that test perches against the other geometry."""

from __future__ import annotations

import numpy as np

from perch_common.mesh_samples import MeshSamples


def project(points: np.ndarray, axes: np.ndarray, origin: np.ndarray | None = None) -> np.ndarray:
    """(N,3) points (minus origin) dotted with each row of `axes` (A,3) -> (N,A).

    Written out per axis: BLAS matmul of a tall (N,3) by a 3x3 is 40x slower here (threading).
    """
    p = points if origin is None else points - origin
    axes = np.atleast_2d(axes)
    out = np.empty((len(p), len(axes)))
    for a, axis in enumerate(axes):
        out[:, a] = p[:, 0] * axis[0] + p[:, 1] * axis[1] + p[:, 2] * axis[2]
    return out


def floor_cells(local: np.ndarray, lo: np.ndarray, size: float) -> np.ndarray:
    """np.floor((local - lo) / size).astype(np.int64) with one float temporary instead of three (the
    building's 8 M samples: 190 MB each; the flight grid and the sample index do this side by side)."""
    scaled = local - lo
    scaled /= size
    np.floor(scaled, out=scaled)
    return scaled.astype(np.int64)


# m: a box's candidates overshoot it by up to a bucket on every side (at 0.5 m a wall's 1 m deep box
# fetched the samples of the wall itself and of the room behind it as well).
BUCKET = 0.25


class SampleIndex:
    """Samples bucketed on a coarse grid (in a rotated frame) to fetch those near a box quickly."""

    def __init__(self, samples: MeshSamples, rotation: np.ndarray, bucket: float = BUCKET,
                 local: np.ndarray | None = None):
        """`local`: the samples already projected onto the rows of `rotation` (the flight grid's)."""
        local = project(samples.points, rotation) if local is None else local
        self.rotation, self.bucket = rotation, bucket
        self.lo = local.min(axis=0)
        cells = floor_cells(local, self.lo, bucket)
        self.dims = cells.max(axis=0) + 1
        key = np.ravel_multi_index(cells.T, tuple(self.dims))
        self.order = np.argsort(key, kind="stable")
        self.sorted_key = key[self.order]

    def near_box(self, corners: np.ndarray) -> np.ndarray:
        """Indices of samples in buckets overlapping the (rotated-frame) bounds of world `corners`."""
        local = project(np.asarray(corners, np.float64).reshape(-1, 3), self.rotation)
        b0 = np.clip(np.floor((local.min(axis=0) - self.lo) / self.bucket).astype(np.int64), 0, self.dims - 1)
        b1 = np.clip(np.floor((local.max(axis=0) - self.lo) / self.bucket).astype(np.int64), 0, self.dims - 1)
        if np.any(local.max(axis=0) < self.lo) or np.any(b0 > b1):
            return np.zeros(0, np.int64)
        ix, iy = np.meshgrid(np.arange(b0[0], b1[0] + 1), np.arange(b0[1], b1[1] + 1), indexing="ij")
        ix, iy = ix.ravel(), iy.ravel()
        first = np.ravel_multi_index((ix, iy, np.full_like(ix, b0[2])), tuple(self.dims))
        last = np.ravel_multi_index((ix, iy, np.full_like(ix, b1[2])), tuple(self.dims))
        start = np.searchsorted(self.sorted_key, first, side="left")
        stop = np.searchsorted(self.sorted_key, last, side="right")
        lengths = stop - start
        total = int(lengths.sum())
        if total == 0:
            return np.zeros(0, np.int64)
        offsets = np.repeat(start - np.concatenate([[0], np.cumsum(lengths)[:-1]]), lengths)
        return self.order[offsets + np.arange(total)]
