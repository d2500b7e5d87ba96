"""Greedy PSO, the default search: one local-best swarm per camera, part of it seeded at the best
discrete candidates, its best polished by hill climbing."""

from __future__ import annotations

import numpy as np

from perch_placement.candidates import CandidateGreedy
from perch_placement.search.context import SearchContext, SearchOutcome, candidate_encoding, greedy, polish
from perch_placement.search.swarm import local_best_pso


def greedy_pso(ctx: SearchContext, k: int) -> SearchOutcome:
    """Place k cameras one at a time, each with its own swarm."""
    return greedy(ctx, k, _best_camera)


def _best_camera(ctx: SearchContext) -> tuple[np.ndarray, float]:
    pso = ctx.config.pso
    initial = _seeds(ctx) if pso.seeded > 0 else None
    swarm = local_best_pso(ctx.objective, ctx.perches.dims, pso, ctx.rng, initial)
    x, f, _ = polish(ctx.objective, swarm.best, swarm.fitness, ctx.rng, pso.polish_rounds, pso.polish_samples,
                     pso.polish_step)
    alternative = ctx.alternative_objective()
    if alternative is not None:
        x = _alternative_choice(ctx, alternative, swarm, x)
        f = float(ctx.objective(x[None])[0])
    return x, f


ALTERNATIVES = 8  # the swarm's best particles re-scored under another objective


def _alternative_choice(ctx: SearchContext, objective, swarm, polished: np.ndarray) -> np.ndarray:
    """The camera the configured non-nominal objective prefers: the nominal search's polished best and
    its swarm's best particles are re-scored under it, and the best of them is polished under it
    (half the nominal polish). The nominal swarm finds the good perches; the other objective chooses
    among them and adjusts the pose, at a fraction of a second swarm's cost."""
    pso = ctx.config.pso
    order = np.argsort(-swarm.personal_fitness, kind="stable")[:ALTERNATIVES]
    options = np.vstack([polished[None], swarm.personal_best[order]]) if len(order) else polished[None]
    score = objective(options)
    j = int(np.argmax(score))
    x, _, _ = polish(objective, options[j], float(score[j]), ctx.rng, max(1, pso.polish_rounds // 2),
                     max(1, pso.polish_samples // 2), pso.polish_step)
    return x


def _seeds(ctx: SearchContext) -> np.ndarray | None:
    """Encodings of the best candidates (best orientation at each of the top positions) for the next
    camera, to start part of the swarm from; None in the mesh encoding."""
    if ctx.perches.encoding != "plane":
        return None
    cands = ctx.candidates()
    if cands.positions == 0:
        return None
    state = CandidateGreedy(cands, ctx.evaluator.info, ctx.evaluator.seen, 0.0)
    where = cands.drone_positions()
    placed = np.array(ctx.others[ctx.fixed_count:]).reshape(-1, 3)
    valid = np.ones(len(where), bool)
    if len(placed):
        gap = np.linalg.norm(where[:, None] - placed[None], axis=-1).min(axis=1)
        valid = gap >= ctx.config.drone.min_spacing
    pos = np.flatnonzero(valid)
    if len(pos) == 0:
        return None
    gains = state.gains(pos)
    ctx.evaluator.candidate_evaluations += state.evaluations
    best_orientation = np.argmax(gains, axis=1)
    order = _diverse_top(gains.max(axis=1), cands.perch.region[pos * cands.orientations], ctx.config.pso.seeded)
    seeds = []
    for i in order:
        index = int(pos[i]) * cands.orientations + int(best_orientation[i])
        seeds.append(candidate_encoding(ctx.plane, cands, index))
    return np.array(seeds)


def _diverse_top(gain: np.ndarray, region: np.ndarray, count: int) -> np.ndarray:
    """Indices of the best position on each region (best regions first), then the best remaining."""
    order = np.argsort(-gain, kind="stable")
    _, first = np.unique(region[order], return_index=True)
    leaders = order[np.sort(first)]
    leaders = leaders[gain[leaders] > 0]
    rest = order[~np.isin(order, leaders)]
    return np.concatenate([leaders, rest])[:count]
