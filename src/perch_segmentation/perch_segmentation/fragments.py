"""Fragments below min_area (clutter, crumpled patches of rough scans) join the adjacent surface
whose plane they lie closest to, so a rough wall is one surface instead of one with many holes.

A fragment's fit to a host's plane (normal n, point c) is the mean squared distance of the
fragment's surface to it: n^T Cov_f n + (n . (mean_f - c))^2, from the fragment's moments alone,
so a rough host is not penalised for its own roughness. Colour is not compared: a fragment is
too small to be reported as a surface of its own anyway (a poster, the colour-blended border
row of a wall). Flat fragments of at least
normal_guard_area must also be parallel to the host (within theta_max): they are surfaces of
their own, not crumbs.
"""

from __future__ import annotations

import numpy as np

from perch_common.symmetric import eigenvalues
from perch_segmentation import stats as st
from perch_segmentation.adjacency import unique_edges
from perch_segmentation.agglomerate import PRIORITY_DECIMALS, components

_MIN_FACING = 0.342  # cos 70 deg: RMS cosine between a fragment's face normals and the host's normal
_FLATNESS = 0.2  # RMS off-plane spread below this fraction of the in-plane spread counts as flat


def absorb_fragments(table: np.ndarray, edges: np.ndarray, min_area: float, max_rms: float,
                     guard_area: float, guard_cos: float,
                     max_rounds: int = 1000
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Merge fragments into adjacent surfaces; returns (old cluster -> new cluster, statistics, edges)."""
    count = len(table)
    mapping = np.arange(count, dtype=np.int64)
    for _ in range(max_rounds):
        if len(edges) == 0:
            break
        area = table[:, st.AREA]
        small = area < min_area
        u, v = edges[:, 0], edges[:, 1]
        one = small[u] != small[v]  # fragment-host pairs; fragment-fragment pairs wait a round
        frag = np.where(small[u], u, v)[one]
        host = np.where(small[u], v, u)[one]
        if len(frag) == 0:
            break
        is_host = np.zeros(count, bool)
        is_host[host] = True
        hosts = np.flatnonzero(is_host)  # plane fits of the hosts only
        host_row = np.cumsum(is_host)[host] - 1
        centroid, normal = st.plane_normals(table[hosts])
        host_normal, host_point = normal[host_row], centroid[host_row]
        cost = st.fit_to_plane(table[frag], host_normal, host_point)
        ok = cost <= max_rms * max_rms
        # Larger flat fragments are surfaces of their own (a box's side, a shelf): they must be
        # parallel to the host; crumbs and crumpled patches of a rough scan need not be.
        cov = st.covariance(table[frag, st.AREA], table[frag, st.FIRST], table[frag, st.SECOND])
        values = np.maximum(eigenvalues(cov), 0.0)
        flat = values[:, 0] <= (_FLATNESS ** 2) * values[:, 1]
        guarded = (table[frag, st.AREA] >= guard_area) & flat
        _, frag_normal = st.plane_normals(table[frag])
        ok &= ~guarded | (np.abs(np.einsum("ij,ij->i", frag_normal, host_normal)) >= guard_cos)
        # And its faces must mostly face the host's way (RMS cosine, blind to the flipped faces of
        # crumpled scan patches): a crumb of a rough wall does, a strip of a box's side does not.
        # (a zero-area fragment, from degenerate faces, faces nothing: it stays apart, as NaN did)
        area = table[frag, st.AREA]
        facing2 = np.divide(st.quadratic_form(table[frag, st.NORMAL2], host_normal), area,
                            out=np.zeros(len(frag)), where=area > 0)
        ok &= facing2 >= _MIN_FACING ** 2
        if not ok.any():
            break
        frag, host, cost = frag[ok], host[ok], cost[ok]
        # Per fragment: best host first; costs compared as step 1 compares priorities (a fragment
        # that lies in the plane of two hosts fits both at ~0: the smaller host index wins, not rounding).
        rank = np.round(cost / (max_rms * max_rms), PRIORITY_DECIMALS) if max_rms > 0 else cost
        order = np.lexsort((host, rank, frag))
        first = np.ones(len(order), bool)
        first[1:] = frag[order][1:] != frag[order][:-1]
        chosen = order[first]
        count, relabel = components(count, frag[chosen], host[chosen])
        mapping = relabel[mapping]
        table = st.aggregate(table, relabel, count)
        edges = unique_edges(relabel[u], relabel[v], count)
    return mapping, table, edges
