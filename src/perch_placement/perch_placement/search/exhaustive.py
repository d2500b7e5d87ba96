"""The exhaustive greedy references: plain greedy over a dense grid of positions and gimbal angles,
for the nominal fitness from the candidate set's cached visibility, for the other objectives by
scoring every candidate with the objective itself."""

from __future__ import annotations

import numpy as np

from perch_placement.candidates import CandidateGreedy, CandidateSet, build_candidates
from perch_placement.search.context import SearchContext, commit


def exhaustive_reference(ctx: SearchContext, k: int, spacing: float | None = None,
                         angles: int | None = None) -> tuple[list, list, int, int]:
    """Greedy over a dense grid of positions and gimbal angles (the brute-force reference; default
    grid: reference_spacing, reference_angles) on the context's perches (plane encoding).

    Returns the fitness after each camera, the chosen perches, the candidate count and the
    arrangements scored."""
    cfg = ctx.config
    cands = build_candidates(ctx.plane, ctx.evaluator, spacing or cfg.reference_spacing,
                             angles or cfg.reference_angles, ctx.exclusions, np.array(ctx.others).reshape(-1, 3))
    greedy_set = CandidateGreedy(cands, ctx.evaluator.info, ctx.evaluator.seen, cfg.drone.min_spacing)
    fitness, chosen = [], []
    for _ in range(k):
        picked = greedy_set.step()
        if picked is None:
            break
        fitness.append(greedy_set.fitness)
        chosen.append(cands.take([picked[0]]))
    return fitness, chosen, len(cands), greedy_set.evaluations


def objective_reference(ctx: SearchContext, k: int, spacing: float, angles: int,
                        chunk: int = 2048) -> tuple[list, int, int]:
    """Greedy under the configured objective (ctx.alternative_objective; the nominal fitness for
    `fitness`) over every candidate of a grid (`spacing`, `angles` x `angles` gimbal settings): each
    step scores every candidate with the objective on top of the cameras chosen so far and commits the
    best. Leaves the context holding the answer. Returns the chosen perches, the candidate count and
    the candidates scored."""
    cands = build_candidates(ctx.plane, ctx.evaluator, spacing, angles, ctx.exclusions,
                             np.array(ctx.others).reshape(-1, 3))
    x = candidate_encodings(ctx, cands)
    chosen, scored = [], 0
    for _ in range(k):
        objective = ctx.alternative_objective() or ctx.objective
        values = np.concatenate([objective(x[s:s + chunk]) for s in range(0, len(x), chunk)]) if len(x) else x
        scored += len(x)
        if not len(x) or not values.max() > 0:
            break
        perch = ctx.plane.decode(x[int(np.argmax(values))])
        commit(ctx, perch)
        chosen.append(perch)
    return chosen, len(cands), scored


def candidate_encodings(ctx: SearchContext, cands: CandidateSet) -> np.ndarray:
    """(C,D) plane encodings of every candidate (zoom 1)."""
    plane = ctx.plane
    position = np.array([plane.encode_position(int(r), p) for r, p in zip(cands.region, cands.points)])
    position = position.reshape(-1, 3)
    x = np.column_stack([np.repeat(position, cands.orientations, axis=0), np.tile(cands.gimbal, (cands.positions, 1))])
    return np.column_stack([x, np.zeros(len(x))]) if plane.max_zoom > 1 else x
