"""Search methods: greedy (PSO, random, grid per camera) and naive all-at-once PSO (CELF and the
exhaustive reference: perch_placement.celf). Each returns the chosen perches in placement order."""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from perch_common.types import ExclusionZone
from perch_placement.candidates import CandidateGreedy, CandidateSet, cached_candidates
from perch_placement.config import PlacementConfig
from perch_placement.fitness import Evaluator
from perch_placement.perches import Perch, Perches
from perch_placement.pso import local_best_pso

METHODS = ("pso", "celf", "random", "grid", "naive")


@dataclass
class SearchContext:
    perches: Perches
    evaluator: Evaluator           # holds the fixed cameras' information
    config: PlacementConfig
    rng: np.random.Generator
    exclusions: tuple[ExclusionZone, ...] = ()
    others: list = field(default_factory=list)  # drone positions already perched (fixed, then added)
    fixed_count: int = 0                         # how many of `others` are fixed drones
    _candidates: CandidateSet | None = None
    _plane: Perches | None = None

    @property
    def plane(self) -> Perches:
        """The regions in the plane encoding (candidate sets and refinement work in it)."""
        if self._plane is None:
            p = self.perches
            self._plane = p if p.encoding == "plane" else Perches(
                p.regions, p.target_centre, p.drone, p.up, "plane", p.max_zoom)
        return self._plane

    def candidates(self) -> CandidateSet:
        """The discrete candidate set (built once; excludes exclusion zones and the fixed drones' spacing)."""
        if self._candidates is None:
            cfg = self.config
            fixed = np.array(self.others[:self.fixed_count]).reshape(-1, 3)
            self._candidates = cached_candidates(self.plane, self.evaluator, cfg.candidate_spacing,
                                                 cfg.candidate_angles, self.exclusions, fixed)
        return self._candidates

    def objective(self, x: np.ndarray) -> np.ndarray:
        perch = self.perches.decode(x)
        ok = self.perches.feasible(perch, np.array(self.others).reshape(-1, 3), self.exclusions)
        return self.evaluator.evaluate(perch.camera_position, perch.camera_rotation, perch.zoom, ok)


@dataclass
class SearchOutcome:
    perches: list                   # Perch of one camera each, in placement order
    stop_reason: str = ""           # why fewer cameras than asked were placed ("" if all)


def commit(ctx: SearchContext, perch: Perch) -> None:
    ctx.evaluator.commit(perch.camera_position, perch.camera_rotation, perch.zoom)
    ctx.others.append(perch.drone_position[0])


def no_gain_reason(ctx: SearchContext, placed: int) -> str:
    if placed == 0 and not ctx.evaluator.seen.any():
        return "the target is not visible from any feasible perch on the given regions"
    return (f"no feasible perch adds fitness (min spacing {ctx.config.drone.min_spacing:g} m, "
            f"{len(ctx.exclusions)} exclusion zone(s))")


def per_camera_budget(cfg: PlacementConfig) -> int:
    """The evaluations baselines get per camera: the swarm's maximum (particles x iterations)."""
    return cfg.pso.particles * cfg.pso.iterations


def _random_search(ctx: SearchContext, budget: int) -> tuple[np.ndarray, float]:
    best_x, best_f = None, -1.0
    batch = ctx.config.pso.particles
    for start in range(0, budget, batch):
        x = ctx.rng.random((min(batch, budget - start), ctx.perches.dims))
        f = ctx.objective(x)
        i = int(np.argmax(f))
        if f[i] > best_f:
            best_x, best_f = x[i], float(f[i])
    return best_x, best_f


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


def _grid_search(ctx: SearchContext, budget: int) -> tuple[np.ndarray, float]:
    x = grid_points(ctx.perches.dims, budget)
    f = np.concatenate([ctx.objective(x[i:i + 512]) for i in range(0, len(x), 512)])
    i = int(np.argmax(f))
    return x[i], float(f[i])


def greedy(ctx: SearchContext, k: int, method: str) -> SearchOutcome:
    """One camera at a time, each search seeing the ones placed before."""
    budget = per_camera_budget(ctx.config)
    chosen = []
    for _ in range(k):
        before = float(ctx.evaluator.current().fitness)
        if method == "pso":
            initial = _seeds(ctx) if ctx.config.pso.seeded > 0 else None
            swarm = local_best_pso(ctx.objective, ctx.perches.dims, ctx.config.pso, ctx.rng, initial)
            x, f, _ = polish(ctx.objective, swarm.best, swarm.fitness, ctx.rng, ctx.config.pso.polish_rounds)
        elif method == "random":
            x, f = _random_search(ctx, budget)
        elif method == "grid":
            x, f = _grid_search(ctx, budget)
        else:
            raise ValueError(f"unknown greedy method '{method}'")
        if x is None or not f > before + 1e-12:
            return SearchOutcome(chosen, no_gain_reason(ctx, len(chosen)))
        perch = ctx.perches.decode(x)
        commit(ctx, perch)
        chosen.append(perch)
    return SearchOutcome(chosen)


def polish(objective, x: np.ndarray, fitness: float, rng: np.random.Generator, rounds: int,
           samples: int = 32, step: float = 0.05) -> tuple[np.ndarray, float, int]:
    """Batched hill climbing from x (region selector kept): Gaussian steps in [0,1]^D, the step
    halving whenever a round brings no gain. Returns (x, fitness, evaluations)."""
    evaluations = 0
    for _ in range(rounds):
        trial = np.clip(x + rng.normal(0.0, step, (samples, len(x))), 0.0, 1.0)
        trial[:, 0] = x[0]  # stay on the same region
        f = objective(trial)
        evaluations += samples
        j = int(np.argmax(f))
        if f[j] > fitness:
            x, fitness = trial[j], float(f[j])
        else:
            step *= 0.5
    return x, fitness, evaluations


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


def candidate_encoding(plane: Perches, cands: CandidateSet, index: int) -> np.ndarray:
    region = int(cands.perch.region[index])
    x = plane.encode_position(region, cands.perch.drone_position[index])
    zoom = [0.0] if plane.max_zoom > 1 else []
    return np.concatenate([x, cands.gimbal[index % cands.orientations], zoom])


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
