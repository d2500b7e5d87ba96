"""Exact point-to-mesh proximity: is a sphere around each point clear of the mesh?

A mesh vertex closer than r settles a point at once (k-d tree of vertices). Otherwise a triangle
can come within r of p only if |p - c_t| < r + R_t, R_t being its farthest corner from its
centroid c_t. Triangles are grouped by R_t (half of them below the median, ..., the largest
0.1 %), each group in a k-d tree of centroids queried at r plus the group's largest R_t, so a few
large triangles (a wall modelled as two) do not widen the search among the many small ones. Only
the candidates left get the exact point-triangle distance.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from perch_common.mesh import Mesh

RADIUS_GROUPS = (0.5, 0.9, 0.99, 0.999, 1.0)   # upper quantiles of R_t bounding each group
CHUNK_PAIRS = 1 << 20                           # point-triangle pairs tested at once (~100 MB of temporaries)


def point_triangle_distance(points: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """(N,) distance from each point (N,3) to its triangle (N,3,3): to the plane where the point
    projects inside the triangle, else to the nearest edge (so degenerate triangles work too)."""
    p = np.asarray(points, np.float64)
    a, b, c = (np.asarray(triangles[:, i], np.float64) for i in range(3))
    best = np.full(len(p), np.inf)
    for start, end in ((a, b), (b, c), (c, a)):
        edge = end - start
        length2 = np.einsum("ij,ij->i", edge, edge)
        t = np.divide(np.einsum("ij,ij->i", p - start, edge), length2, out=np.zeros_like(length2),
                      where=length2 > 0)
        offset = p - (start + np.clip(t, 0.0, 1.0)[:, None] * edge)
        best = np.minimum(best, np.sqrt(np.einsum("ij,ij->i", offset, offset)))
    normal = np.cross(b - a, c - a)
    area2 = np.einsum("ij,ij->i", normal, normal)
    flat = area2 > 1e-24
    if flat.any():
        n = normal[flat]
        inside = np.ones(len(n), bool)   # the projection is on the inner side of all three edges
        for start, end in ((a, b), (b, c), (c, a)):
            side = np.cross(end[flat] - start[flat], p[flat] - start[flat])
            inside &= np.einsum("ij,ij->i", side, n) >= 0
        plane = np.abs(np.einsum("ij,ij->i", p[flat] - a[flat], n)) / np.sqrt(area2[flat])
        best[flat] = np.where(inside, np.minimum(best[flat], plane), best[flat])
    return best


@dataclass
class _Index:
    """What the queries need of a mesh: its vertex tree, triangle centroids and radii, and the
    centroid trees of the radius groups."""

    vertices: object                       # scipy cKDTree of the vertices
    centres: np.ndarray                    # (F,3)
    radii: np.ndarray                      # (F,) farthest corner from the centroid
    groups: list[tuple[object, np.ndarray, float]]   # (tree of centroids, face indices, largest radius)


def _index(mesh: Mesh) -> _Index:
    from scipy.spatial import cKDTree

    triangles = mesh.triangles()
    centres = triangles.mean(axis=1)
    offsets = triangles - centres[:, None]
    radii = np.sqrt(np.einsum("fkj,fkj->fk", offsets, offsets).max(axis=1))
    order = np.argsort(radii, kind="stable")
    bounds = np.unique(np.ceil(np.asarray(RADIUS_GROUPS) * len(order)).astype(np.int64))
    groups = []
    for first, last in zip(np.concatenate([[0], bounds[:-1]]), bounds):
        faces = order[first:last]
        if len(faces):
            groups.append((cKDTree(centres[faces], balanced_tree=False, compact_nodes=False), faces, float(radii[faces[-1]])))
    return _Index(cKDTree(mesh.vertices, balanced_tree=False, compact_nodes=False), centres, radii, groups)


def clear_of_mesh(mesh: Mesh, points: np.ndarray, radius: float) -> np.ndarray:
    """(N,) True where no point of the mesh is closer than `radius` to the point (exact, float64).

    The index (k-d trees, centroids and radii: ~100 B a face) is kept with the mesh (Mesh.derived)."""
    points = np.asarray(points, np.float64).reshape(-1, 3)
    clear = np.ones(len(points), bool)
    if len(points) == 0 or mesh.num_faces == 0:
        return clear
    index = mesh.derived("proximity_index", lambda: _index(mesh))
    nearest_vertex, _ = index.vertices.query(points, distance_upper_bound=radius)
    clear &= ~(nearest_vertex < radius)   # a vertex is a point of the mesh
    open_ = np.flatnonzero(clear)
    rows, faces = [], []
    for tree, members, largest in index.groups:
        near = tree.query_ball_point(points[open_], radius + largest, return_sorted=False)
        counts = np.fromiter((len(n) for n in near), np.int64, len(near))
        if counts.sum():
            rows.append(np.repeat(open_, counts))
            faces.append(members[np.concatenate(near).astype(np.int64)])
    if not rows:
        return clear
    rows, faces = np.concatenate(rows), np.concatenate(faces)
    possible = np.linalg.norm(points[rows] - index.centres[faces], axis=1) - index.radii[faces] < radius
    rows, faces = rows[possible], faces[possible]
    for start in range(0, len(rows), CHUNK_PAIRS):
        r, f = rows[start:start + CHUNK_PAIRS], faces[start:start + CHUNK_PAIRS]
        clear[r[point_triangle_distance(points[r], mesh.vertices[mesh.faces[f]]) < radius]] = False
    return clear
