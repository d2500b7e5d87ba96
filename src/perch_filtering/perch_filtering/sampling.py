"""Dense point samples of a mesh's surface: the 'other geometry' the filters test against."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from perch_common.mesh import Mesh

MAX_SPLITS = 64  # a single triangle is never split into more than 64 x 64 pieces


@dataclass
class MeshSamples:
    """Points on the mesh no further than `spacing` from any surface point, with their face."""

    points: np.ndarray  # (N,3)
    face: np.ndarray    # (N,) face the point lies on
    spacing: float


def sample_mesh(mesh: Mesh, spacing: float) -> MeshSamples:
    """All vertices plus a barycentric lattice on every face with an edge longer than `spacing`."""
    tris = mesh.triangles()
    edges = np.linalg.norm(tris - np.roll(tris, 1, axis=1), axis=2).max(axis=1)
    splits = np.clip(np.ceil(edges / spacing), 1, MAX_SPLITS).astype(np.int64)
    vertex_face = np.zeros(mesh.num_vertices, np.int64)
    vertex_face[mesh.faces.ravel()] = np.repeat(np.arange(mesh.num_faces), 3)
    points, faces = [mesh.vertices], [vertex_face]
    for k in np.unique(splits[splits > 1]):
        members = np.flatnonzero(splits == k)
        weights = _lattice(int(k))
        points.append(np.einsum("wc,fcd->fwd", weights, tris[members]).reshape(-1, 3))
        faces.append(np.repeat(members, len(weights)))
    return MeshSamples(np.concatenate(points), np.concatenate(faces), float(spacing))


def _lattice(k: int) -> np.ndarray:
    """Barycentric weights of the k-split lattice of a triangle, corners excluded."""
    i, j = np.meshgrid(np.arange(k + 1), np.arange(k + 1), indexing="ij")
    keep = (i + j) <= k
    i, j = i[keep], j[keep]
    w = np.stack([k - i - j, i, j], axis=1) / k
    corner = (w.max(axis=1) > 1 - 1e-9)
    return w[~corner]


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


class SampleIndex:
    """Samples bucketed on a coarse grid (in a rotated frame) to fetch those near a box quickly."""

    def __init__(self, samples: MeshSamples, rotation: np.ndarray, bucket: float = 0.5):
        local = project(samples.points, rotation)
        self.rotation, self.bucket = rotation, bucket
        self.lo = local.min(axis=0)
        cells = np.floor((local - self.lo) / bucket).astype(np.int64)
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
