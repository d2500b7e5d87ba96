"""Local-best particle swarm optimisation over [0,1]^D, maximising a batched objective.

The objective takes the whole swarm (P,D) and returns (P,) fitness: one call per generation.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from perch_common.cancellation import checkpoint
from perch_placement.config import PsoConfig


@dataclass
class SwarmResult:
    """The swarm's best position and fitness, and what it took to find them."""

    best: np.ndarray          # (D,) best position found
    fitness: float
    evaluations: int
    generations: int
    history: list             # best fitness after each generation


def local_best_pso(objective: Callable[[np.ndarray], np.ndarray], dims: int, cfg: PsoConfig,
                   rng: np.random.Generator, initial: np.ndarray | None = None) -> SwarmResult:
    """Swarm with neighbourhoods of the k nearest particles, reflective bounds and early stop when the
    best fitness gains less than `tolerance` over `patience` generations. `initial` (M,D) seeds the
    first M particles (the rest are uniform random)."""
    n = cfg.particles
    x = rng.random((n, dims))
    v = rng.uniform(-cfg.initial_speed, cfg.initial_speed, (n, dims))
    if initial is not None and len(initial):
        m = min(len(initial), n)
        x[:m] = np.clip(initial[:m], 0, 1)
        v[:m] *= cfg.seeded_speed  # seeded particles search near their start first
    f = objective(x)
    p_best, p_fit = x.copy(), f.copy()
    history = [float(p_fit.max())]
    k = min(max(cfg.neighbours, 1), n)
    generation = 1
    while generation < cfg.iterations:
        checkpoint(f"swarm generation {generation}")
        # The k nearest particles (self included) share their best position.
        d2 = ((x[:, None, :] - x[None, :, :]) ** 2).sum(-1)
        hood = np.argpartition(d2, k - 1, axis=1)[:, :k] if k < n else np.tile(np.arange(n), (n, 1))
        leader = hood[np.arange(n), np.argmax(p_fit[hood], axis=1)]
        r1, r2 = rng.random((2, n, dims))
        v = cfg.inertia * v + cfg.cognitive * r1 * (p_best - x) + cfg.social * r2 * (p_best[leader] - x)
        x = x + v
        over, under = x > 1, x < 0
        x = np.where(over, 2 - x, np.where(under, -x, x))
        v = np.where(over | under, -v, v)
        x = np.clip(x, 0, 1)
        f = objective(x)
        better = f > p_fit
        p_best[better], p_fit[better] = x[better], f[better]
        history.append(float(p_fit.max()))
        generation += 1
        if len(history) > cfg.patience and history[-1] - history[-1 - cfg.patience] < cfg.tolerance:
            break
    i = int(np.argmax(p_fit))
    return SwarmResult(p_best[i].copy(), float(p_fit[i]), generation * n, generation, history)
