"""Dense point samples of a mesh's surface: every vertex, plus a barycentric lattice on each face
with an edge longer than the spacing. The filter tests its perches against them ('other
geometry', flight grid) and the clearance test (perch_common.proximity) bounds distances by them."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from perch_common.mesh import Mesh

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
    points, faces = [mesh.vertices], [vertex_face]
    for k in np.unique(splits[splits > 1]):
        members = np.flatnonzero(splits == k)
        weights = _lattice(int(k))
        points.append(np.einsum("wc,fcd->fwd", weights, tris[members]).reshape(-1, 3))
        faces.append(np.repeat(members, len(weights)))
    # A lattice cell's edges are at most longest_edge / splits, and no point of a cell is farther
    # from its nearest corner than the cell's longest edge.
    reach = float((edges / splits).max()) if len(edges) else 0.0
    return MeshSamples(np.concatenate(points), np.concatenate(faces), float(spacing), reach)


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
