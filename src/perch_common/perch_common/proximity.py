"""Exact point-to-mesh proximity: is a sphere around each point clear of the mesh?

Every triangle is sampled on a barycentric grid fine enough that each of its points lies within
`spacing` of one of its own grid points (corners included); the samples (the mesh's vertices and
those grid points) go into one k-d tree. For a point p whose nearest sample is at distance d:
  d < r            a point of the mesh is closer than r: not clear;
  d >= r + spacing every point of the mesh is at least d - spacing >= r away: clear;
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

SAMPLE_SPACING = 0.05     # m: band of points that need the exact test; samples ~ 2 x area / spacing^2
RADIUS_BANDS = (0.5, 0.9, 0.99, 0.999, 1.0)   # upper quantiles of R_t bounding each band of triangles
CHUNK_SAMPLES = 1 << 21   # samples generated at once (~50 MB of temporaries)
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


def _barycentric_grid(steps: int) -> np.ndarray:
    """(K,2) barycentric (u, v) of the grid with `steps` intervals per edge, corners excluded."""
    i, j = np.meshgrid(np.arange(steps + 1), np.arange(steps + 1), indexing="ij")
    corner = ((i == 0) | (i == steps)) & ((j == 0) | (j == steps))
    keep = (i + j <= steps) & ~corner
    return np.column_stack([i[keep], j[keep]]) / steps


@dataclass
class _Bands:
    """Triangle centroids and radii, and the centroid trees of the radius bands (the exact test's
    candidates)."""

    centres: np.ndarray                              # (F,3)
    radii: np.ndarray                                # (F,) farthest corner from the centroid
    trees: list[tuple[object, np.ndarray, float]]    # (tree of centroids, face indices, largest radius)


def _samples(mesh: Mesh, spacing: float):
    """k-d tree of the vertices and the grid points of the triangles longer than `spacing`."""
    from scipy.spatial import cKDTree

    corners = mesh.vertices[mesh.faces]                                      # (F,3,3)
    edges = np.linalg.norm(corners - np.roll(corners, 1, axis=1), axis=2).max(axis=1)
    # Grid cells have edges of at most longest_edge / steps <= spacing, and no point of a cell is
    # farther from its nearest corner than the cell's longest edge.
    steps = np.maximum(1, np.ceil(edges / spacing)).astype(np.int64)
    points = [mesh.vertices]
    for count in np.unique(steps[steps > 1]):
        faces = np.flatnonzero(steps == count)
        grid = _barycentric_grid(int(count))
        chunk = max(1, CHUNK_SAMPLES // len(grid))
        for start in range(0, len(faces), chunk):
            a, b, c = (corners[faces[start:start + chunk], k] for k in range(3))
            points.append((a[:, None] + grid[None, :, :1] * (b - a)[:, None] + grid[None, :, 1:] * (c - a)[:, None])
                          .reshape(-1, 3))
    return cKDTree(np.concatenate(points), balanced_tree=False, compact_nodes=False)


def _bands(mesh: Mesh) -> _Bands:
    from scipy.spatial import cKDTree

    corners = mesh.vertices[mesh.faces]
    centres = corners.mean(axis=1)
    offsets = corners - centres[:, None]
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

    What it builds is kept with the mesh (Mesh.derived): the samples' tree (~60 B a sample: the
    vertices and ~2 x area / spacing^2 more), the centroid trees once a point needs the exact test
    (~100 B a face), or, for `large_query` points and more, Open3D's scene."""
    points = np.asarray(points, np.float64).reshape(-1, 3)
    clear = np.ones(len(points), bool)
    if len(points) == 0 or mesh.num_faces == 0:
        return clear
    if len(points) >= large_query:
        # Open3D's BVH answers a closest-point query in ~1 us against the tree's ~5: for this many
        # points its import (0.45 s, once per process) costs less than the queries it saves.
        from perch_common.raycast import ray_scene

        return ray_scene(mesh).closest_points(points)[2] >= radius
    samples = mesh.derived(f"proximity_samples_{spacing:g}", lambda: _samples(mesh, spacing))
    nearest, _ = samples.query(points, distance_upper_bound=radius + spacing, workers=-1)
    clear[nearest < radius] = False
    unsure = np.flatnonzero((nearest >= radius) & (nearest < radius + spacing))
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
