"""Naive PSO: all k cameras at once in one swarm (the original's baseline for the greedy search)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from perch_placement.search.context import SearchContext, SearchOutcome, commit, no_gain_reason, per_camera_budget
from perch_placement.search.swarm import local_best_pso


def naive_pso(ctx: SearchContext, k: int) -> SearchOutcome:
    """All k cameras at once in one swarm over [0,1]^(k*D), with the greedy searches' total budget."""
    dims = ctx.perches.dims
    fixed = np.array(ctx.others).reshape(-1, 3)
    spacing = ctx.config.drone.min_spacing

    def objective(x: np.ndarray) -> np.ndarray:
        b = len(x)
        perch = ctx.perches.decode(x.reshape(b * k, dims))
        ok = ctx.perches.feasible(perch, fixed, ctx.exclusions).reshape(b, k)
        drones = perch.drone_position.reshape(b, k, 3)
        gap = np.linalg.norm(drones[:, :, None] - drones[:, None], axis=-1) + np.eye(k) * 1e9
        feasible = ok.all(axis=1) & (gap.min(axis=(1, 2)) >= spacing)
        return ctx.evaluator.evaluate_arrangements(
            perch.camera_position.reshape(b, k, 3), perch.camera_rotation.reshape(b, k, 3, 3),
            perch.zoom.reshape(b, k), feasible)

    # The greedy searches' total budget, all of it (no early stop: equal budgets).
    cfg = replace(ctx.config.pso, iterations=max(1, k * per_camera_budget(ctx.config) // ctx.config.pso.particles),
                  tolerance=-np.inf)
    swarm = local_best_pso(objective, k * dims, cfg, ctx.rng)
    if not swarm.fitness > float(ctx.evaluator.current().fitness):
        return SearchOutcome([], no_gain_reason(ctx, 0))
    perches = ctx.perches.decode(swarm.best.reshape(k, dims))
    chosen = [perches.take([i]) for i in range(k)]
    for perch in chosen:
        commit(ctx, perch)
    return SearchOutcome(chosen)
