"""Exact point-to-mesh proximity: is a sphere around each point clear of the mesh?

Every triangle is sampled on a barycentric grid fine enough that each of its points lies within
`spacing` of one of its own samples (corners included), and the samples go into one k-d tree with
the triangle each belongs to. For a point p whose nearest sample is at distance d:
  d < r            a point of the mesh is closer than r: not clear;
  d >= r + spacing every point of the mesh is at least d - spacing >= r away: clear;
  otherwise        a triangle closer than r has a sample within r + spacing: only the triangles
                   owning such samples get the exact point-triangle distance.
The first two settle nearly every point with one nearest-neighbour query; no candidate lists are
built for them, however large the mesh's triangles (a decimated wall is a few metre-sized ones).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from perch_common.mesh import Mesh

SAMPLE_SPACING = 0.05     # m: band of points that need the exact test; samples ~ 2 x area / spacing^2
CHUNK_SAMPLES = 1 << 21   # samples generated at once (~50 MB of temporaries)


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
class _Samples:
    """Points on the mesh: its vertices, then grid points of the triangles larger than `spacing`
    (each point of a triangle is within `spacing` of a corner or grid point of its own), in a
    k-d tree; which triangles each sample lies on."""

    tree: object                  # scipy cKDTree of the samples
    vertex_count: int             # samples [0, V) are the vertices
    owner: np.ndarray             # (S - V,) face of each grid point
    faces_of_vertex: tuple[np.ndarray, np.ndarray]   # CSR: offsets (V+1,), faces
    spacing: float


def _samples(mesh: Mesh, spacing: float) -> _Samples:
    from scipy.spatial import cKDTree

    corners = mesh.vertices[mesh.faces]                                      # (F,3,3)
    edges = np.linalg.norm(corners - np.roll(corners, 1, axis=1), axis=2).max(axis=1)
    # Grid cells have edges of at most longest_edge / steps <= spacing, and no point of a cell is
    # farther from its nearest corner than the cell's longest edge.
    steps = np.maximum(1, np.ceil(edges / spacing)).astype(np.int64)
    points, owners = [mesh.vertices], [np.zeros(0, np.int64)]
    for count in np.unique(steps[steps > 1]):
        faces = np.flatnonzero(steps == count)
        grid = _barycentric_grid(int(count))
        chunk = max(1, CHUNK_SAMPLES // len(grid))
        for start in range(0, len(faces), chunk):
            chosen = faces[start:start + chunk]
            a, b, c = corners[chosen, 0], corners[chosen, 1], corners[chosen, 2]
            points.append((a[:, None] + grid[None, :, :1] * (b - a)[:, None] + grid[None, :, 1:] * (c - a)[:, None])
                          .reshape(-1, 3))
            owners.append(np.repeat(chosen, len(grid)))
    order = np.argsort(mesh.faces.ravel(), kind="stable")
    offsets = np.searchsorted(mesh.faces.ravel()[order], np.arange(mesh.num_vertices + 1))
    return _Samples(cKDTree(np.concatenate(points), balanced_tree=False, compact_nodes=False), mesh.num_vertices,
                    np.concatenate(owners), (offsets, order // 3), spacing)


def clear_of_mesh(mesh: Mesh, points: np.ndarray, radius: float, spacing: float = SAMPLE_SPACING) -> np.ndarray:
    """(N,) True where no point of the mesh is closer than `radius` to the point (exact, float64).

    The samples' tree (~60 B a sample: the vertices and ~2 x area / spacing^2 more) is kept with
    the mesh (Mesh.derived)."""
    points = np.asarray(points, np.float64).reshape(-1, 3)
    clear = np.ones(len(points), bool)
    if len(points) == 0 or mesh.num_faces == 0:
        return clear
    index = mesh.derived(f"proximity_samples_{spacing:g}", lambda: _samples(mesh, spacing))
    nearest, _ = index.tree.query(points, distance_upper_bound=radius + index.spacing)
    clear[nearest < radius] = False
    unsure = np.flatnonzero((nearest >= radius) & (nearest < radius + index.spacing))
    if len(unsure) == 0:
        return clear
    near = index.tree.query_ball_point(points[unsure], radius + index.spacing, return_sorted=False)
    rows = np.repeat(unsure, np.fromiter((len(n) for n in near), np.int64, len(near)))
    samples = np.concatenate(near).astype(np.int64)
    # A triangle closer than r has a corner or grid point within r + spacing: its vertices name
    # the triangles around them, its grid points their own triangle.
    grid = samples >= index.vertex_count
    offsets, around = index.faces_of_vertex
    corner_rows, corner_vertices = rows[~grid], samples[~grid]
    counts = offsets[corner_vertices + 1] - offsets[corner_vertices]
    starts = np.repeat(offsets[corner_vertices] - np.cumsum(counts) + counts, counts)
    corner_faces = around[starts + np.arange(counts.sum())]
    keys = np.unique(np.concatenate([np.repeat(corner_rows, counts), rows[grid]]) * mesh.num_faces
                     + np.concatenate([corner_faces, index.owner[samples[grid] - index.vertex_count]]))
    pair_rows, pair_faces = np.divmod(keys, mesh.num_faces)   # each (point, triangle) pair once
    hit = point_triangle_distance(points[pair_rows], mesh.vertices[mesh.faces[pair_faces]]) < radius
    clear[pair_rows[hit]] = False
    return clear
