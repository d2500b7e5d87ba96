"""Vectorised mesh clean-up steps (numpy/scipy): vertex welding, small pieces, vertex clustering."""

from __future__ import annotations

import numpy as np

from perch_common.mesh import Mesh, column_bounds


def _remap(mesh: Mesh, inverse: np.ndarray, count: int, average: bool) -> Mesh:
    """Mesh whose vertex i becomes new vertex inverse[i]; degenerate and duplicate faces dropped."""
    weights = np.bincount(inverse, minlength=count).astype(np.float64)
    if average:
        vertices = np.column_stack([np.bincount(inverse, mesh.vertices[:, i], count) for i in range(3)])
        vertices /= weights[:, None]
    else:
        first = np.full(count, -1, np.int64)
        first[inverse[::-1]] = np.arange(len(inverse))[::-1]
        vertices = mesh.vertices[first]
    colors = None
    if mesh.vertex_colors is not None:
        sums = np.column_stack([np.bincount(inverse, mesh.vertex_colors[:, i].astype(np.float64), count)
                                for i in range(3)])
        colors = np.clip(np.round(sums / weights[:, None]), 0, 255).astype(np.uint8)
    return _remap_faces(Mesh(vertices, mesh.faces, colors, frame_id=mesh.frame_id), inverse[mesh.faces])


def _remap_faces(mesh: Mesh, faces: np.ndarray) -> Mesh:
    """`mesh` with `faces` (indices into its vertices) less degenerate and duplicate ones, unused vertices dropped."""
    count = mesh.num_vertices
    keep = (faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 0] != faces[:, 2])
    faces = faces[keep]
    ordered = np.sort(faces, axis=1)
    key = (ordered[:, 0] * count + ordered[:, 1]) * count + ordered[:, 2] if count < 2 ** 21 else None
    if key is None:
        _, first_face = np.unique(ordered, axis=0, return_index=True)
    else:
        _, first_face = np.unique(key, return_index=True)
    if len(first_face) == len(faces) and keep.all() and faces is mesh.faces:
        return _drop_unused(mesh)
    faces = faces[np.sort(first_face)]
    return _drop_unused(Mesh(mesh.vertices, faces, mesh.vertex_colors, mesh.vertex_normals, frame_id=mesh.frame_id))


def _drop_unused(mesh: Mesh) -> Mesh:
    used = np.zeros(mesh.num_vertices, bool)
    used[mesh.faces.ravel()] = True
    if used.all():
        return mesh
    index = np.cumsum(used) - 1
    return Mesh(mesh.vertices[used], index[mesh.faces],
                None if mesh.vertex_colors is None else mesh.vertex_colors[used], frame_id=mesh.frame_id)


def _cells(points: np.ndarray, cell: float) -> tuple[np.ndarray, int]:
    key = np.floor((points - column_bounds(points)[0]) / cell).astype(np.int64)
    span = column_bounds(key)[1] + 1
    linear = (key[:, 0] * span[1] + key[:, 1]) * span[2] + key[:, 2]
    unique, first, inverse = np.unique(linear, return_index=True, return_inverse=True)
    inverse = inverse.ravel()
    if len(unique) == len(points):   # one point per cell: numbered by first point, that is as given
        return np.arange(len(points)), len(points)
    # Number the cells by their first point, not by position: the output keeps the input's order,
    # so the same mesh in another orientation (other cell keys) comes out in the same order.
    rank = np.empty(len(unique), np.int64)
    rank[np.argsort(first)] = np.arange(len(unique))
    return rank[inverse], len(unique)


def weld_vertices(mesh: Mesh, distance: float) -> Mesh:
    """Merge vertices falling in the same `distance` cell (duplicates from block seams, STL soups)."""
    inverse, count = _cells(mesh.vertices, max(distance, 1e-12))
    if count == mesh.num_vertices:   # nothing to merge: only degenerate and duplicate faces can go
        # Same arrays: per-face geometry already computed (validation) stays valid.
        same = Mesh(mesh.vertices, mesh.faces, mesh.vertex_colors, frame_id=mesh.frame_id, _cache=mesh._cache)
        return _remap_faces(same, mesh.faces)
    return _remap(mesh, inverse, count, average=False)


def weld_close_vertices(mesh: Mesh, distance: float) -> Mesh:
    """Merge vertices closer than `distance` to one another (chains included), wherever they lie:
    a grid (weld_vertices) splits near-coincident corners that straddle a cell border, which the
    jittered corners of an exported triangle soup do at any cell size."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    pairs = cKDTree(mesh.vertices).query_pairs(distance, output_type="ndarray")
    n = mesh.num_vertices
    graph = coo_matrix((np.ones(len(pairs), np.int8), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    count, label = connected_components(graph, directed=False)
    # Number the clusters by their first vertex: the output keeps the input's order.
    first = np.full(count, n, np.int64)
    np.minimum.at(first, label, np.arange(n))
    rank = np.empty(count, np.int64)
    rank[np.argsort(first)] = np.arange(count)
    return _remap(mesh, rank[label], count, average=False)


def remove_small_pieces(mesh: Mesh, min_diameter: float) -> tuple[Mesh, int]:
    """Drop connected pieces whose bounding-box diagonal is below min_diameter; returns (mesh, faces removed)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    n = mesh.num_vertices
    f = mesh.faces
    rows = np.concatenate([f[:, 0], f[:, 1]])
    cols = np.concatenate([f[:, 1], f[:, 2]])
    graph = coo_matrix((np.ones(len(rows), np.int8), (rows, cols)), shape=(n, n))
    count, label = connected_components(graph, directed=False)
    if count == 1:
        lo, hi = column_bounds(mesh.vertices)
        big = np.array([np.linalg.norm(hi - lo) >= min_diameter])
    else:  # each piece's bounding box: its vertices sorted together, then one reduction per piece
        order = np.argsort(label, kind="stable")
        starts = np.searchsorted(label[order], np.arange(count))
        ordered = mesh.vertices[order]
        lo, hi = np.minimum.reduceat(ordered, starts), np.maximum.reduceat(ordered, starts)
        big = np.linalg.norm(hi - lo, axis=1) >= min_diameter
    keep = big[label[f[:, 0]]]
    removed = int((~keep).sum())
    return (mesh if removed == 0 else mesh.submesh(keep)), removed


def cluster_vertices(mesh: Mesh, target_faces: int) -> Mesh:
    """Vertex clustering on a grid sized so roughly target_faces remain (fast coarse decimation)."""
    area = float(mesh.face_areas().sum())
    cell = np.sqrt(2.0 * area / max(target_faces, 1))  # a grid of cell c triangulates to ~2 A / c^2 faces
    inverse, count = _cells(mesh.vertices, cell)
    return _remap(mesh, inverse, count, average=True)
