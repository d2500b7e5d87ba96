"""Vectorised mesh clean-up steps (numpy/scipy): vertex welding, small pieces, vertex clustering."""

from __future__ import annotations

import numpy as np

from perch_common.mesh import FACE_BLOCK, ORDERED_SORT, Mesh, column_bounds

# Below this many vertices a face's three sorted indices fit one int64 key exactly.
EXACT_FACE_KEY_VERTICES = 2 ** 21


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
    # The faces renumbered, those left without area dropped at once (block by block: most faces of a
    # clustered mesh go, and a face-sized copy of them all costs more than the rest of the remap).
    kept = []
    for start in range(0, mesh.num_faces, FACE_BLOCK):
        faces = inverse[mesh.faces[start:start + FACE_BLOCK]]
        kept.append(faces[(faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 0] != faces[:, 2])])
    faces = np.concatenate(kept) if kept else np.zeros((0, 3), np.int64)
    return _remap_faces(Mesh(vertices, mesh.faces, colors, frame_id=mesh.frame_id), faces)


def _remap_faces(mesh: Mesh, faces: np.ndarray) -> Mesh:
    """`mesh` with `faces` (indices into its vertices) less degenerate and duplicate ones, unused vertices dropped."""
    count = mesh.num_vertices
    keep = (faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 0] != faces[:, 2])
    if keep.all() and _all_distinct(faces, count):
        # Nothing to drop (the usual case): the faces as they are; the same arrays keep the per-face
        # data derived from them (validation's cross products) valid.
        shared = mesh._cache if faces is mesh.faces else {}
        return _drop_unused(Mesh(mesh.vertices, faces, mesh.vertex_colors, mesh.vertex_normals,
                                 frame_id=mesh.frame_id, _cache=shared))
    faces = faces[keep]
    ordered = np.sort(faces, axis=1)
    if count < EXACT_FACE_KEY_VERTICES:
        first_face = _first_occurrences((ordered[:, 0] * count + ordered[:, 1]) * count + ordered[:, 2])
    else:
        first_face = np.sort(np.unique(ordered, axis=0, return_index=True)[1])
    faces = faces[first_face]
    return _drop_unused(Mesh(mesh.vertices, faces, mesh.vertex_colors, mesh.vertex_normals, frame_id=mesh.frame_id))


def _all_distinct(faces: np.ndarray, count: int) -> bool:
    """Whether no two faces have the same three vertices (in any order), from one sort of one key per
    face: exact below EXACT_FACE_KEY_VERTICES; above, a hash whose keys all differ only when the faces do
    (equal keys: False, and the caller's exact test decides)."""
    exact = count < EXACT_FACE_KEY_VERTICES
    key = np.empty(len(faces), np.int64 if exact else np.uint64)
    for start in range(0, len(faces), FACE_BLOCK):   # block by block: no face-sized temporaries
        block = faces[start:start + FACE_BLOCK]
        a, b, c = block[:, 0], block[:, 1], block[:, 2]
        low, high = np.minimum(np.minimum(a, b), c), np.maximum(np.maximum(a, b), c)
        middle = a + b + c - low - high
        if exact:
            key[start:start + FACE_BLOCK] = (low * count + middle) * count + high
        else:   # wraps modulo 2^64 (unsigned): a hash
            key[start:start + FACE_BLOCK] = ((low * count + middle).astype(np.uint64) * np.uint64(0x9E3779B97F4A7C15)
                                             + high.astype(np.uint64))
    key.sort(kind=ORDERED_SORT)
    return not (key[1:] == key[:-1]).any()


def _first_occurrences(key: np.ndarray) -> np.ndarray:
    """Ascending indices of the first occurrence of each distinct key: np.unique(key, return_index=True)[1]
    sorted (each key's least index, whatever order the sort leaves equal keys in)."""
    order = np.argsort(key, kind=ORDERED_SORT)
    ordered = key[order]
    starts = np.flatnonzero(np.concatenate([[True], ordered[1:] != ordered[:-1]]))
    first = np.minimum.reduceat(order, starts) if len(key) else order
    first.sort()
    return first


def _drop_unused(mesh: Mesh) -> Mesh:
    used = np.zeros(mesh.num_vertices, bool)
    used[mesh.faces.ravel()] = True
    if used.all():
        return mesh
    index = np.cumsum(used) - 1
    return Mesh(mesh.vertices[used], index[mesh.faces],
                None if mesh.vertex_colors is None else mesh.vertex_colors[used], frame_id=mesh.frame_id)


def _cell_keys(points: np.ndarray, cell: float) -> np.ndarray:
    """One int64 per point naming its grid cell of size `cell`."""
    lo = column_bounds(points)[0]
    # column by column: a third of the (N,3) temporaries' time
    key = [np.floor((points[:, i] - lo[i]) / cell).astype(np.int64) for i in range(3)]
    span = [int(k.max()) + 1 if len(k) else 1 for k in key]
    linear = key[0] * span[1]
    linear += key[1]
    linear *= span[2]
    linear += key[2]
    return linear


def _cells(points: np.ndarray, cell: float, linear: np.ndarray | None = None) -> tuple[np.ndarray, int]:
    """(cell number of each point, cells); `linear`: the points' _cell_keys when already made."""
    linear = _cell_keys(points, cell) if linear is None else linear
    # np.unique(linear, return_index=True, return_inverse=True), whatever order the sort leaves equal keys in
    order = np.argsort(linear, kind=ORDERED_SORT)
    ordered = linear[order]
    new = np.empty(len(points), bool)
    new[:1] = True
    np.not_equal(ordered[1:], ordered[:-1], out=new[1:])
    starts = np.flatnonzero(new)
    if len(starts) == len(points):   # one point per cell: numbered by first point, that is as given
        return np.arange(len(points)), len(points)
    first = np.minimum.reduceat(order, starts)   # each cell's first point
    # Number the cells by their first point, not by position: the output keeps the input's order,
    # so the same mesh in another orientation (other cell keys) comes out in the same order.
    rank = np.empty(len(starts), np.int64)
    rank[np.argsort(first)] = np.arange(len(starts))
    inverse = np.empty(len(points), np.int64)
    inverse[order] = rank[np.cumsum(new) - 1]
    return inverse, len(starts)


def weld_vertices(mesh: Mesh, distance: float) -> Mesh:
    """Merge vertices falling in the same `distance` cell (duplicates from block seams, STL soups)."""
    linear = _cell_keys(mesh.vertices, max(distance, 1e-12))
    ordered = np.sort(linear, kind=ORDERED_SORT)   # a third of _cells' time: enough to see that every vertex has its own cell
    if not (ordered[1:] == ordered[:-1]).any():   # nothing to merge: only degenerate and duplicate faces can go
        # Same arrays: per-face geometry already computed (validation) stays valid.
        same = Mesh(mesh.vertices, mesh.faces, mesh.vertex_colors, frame_id=mesh.frame_id, _cache=mesh._cache)
        return _remap_faces(same, mesh.faces)
    return _remap(mesh, *_cells(mesh.vertices, max(distance, 1e-12), linear), average=False)


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


def piece_labels(mesh: Mesh) -> tuple[int, np.ndarray]:
    """The mesh's connected pieces (faces sharing a vertex): their count and each vertex's piece."""
    from scipy.sparse import csr_matrix
    from scipy.sparse.csgraph import connected_components

    n, f = mesh.num_vertices, mesh.faces
    # Faces and vertices as one graph, each face joined to its three corners: its rows need no sorting
    # (a vertex graph's edge list does), and its vertices fall into the vertex graph's pieces.
    faces = mesh.num_faces
    indptr = np.empty(faces + n + 1, np.int32 if 3 * faces + n < 2 ** 31 else np.int64)
    indptr[:faces + 1] = np.arange(0, 3 * faces + 1, 3)
    indptr[faces + 1:] = 3 * faces
    corners = np.empty(3 * faces, indptr.dtype)
    np.add(f, faces, out=corners.reshape(-1, 3), casting="unsafe")   # below 2^31 where int32
    graph = csr_matrix((np.ones(3 * faces), corners, indptr), shape=(faces + n, faces + n))
    count, label = connected_components(graph, directed=False)
    return count, label[faces:]


def remove_small_pieces(mesh: Mesh, min_diameter: float) -> tuple[Mesh, int]:
    """Drop connected pieces whose bounding-box diagonal is below min_diameter; returns (mesh, faces removed)."""
    count, label = piece_labels(mesh)
    f = mesh.faces
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


def piece_areas(mesh: Mesh) -> np.ndarray:
    """Area (m^2) of each connected piece, largest first."""
    if mesh.num_faces == 0:
        return np.zeros(0)
    count, label = piece_labels(mesh)
    return np.sort(np.bincount(label[mesh.faces[:, 0]], mesh.face_areas(), count))[::-1]


def cluster_vertices(mesh: Mesh, target_faces: int) -> Mesh:
    """Vertex clustering on a grid sized so roughly target_faces remain (fast coarse decimation)."""
    area = float(mesh.face_areas().sum())
    cell = np.sqrt(2.0 * area / max(target_faces, 1))  # a grid of cell c triangulates to ~2 A / c^2 faces
    inverse, count = _cells(mesh.vertices, cell)
    return _remap(mesh, inverse, count, average=True)
