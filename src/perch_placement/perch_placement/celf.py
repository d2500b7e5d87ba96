"""Lazy greedy (CELF) over the discrete candidate set with continuous refinement, and the
exhaustive greedy reference over a dense candidate grid."""

from __future__ import annotations

import numpy as np

from perch_placement.candidates import CandidateGreedy, build_candidates
from perch_placement.fitness import Evaluator
from perch_placement.perches import Perch, Perches
from perch_placement.search import SearchContext, SearchOutcome, candidate_encoding, commit, no_gain_reason, polish


def celf(ctx: SearchContext, k: int, refine_rounds: int = 6, samples: int = 32) -> SearchOutcome:
    """Lazy greedy over the discrete candidate set, then continuous refinement of each camera."""
    plane = ctx.plane
    cfg = ctx.config
    fixed = np.array(ctx.others).reshape(-1, 3)
    cands = ctx.candidates()
    if len(cands) == 0:
        return SearchOutcome([], "no candidate perch is feasible (regions, spacing, exclusion zones)")
    base_info, base_seen = ctx.evaluator.info.copy(), ctx.evaluator.seen.copy()
    lazy = CandidateGreedy(cands, base_info, base_seen, cfg.drone.min_spacing)
    pick = lazy.run(k, lazy=True)
    ctx.evaluator.candidate_evaluations += pick.evaluations
    encodings = [candidate_encoding(plane, cands, index) for index in pick.chosen]
    encodings = _refine(ctx, plane, encodings, base_info, base_seen, fixed, refine_rounds, samples)
    ctx.evaluator.set_state(base_info, base_seen)
    chosen = [plane.decode(x) for x in encodings]
    for perch in chosen:
        commit(ctx, perch)
    reason = "" if len(chosen) == k else no_gain_reason(ctx, len(chosen))
    return SearchOutcome(chosen, reason)


def _refine(ctx: SearchContext, plane: Perches, encodings: list, base_info, base_seen, fixed,
            rounds: int, samples: int) -> list:
    """Coordinate-wise hill climbing of each camera (position within its region, pan, tilt) with the
    others fixed: batched Gaussian steps, the step shrinking whenever a round brings no gain."""
    ev = ctx.evaluator
    perches = [plane.decode(x) for x in encodings]
    views = [_views(ev, p) for p in perches]
    for i, x in enumerate(encodings):
        others = [j for j in range(len(encodings)) if j != i]
        ev.set_state(base_info + sum((views[j][1][0] for j in others), np.zeros_like(base_info)),
                     base_seen | np.any([views[j][0][0] for j in others] or [np.zeros_like(base_seen)], axis=0))
        neighbours = np.vstack([fixed] + [perches[j].drone_position for j in others])

        def objective(batch: np.ndarray) -> np.ndarray:
            perch = plane.decode(batch)
            ok = plane.feasible(perch, neighbours, ctx.exclusions)
            return ev.evaluate(perch.camera_position, perch.camera_rotation, perch.zoom, ok)

        x, _, _ = polish(objective, x, float(objective(x[None])[0]), ctx.rng, rounds, samples)
        encodings[i] = x
        perches[i] = plane.decode(x)
        views[i] = _views(ev, perches[i])
    return encodings


def _views(ev: Evaluator, perch: Perch):
    return ev.views(perch.camera_position, perch.camera_rotation, perch.zoom)


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
