"""CELF: lazy greedy over the discrete candidate set, then continuous refinement of each camera.

The lazy step re-scores only the candidates whose stale gains could still win, which is exact for
submodular objectives; fusion is not submodular, so gains that grew are caught by re-scoring in
doubling blocks until a fresh gain beats every stale bound.
"""

from __future__ import annotations

import numpy as np

from perch_common.work import steps
from perch_placement.candidates import CandidateGreedy, GreedyPick
from perch_placement.perches import Perches
from perch_placement.search.context import SearchContext, SearchOutcome, candidate_encoding, commit, no_gain_reason, polish

LAZY_BLOCK = 64  # candidates re-scored in the first round of a lazy step (doubling after)


def celf(ctx: SearchContext, k: int) -> SearchOutcome:
    """Lazy greedy over the discrete candidate set, then continuous refinement of each camera."""
    plane = ctx.plane
    cfg = ctx.config
    fixed = np.array(ctx.others).reshape(-1, 3)
    cands = ctx.candidates()
    if len(cands) == 0:
        return SearchOutcome([], "no candidate perch is feasible (regions, spacing, exclusion zones)")
    base_info, base_seen = ctx.evaluator.info.copy(), ctx.evaluator.seen.copy()
    pick = lazy_greedy(CandidateGreedy(cands, base_info, base_seen, cfg.drone.min_spacing), k)
    ctx.evaluator.candidate_evaluations += pick.evaluations
    encodings = [candidate_encoding(plane, cands, index) for index in pick.chosen]
    encodings = _refine(ctx, plane, encodings, base_info, base_seen, fixed)
    ctx.evaluator.set_state(base_info, base_seen)
    chosen = [plane.decode(x) for x in encodings]
    for perch in chosen:
        commit(ctx, perch)
    reason = "" if len(chosen) == k else no_gain_reason(ctx, len(chosen))
    return SearchOutcome(chosen, reason)


def lazy_greedy(state: CandidateGreedy, k: int, block: int = LAZY_BLOCK) -> GreedyPick:
    """Up to k candidates by lazy greedy: the first step scores every candidate, later ones lazily."""
    chosen, gains = [], []
    bounds = None
    for _ in steps(range(k), "camera"):
        picked = _lazy_step(state, bounds, block) if bounds is not None else None
        if picked is None:
            pos = np.flatnonzero(state.valid)
            if len(pos) == 0:
                break
            g = np.full((state.c.positions, state.c.orientations), -np.inf)
            g[pos] = state.gains(pos)
            bounds = g.reshape(-1)
            best = int(np.argmax(bounds))
            if not bounds[best] > 0:
                break
            picked = (best, state.add(best))
        chosen.append(picked[0])
        gains.append(picked[1])
    return GreedyPick(chosen, gains, state.evaluations)


def _lazy_step(state: CandidateGreedy, bounds: np.ndarray, block: int) -> tuple[int, float] | None:
    """Re-score the candidates with the highest stale gains in blocks until a freshly scored one beats
    every stale bound; add it. None when no fresh gain is positive (the caller then scores all)."""
    a = state.c.orientations
    valid = np.repeat(state.valid, a)
    bounds[~valid] = -np.inf
    fresh = np.zeros(len(bounds), bool)
    while True:
        stale = np.where(fresh, -np.inf, bounds)
        best_fresh = np.max(np.where(fresh, bounds, -np.inf))
        top = np.argpartition(-stale, min(block, len(stale) - 1))[:block]
        top = top[np.isfinite(stale[top])]
        if len(top) == 0 or best_fresh >= stale[top].max():
            break
        p, o = np.divmod(top, a)
        upos, inv = np.unique(p, return_inverse=True)
        delta = state.point_gains(upos)
        bounds[top] = (state.c.visible[p, o] * delta[inv]).sum(-1) / len(state.scores)
        state.evaluations += len(top)
        fresh[top] = True
        block *= 2  # gains that grew (fusion is not submodular) can take many rounds
    best = int(np.argmax(np.where(fresh, bounds, -np.inf)))
    if not fresh[best] or not bounds[best] > 0:
        return None
    return best, state.add(best)


def _refine(ctx: SearchContext, plane: Perches, encodings: list, base_info, base_seen, fixed) -> list:
    """Coordinate-wise hill climbing of each camera (position within its region, pan, tilt) with the
    others fixed: batched Gaussian steps, the step shrinking whenever a round brings no gain."""
    ev = ctx.evaluator
    pso = ctx.config.pso
    perches = [plane.decode(x) for x in encodings]
    views = [ev.views(p.camera_position, p.camera_rotation, p.zoom) for p in perches]
    for i, x in enumerate(encodings):
        others = [j for j in range(len(encodings)) if j != i]
        ev.set_state(base_info + sum((views[j][1][0] for j in others), np.zeros_like(base_info)),
                     base_seen | np.any([views[j][0][0] for j in others] or [np.zeros_like(base_seen)], axis=0))
        neighbours = np.vstack([fixed] + [perches[j].drone_position for j in others])

        def objective(batch: np.ndarray) -> np.ndarray:
            perch = plane.decode(batch)
            ok = plane.feasible(perch, neighbours, ctx.exclusions)
            return ev.evaluate(perch.camera_position, perch.camera_rotation, perch.zoom, ok)

        x, _, _ = polish(objective, x, float(objective(x[None])[0]), ctx.rng, ctx.config.refine_rounds,
                         pso.polish_samples, pso.polish_step)
        encodings[i] = x
        perches[i] = plane.decode(x)
        views[i] = ev.views(perches[i].camera_position, perches[i].camera_rotation, perches[i].zoom)
    return encodings

