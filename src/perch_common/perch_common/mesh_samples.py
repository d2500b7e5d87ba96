"""Dense point samples of a mesh's surface: every vertex, plus a barycentric lattice on each face
with an edge longer than the spacing. The filter tests its perches against them ('other
geometry', flight grid) and the clearance test (perch_common.proximity) bounds distances by them."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from perch_common.mesh import Mesh
from perch_common.threads import side_by_side

MAX_SPLITS = 64  # a single triangle is never split into more than 64 x 64 pieces


@dataclass
class MeshSamples:
    """Points on the mesh, with their face; every point of the mesh lies within `reach` of a
    sample of its own face (`spacing`, or more on a face longer than MAX_SPLITS x spacing)."""

    points: np.ndarray  # (N,3)
    face: np.ndarray    # (N,) face the point lies on
    spacing: float
    reach: float

    @property
    def nbytes(self) -> int:
        """What a mesh cache counts when the samples are kept with their mesh."""
        return self.points.nbytes + self.face.nbytes


def sample_mesh(mesh: Mesh, spacing: float) -> MeshSamples:
    """All vertices plus a barycentric lattice on every face with an edge longer than `spacing`."""
    tris = mesh.triangles()
    edges = np.linalg.norm(tris - np.roll(tris, 1, axis=1), axis=2).max(axis=1)
    splits = np.clip(np.ceil(edges / spacing), 1, MAX_SPLITS).astype(np.int64)
    vertex_face = np.zeros(mesh.num_vertices, np.int64)
    vertex_face[mesh.faces.ravel()] = np.repeat(np.arange(mesh.num_faces), 3)
    # The vertices, then each split count's lattices (ascending), written in place into one array.
    levels = [(np.flatnonzero(splits == k), _lattice(int(k))) for k in np.unique(splits[splits > 1])]
    ends = np.cumsum([mesh.num_vertices] + [len(members) * len(weights) for members, weights in levels])
    points, faces = np.empty((int(ends[-1]), 3)), np.empty(int(ends[-1]), np.int64)
    points[:ends[0]], faces[:ends[0]] = mesh.vertices, vertex_face

    def fill(which: list[int]) -> None:
        for i in which:
            members, weights = levels[i]
            part = slice(ends[i], ends[i + 1])
            _lattice_points(weights, tris[members], points[part].reshape(len(members), len(weights), 3))
            faces[part] = np.repeat(members, len(weights))

    # Two halves of the points side by side (numpy releases the GIL): a building's 3.1 M in 0.2 s, not 0.4.
    halves: tuple[list[int], list[int]] = ([], [])
    held = [0, 0]
    for i in np.argsort(-np.diff(ends), kind="stable"):
        lighter = int(held[1] < held[0])
        halves[lighter].append(int(i))
        held[lighter] += int(ends[i + 1] - ends[i])
    side_by_side(*(lambda half=half: fill(half) for half in halves if half))
    # A lattice cell's edges are at most longest_edge / splits, and no point of a cell is farther
    # from its nearest corner than the cell's longest edge.
    reach = float((edges / splits).max()) if len(edges) else 0.0
    return MeshSamples(points, faces, float(spacing), reach)


def _lattice_points(weights: np.ndarray, tris: np.ndarray, out: np.ndarray) -> None:
    """out (F, W, 3) = the barycentric `weights` (W, 3) of each of `tris` (F, 3, 3): corner by corner,
    in corner order (what np.einsum("wc,fcd->fwd") computes, bit for bit, in 60 % of its time)."""
    np.multiply(weights[None, :, 0, None], tris[:, None, 0, :], out=out)
    out += weights[None, :, 1, None] * tris[:, None, 1, :]
    out += weights[None, :, 2, None] * tris[:, None, 2, :]


def mesh_samples(mesh: Mesh, spacing: float) -> MeshSamples:
    """sample_mesh, once per mesh and spacing (kept with the mesh: Mesh.derived; read-only, as shared)."""
    def build() -> MeshSamples:
        samples = sample_mesh(mesh, spacing)
        samples.points.flags.writeable = samples.face.flags.writeable = False
        return samples

    return mesh.derived(f"samples_{spacing:g}", build)


def _lattice(k: int) -> np.ndarray:
    """Barycentric weights of the k-split lattice of a triangle, corners excluded."""
    i, j = np.meshgrid(np.arange(k + 1), np.arange(k + 1), indexing="ij")
    keep = (i + j) <= k
    i, j = i[keep], j[keep]
    w = np.stack([k - i - j, i, j], axis=1) / k
    corner = (w.max(axis=1) > 1 - 1e-9)
    return w[~corner]
