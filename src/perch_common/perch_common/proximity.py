"""Exact point-to-mesh proximity: is a sphere around each point clear of the mesh?

The mesh's surface samples (perch_common.mesh_samples: its vertices and a lattice on its larger
faces, every point of the mesh within `reach` of one) go into a k-d tree. For a point p whose
nearest sample is at distance d:
  d < r            a point of the mesh is closer than r: not clear;
  d >= r + reach   every point of the mesh is at least d - reach >= r away: clear;
  otherwise        the exact point-triangle distance decides, against the triangles whose bounding
                   ball (centroid, farthest corner R_t) reaches within r: |p - c_t| < r + R_t. These
                   come from k-d trees of centroids, one per band of R_t (half the triangles below
                   the median, ..., the largest 0.1 %), each searched at r plus its band's largest
                   R_t, so a few metre-sized triangles (a decimated wall) do not widen every search.
One nearest-sample query settles nearly every point; no candidate lists are built for them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from perch_common.mesh import Mesh
from perch_common.mesh_samples import mesh_samples

SAMPLE_SPACING = 0.05     # m: band of points that need the exact test; samples ~ 2 x area / spacing^2
RADIUS_BANDS = (0.5, 0.9, 0.99, 0.999, 1.0)   # upper quantiles of R_t bounding each band of triangles
CHUNK_PAIRS = 1 << 20     # point-triangle pairs tested at once (~100 MB of temporaries)
LARGE_QUERY = 100_000     # points from which Open3D's closest points are asked instead (see clear_of_mesh)


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
class _Bands:
    """Triangle centroids and radii, and the centroid trees of the radius bands (the exact test's
    candidates)."""

    centres: np.ndarray                              # (F,3)
    radii: np.ndarray                                # (F,) farthest corner from the centroid
    trees: list[tuple[object, np.ndarray, float]]    # (tree of centroids, face indices, largest radius)

    @property
    def nbytes(self) -> int:
        """What a mesh cache counts when the bands are kept with their mesh."""
        trees = sum(tree.data.nbytes + tree.indices.nbytes for tree, _, _ in self.trees)
        return self.centres.nbytes + self.radii.nbytes + trees


@dataclass
class _SampleTree:
    """The surface samples in a k-d tree, and how far any point of the mesh is from one."""

    tree: object    # scipy cKDTree
    reach: float

    @property
    def nbytes(self) -> int:
        """What a mesh cache counts when the tree is kept with its mesh."""
        return self.tree.data.nbytes + self.tree.indices.nbytes


def _sample_tree(mesh: Mesh, spacing: float) -> _SampleTree:
    from scipy.spatial import cKDTree

    samples = mesh_samples(mesh, spacing)
    return _SampleTree(cKDTree(samples.points, balanced_tree=False, compact_nodes=False), samples.reach)


def _bands(mesh: Mesh) -> _Bands:
    from scipy.spatial import cKDTree

    centres = mesh.face_centroids()
    offsets = mesh.triangles() - centres[:, None]
    radii = np.sqrt(np.einsum("fkj,fkj->fk", offsets, offsets).max(axis=1))
    order = np.argsort(radii, kind="stable")
    trees = []
    bounds = np.unique(np.ceil(np.asarray(RADIUS_BANDS) * len(order)).astype(np.int64))
    for first, last in zip(np.concatenate([[0], bounds[:-1]]), bounds):
        members = order[first:last]
        if len(members):
            trees.append((cKDTree(centres[members], balanced_tree=False, compact_nodes=False), members,
                          float(radii[members[-1]])))
    return _Bands(centres, radii, trees)


def clear_of_mesh(mesh: Mesh, points: np.ndarray, radius: float, spacing: float = SAMPLE_SPACING,
                  large_query: int = LARGE_QUERY) -> np.ndarray:
    """(N,) True where no point of the mesh is closer than `radius` to the point (exact: in float64,
    or in Open3D's float32 from `large_query` points on).

    What it builds is kept with the mesh (Mesh.derived): the surface samples at `spacing` (the
    filter's, when it asks with its own spacing) and their tree (~60 B a sample: the vertices and
    ~2 x area / spacing^2 more), the centroid trees once a point needs the exact test (~100 B a
    face), or, for `large_query` points and more, Open3D's scene."""
    points = np.asarray(points, np.float64).reshape(-1, 3)
    clear = np.ones(len(points), bool)
    if len(points) == 0 or mesh.num_faces == 0:
        return clear
    if len(points) >= large_query:
        # Open3D's BVH answers a closest-point query in ~1 us against the tree's ~5: for this many
        # points its import (0.45 s, once per process) costs less than the queries it saves.
        from perch_common.raycast import ray_scene

        return ray_scene(mesh).closest_points(points)[2] >= radius
    samples = mesh.derived(f"sample_tree_{spacing:g}", lambda: _sample_tree(mesh, spacing))
    nearest, _ = samples.tree.query(points, distance_upper_bound=radius + samples.reach, workers=-1)
    clear[nearest < radius] = False
    unsure = np.flatnonzero((nearest >= radius) & (nearest < radius + samples.reach))
    if len(unsure) == 0:
        return clear
    bands = mesh.derived("proximity_bands", lambda: _bands(mesh))
    rows, faces = [], []
    for tree, members, largest in bands.trees:
        near = tree.query_ball_point(points[unsure], radius + largest, return_sorted=False, workers=-1)
        rows.append(np.repeat(unsure, np.fromiter((len(n) for n in near), np.int64, len(near))))
        faces.append(members[np.concatenate(near).astype(np.int64)] if rows[-1].size else np.zeros(0, np.int64))
    rows, faces = np.concatenate(rows), np.concatenate(faces)
    reach = np.linalg.norm(points[rows] - bands.centres[faces], axis=1) - bands.radii[faces] < radius
    rows, faces = rows[reach], faces[reach]
    for start in range(0, len(rows), CHUNK_PAIRS):
        r, f = rows[start:start + CHUNK_PAIRS], faces[start:start + CHUNK_PAIRS]
        clear[r[point_triangle_distance(points[r], mesh.vertices[mesh.faces[f]]) < radius]] = False
    return clear
