"""Step 2: merge adjacent clusters that lie on one plane, then unite the floor's and ceiling's pieces.

Criteria (each a function, so each can be tested on its own):
  normals_agree   normals differ by less than theta_max;
  side_by_side    the line joining the centroids makes at least theta_min with both normals
                  (parallel planes stacked on each other never merge);
  planes_close    each centroid lies within d_max of the other cluster's plane;
  colors_close    mean CIELAB colours within the threshold (only when colour is used).
Pairs merge lowest normal angle first, in rounds, and statistics are recomputed after every
round, so a merged cluster's new plane is what later merges must match (a gently curved surface
cannot chain its way around a corner).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from perch_common.cancellation import checkpoint
from perch_segmentation import stats as st
from perch_segmentation.adjacency import unique_edges
from perch_segmentation.agglomerate import best_edges, components, flag_union


@dataclass
class PlaneRules:
    """When step 2 merges two clusters: normal angle, stacking angle, plane distance, colour."""

    theta_max_deg: float
    theta_min_deg: float
    d_max: float
    color_threshold: float | None  # None: colour ignored


@dataclass
class Geometry:
    """Per cluster: area, centroid, oriented unit normal, mean CIELAB colour."""

    area: np.ndarray
    centroid: np.ndarray
    normal: np.ndarray
    lab: np.ndarray

    @staticmethod
    def of(table: np.ndarray) -> "Geometry":
        """The geometry of every cluster of a statistics table."""
        centroid, normals = st.plane_normals(table)
        return Geometry(table[:, st.AREA], centroid, normals, st.mean_lab(table))


def normal_cosine(g: Geometry, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """|cos| of the angle between normals (unsigned: winding may differ between pieces)."""
    return np.abs(np.einsum("ij,ij->i", g.normal[u], g.normal[v]))


def normals_agree(g: Geometry, u, v, rules: PlaneRules) -> np.ndarray:
    """(E,) whether the normals of clusters u and v differ by less than theta_max."""
    return normal_cosine(g, u, v) >= np.cos(np.radians(rules.theta_max_deg))


def side_by_side(g: Geometry, u, v, rules: PlaneRules) -> np.ndarray:
    """(E,) whether clusters u and v lie side by side, not stacked (the joining line is far from both normals)."""
    d = g.centroid[v] - g.centroid[u]
    length = np.linalg.norm(d, axis=1)
    unit = np.divide(d, length[:, None], out=np.zeros_like(d), where=length[:, None] > 1e-9)
    limit = np.cos(np.radians(rules.theta_min_deg))  # angle >= theta_min  <=>  |cos| <= cos(theta_min)
    return (np.abs(np.einsum("ij,ij->i", unit, g.normal[u])) <= limit + 1e-12) & \
           (np.abs(np.einsum("ij,ij->i", unit, g.normal[v])) <= limit + 1e-12)


def planes_close(g: Geometry, u, v, rules: PlaneRules) -> np.ndarray:
    """(E,) whether each centroid lies within d_max of the other's plane."""
    d = g.centroid[v] - g.centroid[u]
    return (np.abs(np.einsum("ij,ij->i", d, g.normal[u])) <= rules.d_max) & \
           (np.abs(np.einsum("ij,ij->i", d, g.normal[v])) <= rules.d_max)


def colors_close(g: Geometry, u, v, rules: PlaneRules) -> np.ndarray:
    """(E,) whether the mean colours are close enough (always, without colour)."""
    if rules.color_threshold is None:
        return np.ones(len(u), bool)
    return st.distance(g.lab[u], g.lab[v]) <= rules.color_threshold


def mergeable(g: Geometry, u, v, rules: PlaneRules) -> np.ndarray:
    """(E,) whether clusters u and v may merge: every rule holds."""
    return (normals_agree(g, u, v, rules) & side_by_side(g, u, v, rules)
            & planes_close(g, u, v, rules) & colors_close(g, u, v, rules))


def merge_priority(g: Geometry, u, v, rules: PlaneRules) -> np.ndarray:
    """Normal angle, plane offset and colour distance, each relative to its limit: the most
    alike pairs merge first, so a flush door is whole before it meets its wall."""
    angle = np.degrees(np.arccos(np.clip(normal_cosine(g, u, v), 0.0, 1.0)))
    d = g.centroid[v] - g.centroid[u]
    offset = np.maximum(np.abs(np.einsum("ij,ij->i", d, g.normal[u])), np.abs(np.einsum("ij,ij->i", d, g.normal[v])))
    priority = angle / rules.theta_max_deg + offset / rules.d_max
    if rules.color_threshold is not None:
        priority += st.distance(g.lab[u], g.lab[v]) / rules.color_threshold
    return priority


def members_off_plane(table: np.ndarray, g: Geometry, comp: np.ndarray, count: int,
                      rules: PlaneRules) -> np.ndarray:
    """Per cluster: does it disagree with the plane (theta_max, d_max) or colour of its component?"""
    merged = Geometry.of(st.aggregate(table, comp, count))
    cos = np.abs(np.einsum("ij,ij->i", g.normal, merged.normal[comp]))
    offset = np.abs(np.einsum("ij,ij->i", g.centroid - merged.centroid[comp], merged.normal[comp]))
    bad = (cos < np.cos(np.radians(rules.theta_max_deg))) | (offset > rules.d_max)
    if rules.color_threshold is not None:
        bad |= st.distance(g.lab, merged.lab[comp]) > rules.color_threshold
    return bad


def merge_coplanar(table: np.ndarray, edges: np.ndarray, rules: PlaneRules,
                   max_rounds: int = 1000) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Merge adjacent coplanar clusters; returns (old cluster -> new cluster, statistics, edges).

    Each round every cluster picks its most alike admissible neighbour (merge_priority); the picks
    form trees. Members that agree with their tree's union (theta_max, d_max, colour) merge with
    it; the others wait for the next round, except mutual-best pairs, which always merge.
    """
    count = len(table)
    mapping = np.arange(count, dtype=np.int64)
    for _ in range(max_rounds):
        checkpoint("the next merge round")
        if len(edges) == 0:
            break
        u, v = edges[:, 0], edges[:, 1]
        g = Geometry.of(table)
        ok = mergeable(g, u, v, rules)
        if not ok.any():
            break
        choice = best_edges(count, u, v, merge_priority(g, u, v, rules), ok)
        picked = flag_union(len(edges), choice[choice >= 0])
        mutual = picked[(choice[u[picked]] == picked) & (choice[v[picked]] == picked)]
        ncomp, comp = components(count, u[picked], v[picked])
        bad = members_off_plane(table, g, comp, ncomp, rules)
        accept = flag_union(len(edges), picked[~bad[u[picked]] & ~bad[v[picked]]], mutual)
        count, relabel = components(count, u[accept], v[accept])
        mapping = relabel[mapping]
        table = st.aggregate(table, relabel, count)
        edges = unique_edges(relabel[u], relabel[v], count)
    return mapping, table, edges


def boundary_plane_groups(table: np.ndarray, up: np.ndarray, extent: tuple[float, float],
                          rules: PlaneRules, min_area: float) -> np.ndarray:
    """Cluster -> merged cluster uniting the disconnected coplanar pieces of floor and ceiling.

    The floor (ceiling) is the largest horizontal cluster of at least min_area in the lowest
    (highest) quarter of the mesh's height; every cluster facing the same way whose centroid is
    within d_max of its plane (and whose colour matches, if colour is used) joins it.
    """
    count = len(table)
    mapping = np.arange(count, dtype=np.int64)
    if count == 0:
        return mapping
    g = Geometry.of(table)
    cos_max = np.cos(np.radians(rules.theta_max_deg))
    height = g.centroid @ up
    horizontal = np.abs(g.normal @ up) >= cos_max
    low, high = extent
    quarter = 0.25 * (high - low)
    for band in (height <= low + quarter, height >= high - quarter):
        candidates = np.flatnonzero(horizontal & band & (g.area >= min_area))
        if len(candidates) == 0:
            continue
        ref = candidates[np.argmax(g.area[candidates])]
        facing = g.normal @ g.normal[ref] >= cos_max
        close = np.abs((g.centroid - g.centroid[ref]) @ g.normal[ref]) <= rules.d_max
        members = facing & close
        if rules.color_threshold is not None:
            members &= st.distance(g.lab, g.lab[ref]) <= rules.color_threshold
        mapping[members] = mapping[ref]
    _, mapping = np.unique(mapping, return_inverse=True)
    return mapping
