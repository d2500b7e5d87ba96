"""The exhaustive greedy reference: plain greedy over a dense grid of positions and gimbal angles."""

from __future__ import annotations

import numpy as np

from perch_placement.candidates import CandidateGreedy, build_candidates
from perch_placement.search.context import SearchContext


def exhaustive_reference(ctx: SearchContext, k: int) -> tuple[list, list, int, int]:
    """Greedy over a dense grid of positions and gimbal angles (the brute-force reference).

    Returns the fitness after each camera, the chosen perches, the candidate count and the
    arrangements scored."""
    cfg = ctx.config
    cands = build_candidates(ctx.plane, ctx.evaluator, cfg.reference_spacing, cfg.reference_angles,
                             ctx.exclusions, np.array(ctx.others).reshape(-1, 3))
    greedy_set = CandidateGreedy(cands, ctx.evaluator.info, ctx.evaluator.seen, cfg.drone.min_spacing)
    fitness, chosen = [], []
    for _ in range(k):
        picked = greedy_set.step()
        if picked is None:
            break
        fitness.append(greedy_set.fitness)
        chosen.append(cands.perch.take([picked[0]]))
    return fitness, chosen, len(cands), greedy_set.evaluations
