"""The greedy baselines of the original's Table 7: per camera, the best of uniform random samples or
of a regular grid, with the swarm's evaluation budget."""

from __future__ import annotations

import numpy as np

from perch_placement.search.context import SearchContext, SearchOutcome, greedy, per_camera_budget

GRID_BATCH = 512  # grid points scored per objective call (bounds memory)


def greedy_random(ctx: SearchContext, k: int) -> SearchOutcome:
    """Place k cameras one at a time, each the best of random encodings."""
    return greedy(ctx, k, _best_random)


def greedy_grid(ctx: SearchContext, k: int) -> SearchOutcome:
    """Place k cameras one at a time, each the best point of a regular grid over the encoding."""
    return greedy(ctx, k, _best_grid)


def _best_random(ctx: SearchContext) -> tuple[np.ndarray | None, float]:
    budget = per_camera_budget(ctx.config)
    best_x, best_f = None, -1.0
    batch = ctx.config.pso.particles
    for start in range(0, budget, batch):
        x = ctx.rng.random((min(batch, budget - start), ctx.perches.dims))
        f = ctx.objective(x)
        i = int(np.argmax(f))
        if f[i] > best_f:
            best_x, best_f = x[i], float(f[i])
    return best_x, best_f


def _best_grid(ctx: SearchContext) -> tuple[np.ndarray, float]:
    x = grid_points(ctx.perches.dims, per_camera_budget(ctx.config))
    f = np.concatenate([ctx.objective(x[i:i + GRID_BATCH]) for i in range(0, len(x), GRID_BATCH)])
    i = int(np.argmax(f))
    return x[i], float(f[i])


def grid_points(dims: int, budget: int) -> np.ndarray:
    """A regular grid of cell centres over [0,1]^dims with at most `budget` points."""
    counts = np.ones(dims, int)
    d = 0
    while True:
        trial = counts.copy()
        trial[d % dims] += 1
        if np.prod(trial) > budget:
            break
        counts, d = trial, d + 1
    axes = [(np.arange(n) + 0.5) / n for n in counts]
    return np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, dims)
