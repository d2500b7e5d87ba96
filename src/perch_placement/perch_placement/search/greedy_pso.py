"""Greedy PSO, the default search: one local-best swarm per camera, part of it seeded at the best
discrete candidates, its best polished by hill climbing."""

from __future__ import annotations

import numpy as np

from perch_placement.perches import Perch, Perches
from perch_placement.robustness import KViewState
from perch_placement.search.context import (
    SearchContext,
    SearchOutcome,
    _restore,
    candidate_encoding,
    greedy,
    perch_arrangement,
    polish,
)
from perch_placement.search.swarm import local_best_pso


def greedy_pso(ctx: SearchContext, k: int) -> SearchOutcome:
    """Place k cameras one at a time, each with its own swarm; each camera is then refined under the
    objective with the others fixed."""
    base = (ctx.evaluator.info, ctx.evaluator.seen, list(ctx.others))
    return refine(ctx, greedy(ctx, k, _best_camera), base)


REFINE_ROUNDS, REFINE_SAMPLES = 3, 16  # hill climbing per camera under the objective


def refine(ctx: SearchContext, outcome: SearchOutcome, base: tuple) -> SearchOutcome:
    """Each chosen camera polished (position and gimbal, same region) under the configured objective
    with every other camera fixed: coordinate ascent on the whole arrangement's objective (greedy
    chose each camera seeing only the ones before it). Under the nominal fitness a move must also keep
    the arrangement's k-view coverage: unconstrained, the ascent traded it away (apartment 2-view
    90.7 -> 89.2 %). Plane encoding only; leaves the evaluator holding the answer."""
    if not outcome.perches or ctx.perches.encoding != "plane":
        return outcome
    plane, pso = ctx.perches, ctx.config.pso
    encodings = [encode_perch(plane, p) for p in outcome.perches]
    perches = [plane.decode(e) for e in encodings]   # decoded once: their views are kept (perch_views)
    for i in range(len(encodings)):
        _restore(ctx, base, [p for n, p in enumerate(perches) if n != i])
        if ctx.config.objective == "fitness":
            objective = fitness_keeping_kview(ctx, encodings[i])
        else:
            objective = ctx.alternative_objective()
        start = float(objective(encodings[i][None])[0])
        encodings[i], _, _ = polish(objective, encodings[i], start, ctx.rng, REFINE_ROUNDS, REFINE_SAMPLES,
                                    pso.polish_step)
        perches[i] = plane.decode(encodings[i])
    _restore(ctx, base, perches)
    return SearchOutcome(perches, outcome.stop_reason)


def fitness_keeping_kview(ctx: SearchContext, current: np.ndarray):
    """Fitness (B,) of one more camera on top of the committed ones at each encoding, -1 where the
    perch is infeasible or the arrangement's k-view coverage falls below the one with the camera at
    `current` (so hill climbing never takes such a move)."""
    cfg, evaluator = ctx.config, ctx.evaluator
    kview = KViewState(evaluator, ctx.arrangement(), cfg.kview_k, cfg.kview_angle_deg)

    def scores(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        perch = ctx.perches.decode(x)
        ok = np.flatnonzero(ctx.perches.feasible(perch, np.array(ctx.others).reshape(-1, 3), ctx.exclusions))
        fitness, coverage = np.full(len(perch), -1.0), np.zeros(len(perch))
        if len(ok):
            cameras = perch_arrangement(perch.take(ok))
            seen, info = evaluator.views(cameras.camera_position, cameras.camera_rotation, cameras.zoom)
            evaluator.evaluations += len(ok)
            fitness[ok] = evaluator.score(evaluator.info[None] + info, evaluator.seen[None] | seen).fitness
            coverage[ok] = kview.coverage(cameras, seen)
        return fitness, coverage

    floor = float(scores(current[None])[1][0]) - 1e-9

    def objective(x: np.ndarray) -> np.ndarray:
        fitness, coverage = scores(x)
        return np.where(coverage >= floor, fitness, -1.0)
    return objective


def encode_perch(plane: Perches, perch: Perch) -> np.ndarray:
    """The plane encoding of one decoded perch (decode(encode_perch(p)) is p to rounding)."""
    region = int(perch.region[0])
    x = plane.encode_position(region, perch.drone_position[0])
    window = plane.gimbal_window(perch.camera_position, perch.drone_rotation)[0]
    coords = [(a - lo) / (hi - lo) if hi > lo else 0.5
              for a, lo, hi in ((perch.pan[0], window[0], window[1]), (perch.tilt[0], window[2], window[3]))]
    zoom = [(perch.zoom[0] - 1.0) / (plane.max_zoom - 1.0)] if plane.max_zoom > 1 else []
    return np.clip(np.concatenate([x, coords, zoom]), 0.0, 1.0)


# Objectives cheap enough for the swarm itself (one more visibility test per camera); `expected`
# (one per landing sample) only refines the nominal answer.
SWARM_OBJECTIVES = ("kview", "worst_case")


def _best_camera(ctx: SearchContext) -> tuple[np.ndarray, float]:
    pso = ctx.config.pso
    initial = _seeds(ctx) if pso.seeded > 0 else None
    objective = ctx.alternative_objective() if ctx.config.objective in SWARM_OBJECTIVES else ctx.objective
    swarm = local_best_pso(objective, ctx.perches.dims, pso, ctx.rng, initial)
    x, f, _ = polish(objective, swarm.best, swarm.fitness, ctx.rng, pso.polish_rounds, pso.polish_samples,
                     pso.polish_step)
    if objective is not ctx.objective:
        f = float(ctx.objective(x[None])[0])  # the greedy loop stops on the nominal fitness
    return x, f


def _seeds(ctx: SearchContext) -> np.ndarray | None:
    """Encodings of the best candidates (best orientation at each of the top positions) for the next
    camera, to start part of the swarm from; None in the mesh encoding."""
    if ctx.perches.encoding != "plane":
        return None
    cands = ctx.candidates()
    if cands.positions == 0:
        return None
    pos = np.flatnonzero(ctx.spaced_candidates(np.array(ctx.others[ctx.fixed_count:])))
    if len(pos) == 0:
        return None
    gains = ctx.candidate_gains(pos)
    ctx.evaluator.candidate_evaluations += gains.size
    best_orientation = np.argmax(gains, axis=1)
    order = _diverse_top(gains.max(axis=1), cands.region[pos], ctx.config.pso.seeded)
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
