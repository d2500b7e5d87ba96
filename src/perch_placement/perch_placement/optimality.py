"""Checking the greedy online bound against exhaustive enumeration on small candidate sets.

For a monotone submodular f, every set S gives f(OPT_k) <= f(S) + sum of the k largest marginal
gains over the candidates. Our objective's coverage part is submodular, but fusing anisotropic
covariances is not (a second, orthogonal view can gain more than the first did), so whether the
bound holds is measured here, by enumerating every feasible k-subset. The coverage relaxation
(g(S) = fraction of points seen >= f(S), submodular) gives a bound that always holds.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from perch_placement.candidates import CandidateGreedy, CandidateSet
from perch_placement.fitness import point_score


@dataclass
class BoundCheck:
    """Exhaustive optimum versus the greedy online bounds on one small instance."""

    k: int
    optimum: float          # best fitness over all feasible k-subsets of the candidates
    greedy: float           # plain greedy's fitness
    bounds: list            # online bound at each greedy prefix S_0..S_k
    coverage_bounds: list   # guaranteed (coverage relaxation) bound at each prefix
    subsets: int            # feasible subsets enumerated

    TOLERANCE = 1e-6        # candidate gains are summed in float32

    @property
    def holds(self) -> bool:
        """The online bound held at every greedy prefix."""
        return min(self.bounds) >= self.optimum - self.TOLERANCE

    @property
    def holds_final(self) -> bool:
        """The online bound held at the final greedy set (the one reported with an answer)."""
        return self.bounds[-1] >= self.optimum - self.TOLERANCE

    @property
    def coverage_holds(self) -> bool:
        """Whether the coverage bound held at every greedy prefix."""
        return min(self.coverage_bounds) >= self.optimum - self.TOLERANCE

    @property
    def slack(self) -> float:
        """Least margin of the online bound over the optimum (negative: it failed)."""
        return min(self.bounds) - self.optimum


def subset_fitness(cands: CandidateSet, subsets: np.ndarray, base_info: np.ndarray,
                   base_seen: np.ndarray, chunk: int = 4096) -> np.ndarray:
    """Fitness of each subset (S,k) of candidate indices on top of a base state."""
    a = cands.orientations
    out = np.zeros(len(subsets))
    for start in range(0, len(subsets), chunk):
        block = subsets[start:start + chunk]
        p, o = np.divmod(block, a)
        seen = cands.visible[p, o]                                  # (s,k,N)
        info = base_info[None] + (cands.info_rows(p) * seen[..., None]).sum(axis=1)
        out[start:start + chunk] = point_score(info, base_seen[None] | seen.any(axis=1))[0].mean(axis=1)
    return out


def check_bound(cands: CandidateSet, k: int, base_info: np.ndarray, base_seen: np.ndarray,
                min_spacing: float) -> BoundCheck:
    """Exact optimum over feasible k-subsets versus the online bound along the greedy path."""
    drones = cands.drone_positions()
    a = cands.orientations
    subsets = np.array(list(itertools.combinations(range(len(cands)), k)), dtype=np.int64).reshape(-1, k)
    if k > 1 and len(subsets):
        where = drones[subsets // a]
        gap = np.linalg.norm(where[:, :, None] - where[:, None], axis=-1) + np.eye(k) * 1e9
        subsets = subsets[gap.min(axis=(1, 2)) >= max(min_spacing, 1e-9)]
    optimum = float(subset_fitness(cands, subsets, base_info, base_seen).max()) if len(subsets) else 0.0
    greedy = CandidateGreedy(cands, base_info, base_seen, min_spacing)
    bounds, coverage_bounds = [], []
    while True:
        fresh = CandidateGreedy(cands, greedy.info, greedy.seen, min_spacing)
        bounds.append(fresh.online_bound(k))
        coverage_bounds.append(fresh.coverage_bound(k))
        if len(bounds) > k or greedy.step() is None:
            break
    return BoundCheck(k, optimum, greedy.fitness, bounds, coverage_bounds, len(subsets))


def bound_check_suite(instances: int = 10, k_max: int = 3, points: int = 30, spacing: float = 2.0,
                      angles: int = 2, max_subsets: float = 2e6) -> dict:
    """Run check_bound on small generated rooms (furnished, so occlusion matters); a summary dict."""
    import math

    from perch_common.scene_generator import generate_scene
    from perch_placement.candidates import build_candidates
    from perch_placement.cli_problem import unfiltered_regions
    from perch_placement.config import PlacementConfig
    from perch_placement.core import scene_for
    from perch_placement.fitness import Evaluator
    from perch_placement.perches import Perches

    cfg = PlacementConfig().resolved()
    checks = []
    for seed in range(instances):
        scene = generate_scene(seed, ("room", "l_shaped", "two_rooms")[seed % 3])
        regions = unfiltered_regions(scene.mesh, scene.ground_truth_surfaces())
        ev = Evaluator(scene_for(scene.mesh), scene.target.sample(points, seed=seed), cfg.camera)
        cands = build_candidates(Perches(regions, scene.target.centroid(), cfg.drone), ev, spacing, angles)
        for k in range(1, k_max + 1):
            if math.comb(len(cands), k) <= max_subsets:
                checks.append(check_bound(cands, k, ev.info, ev.seen, cfg.drone.min_spacing))
    return {"checks": len(checks), "candidates_per_instance": f"{spacing} m grid, {angles}x{angles} angles",
            "online_bound_held_at_final_set": sum(c.holds_final for c in checks),
            "online_bound_held_at_every_prefix": sum(c.holds for c in checks),
            "coverage_bound_held": sum(c.coverage_holds for c in checks),
            "worst_slack_any_prefix": min(c.slack for c in checks) if checks else None,
            "worst_slack_final": min(c.bounds[-1] - c.optimum for c in checks) if checks else None,
            "mean_greedy_over_optimum": float(np.mean([c.greedy / c.optimum for c in checks if c.optimum > 0]))}
