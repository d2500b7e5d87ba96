"""A provable upper bound on the best coverage k cameras can reach on a candidate set.

Max-k-coverage as an integer program over the candidate set (x_c: candidate c is chosen, y_n:
target point n is seen):

    maximise  (|seen before| + sum_n y_n) / N
    s.t.      y_n <= sum_{c sees n} x_c         every point not seen by the fixed cameras
              sum_c x_c <= k
              sum_{c in B} x_c <= 1              every "ball" B of positions closer than min_spacing
                                                  to each other (at most one drone there)
              x, y in {0, 1}

Every feasible k-subset of the candidates (drones min_spacing apart) is a feasible point of this
program with objective = its coverage, so the program's optimum, and a fortiori the optimum of its
linear relaxation (x, y in [0, 1]), bounds the best coverage on the candidate set from above. HiGHS
(scipy.optimize.linprog) solves the relaxation; the larger of its primal and dual objectives is
reported (they agree at optimality). A program stopped by the time limit gives no LP bound.

What it bounds: **coverage** (the fraction of points seen), not the fitness. Fitness is at most
coverage (a seen point scores at most 1, an unseen one 0), so the same number bounds the best
fitness too, loosely. Given the answer, two bounds that need no program come first (the share of
points any candidate sees; coverage's online bound at the answer, valid as coverage is monotone
submodular): when the answer reaches them the certificate is exact without the program, and when
the program does not finish in time they are what is reported. Orientations of one position that
see a subset of what another orientation of the same position sees are dropped first: that leaves
the relaxation's optimum unchanged (the mass moves to the dominating column) and shrinks the
program many times; the mask is computed once per candidate set (kept with it in the cache).

The budget (`time_limit`) counts the process's CPU seconds, as the stages' work budgets do: on a
loaded machine a wall-clock limit stopped the program before it had done its work (the Quest room's
LP needs ~0.6 CPU s; at load 4 on 2 cores it took 1.7 s of wall time). HiGHS only knows a wall-clock
limit, so it gets the CPU seconds left stretched by the machine's load (runnable tasks per core).
The program is skipped when the steps before it used the budget up; the program-free bound is then
reported, so an answer given with its seen points always carries a bound. HiGHS's presolve is off: on
these programs it cost more than the solve (Quest room 0.61 -> 0.22 CPU s, generated room 0.48 ->
0.19) and did not look at the time limit while it ran.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass

import numpy as np

from perch_placement.candidates import CandidateSet


@dataclass
class Certificate:
    """The LP bound on the best coverage and how it was obtained."""

    coverage_bound: float   # upper bound on the best coverage of k candidates (NaN: not obtained)
    columns: int            # candidate columns left after dropping dominated orientations
    seconds: float          # CPU seconds of the process (what the budget counts)
    status: str             # "optimal", or why the bound is missing or only the dual bound at a time limit
    wall_seconds: float = float("nan")

    def gap(self, coverage: float) -> float:
        """How far below the bound an answer's coverage is, as a fraction of the bound (>= 0 unless the
        answer, found off the candidate grid, beats the candidate set's best)."""
        if not np.isfinite(self.coverage_bound) or self.coverage_bound <= 0:
            return float("nan")
        return 1.0 - coverage / self.coverage_bound


def undominated(visible: np.ndarray) -> np.ndarray:
    """(P,A) mask of the orientations at each position not dominated by another one there (a
    visibility set strictly inside another's, or equal to an earlier one's)."""
    v = visible.astype(np.float32)
    counts = v.sum(axis=-1)                                    # (P,A)
    keep = np.ones(visible.shape[:2], bool)
    chunk = max(1, 2_000_000 // max(1, visible.shape[1] ** 2))
    a = visible.shape[1]
    earlier = np.tril(np.ones((a, a), bool), -1)               # [i, j]: j < i
    for start in range(0, len(v), chunk):
        sl = slice(start, start + chunk)
        inter = np.matmul(v[sl], v[sl].transpose(0, 2, 1))     # (p,A,A) |V_i & V_j|
        c = counts[sl]
        inside = inter >= c[:, :, None] - 0.5                  # V_i within V_j
        strictly = inside & (c[:, None, :] > c[:, :, None] + 0.5)
        equal = inside & (np.abs(c[:, None, :] - c[:, :, None]) < 0.5) & earlier[None]
        keep[sl] = ~(strictly | equal).any(axis=2)
    return keep & visible.any(axis=-1)


def spacing_cliques(positions: np.ndarray, min_spacing: float) -> list[np.ndarray]:
    """Sets of positions pairwise closer than min_spacing (any two within min_spacing/2 of one centre
    are), centred on a subset of the positions that covers them all at min_spacing/4."""
    if min_spacing <= 0 or len(positions) == 0:
        return []
    from scipy.spatial import cKDTree

    tree = cKDTree(positions)
    radius = 0.5 * min_spacing * (1 - 1e-9)
    centres, covered = [], np.zeros(len(positions), bool)
    for i in range(len(positions)):  # greedy cover: centres min_spacing/4 apart
        if not covered[i]:
            centres.append(i)
            covered[tree.query_ball_point(positions[i], 0.25 * min_spacing)] = True
    cliques = [np.array(sorted(m)) for m in tree.query_ball_point(positions[centres], radius)]
    return [c for c in cliques if len(c) > 1]


def cheap_bound(cands: CandidateSet, base_seen: np.ndarray, answer_seen: np.ndarray, k: int,
                min_spacing: float) -> float:
    """Two bounds on the best coverage of k candidates added to `base_seen` that need no program:
    the share of points some candidate (or a fixed camera) sees, and coverage's online bound at the
    answer S (coverage is monotone submodular, so best <= g(S) + the k largest gains over S, at most
    one per position when drones must be apart)."""
    base_seen, answer_seen = np.asarray(base_seen, bool), np.asarray(answer_seen, bool) | base_seen
    reachable = float((base_seen | cands.reach.any(axis=0)).mean())
    # Only the points the answer misses matter (a few): a float copy of every column cost ~80 MB on
    # the Quest room and most of this bound's time.
    gains = cands.visible[:, :, np.flatnonzero(~answer_seen)].sum(axis=-1)  # (P,A) points each would add
    gains = gains.max(axis=1) if min_spacing > 0 else gains.reshape(-1)
    online = float(answer_seen.mean() + np.sort(gains)[::-1][:k].sum() / len(answer_seen))
    return min(1.0, reachable, online)


def coverage_certificate(cands: CandidateSet, base_seen: np.ndarray, k: int, min_spacing: float,
                         time_limit: float = 2.0, answer_seen: np.ndarray | None = None,
                         clock=time.process_time) -> Certificate:
    """An upper bound on the best coverage of k candidates added to a state seeing `base_seen`: the
    LP bound, or (given the answer's seen points `answer_seen`) first the bounds that need no
    program (cheap_bound), enough when the answer reaches them; the smallest bound found.
    `time_limit` is in seconds of `clock` (CPU seconds of the process)."""
    start, wall_start = clock(), time.perf_counter()

    def done(bound: float, columns: int, status: str) -> Certificate:
        return Certificate(bound, columns, clock() - start, status, time.perf_counter() - wall_start)

    n = len(base_seen)
    base = float(np.count_nonzero(base_seen))
    if k <= 0 or cands.positions == 0:
        return done(base / n, 0, "optimal")
    open_points = np.flatnonzero(~np.asarray(base_seen, bool))
    if len(open_points) == 0:
        return done(1.0, 0, "optimal")
    cheap = 1.0
    if answer_seen is not None:
        cheap = cheap_bound(cands, base_seen, answer_seen, k, min_spacing)
        if float(np.mean(np.asarray(answer_seen, bool) | base_seen)) >= cheap - 1e-12:
            return done(cheap, 0, "tight: the answer reaches the bound")
    # Imported here: an answer that reaches the cheap bound (most) needs no program, and the import
    # costs ~0.2 CPU s.
    from scipy.optimize import linprog
    from scipy.sparse import coo_matrix, csr_matrix, vstack

    visible = cands.visible[:, :, open_points]
    # Dominance on every point holds on the open ones too (columns dominated only there are kept:
    # the bound is the same, the program a little larger); computed once per candidate set.
    keep = cands.undominated()
    pos, ori = np.nonzero(keep)
    cols = len(pos)
    if cols == 0:
        return done(base / n, 0, "optimal")
    m = len(open_points)
    # Variables: x (cols) then y (m). Rows: y_n - sum x <= 0; sum x <= k; one per position; cliques.
    col_vis = visible[pos, ori]                                    # (cols, m)
    c_idx, p_idx = np.nonzero(col_vis)
    cover = coo_matrix((np.concatenate([-np.ones(len(c_idx)), np.ones(m)]),
                        (np.concatenate([p_idx, np.arange(m)]), np.concatenate([c_idx, cols + np.arange(m)]))),
                       shape=(m, cols + m))
    rows = [csr_matrix(cover), csr_matrix(np.concatenate([np.ones(cols), np.zeros(m)])[None])]
    rhs = [np.zeros(m), [float(k)]]
    where = cands.drone_positions()
    if min_spacing > 0:
        # Rows "at most one drone" per clique of positions, and per position in no clique: (sets x
        # positions) @ (positions x columns).
        groups = spacing_cliques(where, min_spacing)
        alone = np.setdiff1d(np.arange(cands.positions), np.concatenate(groups) if groups else [])
        sets = groups + [np.array([p]) for p in alone]
        members = coo_matrix((np.ones(sum(len(g) for g in sets)),
                              (np.repeat(np.arange(len(sets)), [len(g) for g in sets]), np.concatenate(sets))),
                             shape=(len(sets), cands.positions)).tocsr()
        column_of = coo_matrix((np.ones(cols), (pos, np.arange(cols))), shape=(cands.positions, cols)).tocsr()
        one_drone = (members @ column_of).tocsr()
        one_drone = one_drone[np.diff(one_drone.indptr) > 1]   # a row with one column is the bound x <= 1
        rows.append(csr_matrix((one_drone.data * 0 + 1, one_drone.indices, one_drone.indptr),
                               shape=(one_drone.shape[0], cols)))
        rows[-1] = hstack_zero(rows[-1], m)
        rhs.append(np.ones(one_drone.shape[0]))
    a_ub = vstack(rows).tocsr()
    b_ub = np.concatenate([np.asarray(b, np.float64) for b in rhs])
    objective = np.concatenate([np.zeros(cols), -np.ones(m) / n])
    spent = clock() - start
    remaining = time_limit - spent
    if remaining < 0.05 * time_limit:
        why = f"no time left for the linear program ({spent:.2f} of {time_limit:g} CPU s spent before it)"
        return done(cheap, cols, f"online coverage bound only: {why}") if answer_seen is not None else \
            done(float("nan"), cols, f"no bound: {why}")
    res = linprog(objective, A_ub=a_ub, b_ub=b_ub, bounds=(0.0, 1.0), method="highs",
                  options={"time_limit": remaining * load_stretch(), "presolve": False})
    seconds = clock() - start
    if res.status == 0:
        # The primal optimum equals the dual objective at optimality; a dual-feasible point's objective
        # is what bounds the integer optimum, so take the larger of the two reported values.
        dual = _dual_bound(res, b_ub, n)
        bound = max(-float(res.fun), dual if np.isfinite(dual) else -np.inf)
        return done(min(1.0, cheap, base / n + bound), cols, "optimal")
    if answer_seen is not None:
        return done(cheap, cols, f"online coverage bound only: the linear program stopped "
                    f"({res.message.strip()}) after {seconds:.2f} CPU s")
    return done(float("nan"), cols,
                f"no bound: the linear program stopped ({res.message.strip()}) after {seconds:.2f} CPU s")


def load_stretch(most: float = 4.0) -> float:
    """Wall seconds per CPU second a single-threaded task can expect now: runnable tasks per core
    (1-minute load average), at least 1, at most `most` (so a stale load figure cannot hold the
    program for long)."""
    try:
        load = os.getloadavg()[0]
    except OSError:   # not available on this platform
        return 1.0
    return float(np.clip(load / max(1, os.cpu_count() or 1), 1.0, most))


def hstack_zero(matrix, width: int):
    """The sparse matrix with `width` zero columns appended (the y variables)."""
    from scipy.sparse import csr_matrix, hstack

    return hstack([matrix, csr_matrix((matrix.shape[0], width))]).tocsr()


def _dual_bound(res, b_ub: np.ndarray, n: int) -> float:
    """The dual objective of linprog's answer (HiGHS marginals): an upper bound on the LP maximum."""
    try:
        lam = -np.asarray(res.ineqlin.marginals)       # >= 0 for the maximisation
        upper = -np.asarray(res.upper.marginals)       # variable bounds x, y <= 1
    except AttributeError:
        return float("nan")
    return float(lam @ b_ub + upper.sum())
