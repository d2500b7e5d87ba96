"""Step 1: greedy bottom-up merging of adjacent clusters by plane-fit energy, in parallel rounds.

The original pops one merge at a time from a heap. Here every round lets each cluster pick its
lowest-energy admissible neighbour; the picked edges form small trees (Boruvka). The members of
a tree that fit the plane of its union within the energy bound merge (see members_fit), and so
do mutual-best pairs. Each round is a handful of numpy passes over the edge list, and the number of
clusters shrinks geometrically, so a million faces take a few rounds of vector work instead of
millions of heap operations in Python.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from perch_common.cancellation import checkpoint
from perch_common.work import report
from perch_segmentation import stats as st
from perch_segmentation.adjacency import unique_edges

# Priorities are compared at this many decimals (of their bound; energy to 4e-7 m^2, 0.6 mm RMS):
# coplanar neighbours, which scans and plane-optimised meshes have many of, have energy ~0 to float
# rounding, and a mesh given in another orientation moves its vertices by float32 rounding (~5e-7 m),
# which changes small faces' energies in the 5th digit. Rounded, such pairs tie and the tie goes to the
# larger edge index, not to the rounding (6 decimals still let the ICL living room's tilted copy differ).
PRIORITY_DECIMALS = 3


@dataclass
class MergeRules:
    """When two adjacent clusters may merge in step 1."""

    energy_bound: float          # m^2, plane-fit variance of the union
    color_threshold: float | None  # Delta E between mean colours; None: colour ignored
    guard_area: float            # m^2; a cluster at least this large only takes neighbours whose
    guard_cos: float             # normal is within theta_max of its own (cos)
    fold_cos: float = math.cos(math.radians(75.0))  # smaller ones: no fold sharper than 45 deg


def components(count: int, u: np.ndarray, v: np.ndarray) -> tuple[int, np.ndarray]:
    """Connected components of the graph with edges (u, v): (count, label of each node)."""
    graph = coo_matrix((np.ones(len(u), np.int8), (u, v)), shape=(count, count))
    return connected_components(graph, directed=False)


def admissible(table: np.ndarray, u: np.ndarray, v: np.ndarray, rules: MergeRules,
               energy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Which edges may merge, and their priority: energy and colour distance, each relative to
    its bound (like colours merge first, so a flush door is whole before it meets its wall)."""
    ok = energy <= rules.energy_bound
    priority = energy / rules.energy_bound
    if rules.color_threshold is not None:
        lab = st.mean_lab(table)
        distance = st.distance(lab[u], lab[v])
        ok &= distance <= rules.color_threshold
        priority += distance / rules.color_threshold
    # Normals (winding means, unsigned) may differ by theta_max once a cluster is large enough to
    # have a reliable one, and never by a fold sharper than 45 deg: two tiny pieces across a room
    # corner have little plane-fit energy but are not one plane.
    area = table[:, st.AREA]
    normal = st.winding_normals(table)
    cos = np.abs(np.einsum("ij,ij->i", normal[u], normal[v]))
    big = np.maximum(area[u], area[v]) >= rules.guard_area
    ok &= cos >= np.where(big, rules.guard_cos, rules.fold_cos)
    return ok, np.round(priority, PRIORITY_DECIMALS)


def flag_union(size: int, *index_arrays: np.ndarray) -> np.ndarray:
    """Sorted distinct indices in 0..size-1 found in any of the arrays (a mask: no hashing or sort)."""
    flags = np.zeros(size, bool)
    for indices in index_arrays:
        flags[indices] = True
    return np.flatnonzero(flags)


def best_edges(count: int, u: np.ndarray, v: np.ndarray, priority: np.ndarray,
               ok: np.ndarray) -> np.ndarray:
    """Per node, the admissible incident edge of lowest priority (-1: none); ties to the larger index."""
    idx = np.flatnonzero(ok)
    pu, pv, pp = u[idx], v[idx], priority[idx]
    best = np.full(count, np.inf)
    np.minimum.at(best, pu, pp)
    np.minimum.at(best, pv, pp)
    choice = np.full(count, -1, np.int64)
    for ends in (pu, pv):
        hit = pp == best[ends]
        np.maximum.at(choice, ends[hit], idx[hit])
    return choice


def members_fit(table: np.ndarray, comp: np.ndarray, ncomp: int, rules: MergeRules) -> np.ndarray:
    """Per cluster: may it merge with its component (tree of picks)?

    Yes if its surface lies within the energy bound of the union's plane (and agrees in colour
    and normal). Any set of such members has a plane-fit energy within the bound too (its best
    plane fits no worse than the union's), so the accepted parts of a tree can merge safely.
    """
    ok = np.ones(len(table), bool)
    member = np.flatnonzero(np.bincount(comp, minlength=ncomp)[comp] > 1)  # singletons need no check
    if len(member) == 0:
        return ok
    in_tree = np.zeros(ncomp, bool)
    in_tree[comp[member]] = True
    trees = np.flatnonzero(in_tree)
    tree_of = np.cumsum(in_tree)[comp[member]] - 1
    part = table[member]
    merged = st.aggregate(part, tree_of, len(trees))
    centroid, normal = st.plane_normals(merged)
    fits = st.fit_to_plane(part, normal[tree_of], centroid[tree_of]) <= rules.energy_bound
    if rules.color_threshold is not None:
        fits &= st.distance(st.mean_lab(part), st.mean_lab(merged)[tree_of]) <= rules.color_threshold
    cos = np.abs(np.einsum("ij,ij->i", st.winding_normals(part), st.winding_normals(merged)[tree_of]))
    fits &= cos >= np.where(merged[tree_of, st.AREA] >= rules.guard_area, rules.guard_cos, rules.fold_cos)
    ok[member] = fits
    return ok


def grow_clusters(face_stats: np.ndarray, adjacency: np.ndarray, rules: MergeRules, target: int,
                  max_rounds: int = 200, min_progress: float = 0.02) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Merge faces into clusters; returns (face labels, cluster statistics, cluster edges)."""
    count = len(face_stats)
    labels = np.arange(count, dtype=np.int64)
    table, edges = face_stats, adjacency
    for _ in range(max_rounds):
        checkpoint("the next merge round")
        # Progress: clusters shrink geometrically from faces towards target, so the share is logarithmic.
        faces = max(len(face_stats), 1)
        report(math.log(faces / max(count, 1)) / math.log(max(faces / max(target, 1), 2.0)), "grow clusters")
        if count <= target or len(edges) == 0:
            break
        u, v = edges[:, 0], edges[:, 1]
        energy = st.merged_energy(table, u, v)
        ok, priority = admissible(table, u, v, rules, energy)
        if not ok.any():
            break
        choice = best_edges(count, u, v, priority, ok)
        picked = flag_union(len(edges), choice[choice >= 0])
        mutual = picked[(choice[u[picked]] == picked) & (choice[v[picked]] == picked)]
        ncomp, comp = components(count, u[picked], v[picked])
        fits = members_fit(table, comp, ncomp, rules)
        accept = flag_union(len(edges), picked[fits[u[picked]] & fits[v[picked]]], mutual)
        merges = count - components(count, u[accept], v[accept])[0]
        if count - merges < target:  # the last round: only the cheapest pairs, down to the target
            accept = mutual[np.argsort(priority[mutual], kind="stable")[: count - target]]
        before = count
        count, relabel = components(count, u[accept], v[accept])
        labels = relabel[labels]
        table = st.aggregate(table, relabel, count)
        edges = unique_edges(relabel[u], relabel[v], count)
        if before - count < min_progress * before:
            break  # the tail merges a few clusters per round; step 2 and fragments take it from here
    return labels, table, edges
