"""Face adjacency of a triangle mesh: pairs of faces sharing an edge, fully vectorised."""

from __future__ import annotations

import numpy as np


def face_adjacency(faces: np.ndarray, num_vertices: int) -> np.ndarray:
    """(E,2) int64 face pairs sharing an edge, each pair once with first < second.

    Non-manifold edges (3+ faces) link their faces in a chain, which keeps them connected
    without a quadratic number of pairs.
    """
    f = len(faces)
    if f == 0:
        return np.zeros((0, 2), np.int64)
    a = faces[:, [0, 1, 2]].ravel()
    b = faces[:, [1, 2, 0]].ravel()
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    keep = lo != hi  # edges of degenerate faces with a repeated vertex
    keys = lo[keep] * np.int64(num_vertices) + hi[keep]
    owner = np.repeat(np.arange(f, dtype=np.int64), 3)[keep]
    # Stable: the faces of a non-manifold edge chain in mesh order. numpy's default sort leaves equal keys
    # in an order that follows the CPU's SIMD level, and real scans segmented differently on two machines.
    order = np.argsort(keys, kind="stable")
    keys, owner = keys[order], owner[order]
    same = keys[1:] == keys[:-1]
    pairs = np.stack([owner[:-1][same], owner[1:][same]], axis=1)
    pairs = pairs[pairs[:, 0] != pairs[:, 1]]
    pairs.sort(axis=1)
    return pairs


def unique_edges(u: np.ndarray, v: np.ndarray, count: int) -> np.ndarray:
    """(E,2) distinct undirected edges between different nodes of a graph with `count` nodes."""
    lo, hi = np.minimum(u, v), np.maximum(u, v)
    keep = lo != hi
    keys = np.sort(lo[keep] * np.int64(count) + hi[keep])
    keys = keys[np.concatenate([[True], keys[1:] != keys[:-1]])] if len(keys) else keys
    return np.stack([keys // count, keys % count], axis=1)
