"""What every search shares: the search context (perches, evaluator, configuration, seeded generator),
the outcome, the greedy one-camera-at-a-time loop, committing a camera and hill-climbing polish."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from perch_common.types import ExclusionZone
from perch_common.work import steps
from perch_placement.cache import PlacementCache
from perch_placement.candidates import CandidateGreedy, CandidateSet, GainMemo, cached_candidates
from perch_placement.config import PlacementConfig
from perch_placement.fitness import Evaluator
from perch_placement.perches import Perch, Perches
from perch_placement.robustness import Arrangement, KViewState, LandingSampler, RobustState, worst_loss_coverage


@dataclass
class SearchContext:
    """One search's problem and state: the perches, the evaluator holding the committed cameras,
    the configuration and the seeded generator every random choice draws from."""

    perches: Perches
    evaluator: Evaluator           # holds the fixed cameras' information
    config: PlacementConfig
    rng: np.random.Generator
    exclusions: tuple[ExclusionZone, ...] = ()
    others: list = field(default_factory=list)  # drone positions already perched (fixed, then added)
    fixed_count: int = 0                         # how many of `others` are fixed drones
    cache: PlacementCache | None = None          # keeps the unconstrained candidate set between requests
    scene_key: str = ""                          # content digest of the scene's mesh (cache key)
    fixed_cameras: Arrangement | None = None     # the fixed cameras (the robust and k-view objectives use them)
    placed: list = field(default_factory=list)   # Perch of each camera committed by the search, in order
    _candidates: CandidateSet | None = None
    _gains: GainMemo | None = None
    _views: dict = field(default_factory=dict)   # id(perch) -> (perch, its views): re-commits cast no rays
    _spaced: dict = field(default_factory=dict)  # drone position bytes -> candidate positions far enough
    _plane: Perches | None = None

    @property
    def plane(self) -> Perches:
        """The regions in the plane encoding (candidate sets and refinement work in it)."""
        if self._plane is None:
            p = self.perches
            self._plane = p if p.encoding == "plane" else Perches(
                p.regions, p.target_centre, p.drone, p.up, "plane", p.max_zoom, self.config.border_margin)
        return self._plane

    def candidates(self) -> CandidateSet:
        """The discrete candidate set (built once; excludes exclusion zones and the fixed drones' spacing)."""
        if self._candidates is None:
            cfg = self.config
            fixed = np.array(self.others[:self.fixed_count]).reshape(-1, 3)
            self._candidates = cached_candidates(self.plane, self.evaluator, cfg.candidate_spacing,
                                                 cfg.candidate_angles, self.exclusions, fixed,
                                                 self.cache, self.scene_key)
        return self._candidates

    def candidate_gains(self, positions: np.ndarray | None = None) -> np.ndarray:
        """(P',A) marginal gains of the candidates at `positions` (default: all) on the committed cameras
        (kept between calls: only positions whose points changed are scored again)."""
        if self._gains is None:
            self._gains = GainMemo(self.candidates())
        return self._gains.gains(self.evaluator.info, self.evaluator.seen, positions)

    def perch_views(self, perch: Perch) -> tuple[np.ndarray, np.ndarray]:
        """The evaluator's views of a decoded perch (kept while the context lives: searches that restore
        a state commit the same perches again)."""
        hit = self._views.get(id(perch))
        if hit is None or hit[0] is not perch:
            hit = self._views[id(perch)] = (perch, self.evaluator.views(perch.camera_position, perch.camera_rotation,
                                                                        perch.zoom))
        return hit[1]

    def spaced_candidates(self, drones: np.ndarray) -> np.ndarray:
        """(P,) candidate positions at least min_spacing from every drone position in `drones` (K,3)
        (each drone's test kept: the greedy loop asks again with one more drone per camera)."""
        where = self.candidates().drone_positions()
        valid = np.ones(len(where), bool)
        for drone in np.asarray(drones, np.float64).reshape(-1, 3):
            key = drone.tobytes()
            if key not in self._spaced:
                self._spaced[key] = np.linalg.norm(where - drone, axis=-1) >= self.config.drone.min_spacing
            valid &= self._spaced[key]
        return valid

    def online_bound(self, k: int) -> float:
        """The greedy online bound for k cameras on the candidate set, from the committed cameras."""
        state = CandidateGreedy(self.candidates(), self.evaluator.info, self.evaluator.seen,
                                self.config.drone.min_spacing)
        return state.online_bound(k, self.candidate_gains() if self.candidates().positions else None)

    def arrangement(self) -> Arrangement:
        """The committed cameras (fixed, then placed) as one arrangement."""
        parts = ([self.fixed_cameras] if self.fixed_cameras is not None else []) + \
            [perch_arrangement(p) for p in self.placed]
        if not parts:
            return Arrangement(np.zeros((0, 3)), np.zeros((0, 3, 3)), np.zeros(0), np.zeros((0, 3, 3)))
        return Arrangement(*(np.concatenate([getattr(a, f) for a in parts]) for f in
                             ("camera_position", "camera_rotation", "zoom", "drone_rotation")))

    def alternative_objective(self) -> Callable[[np.ndarray], np.ndarray] | None:
        """The configured objective other than the nominal fitness, for one more camera on top of the
        committed ones (None for `fitness`): `expected` fitness under landing error (common random
        numbers, landing.search_samples landings), fitness + kview_weight x k-view coverage (`kview`),
        or fitness + resilience_weight x coverage after losing the worst camera (`worst_case`)."""
        cfg = self.config
        if cfg.objective == "fitness":
            return None
        committed = self.arrangement()
        if cfg.objective == "expected":
            land = cfg.landing
            # Its own stream (not the assessment's draws): the reported figures are not the ones it fitted.
            sampler = LandingSampler(land.position_sigma, land.yaw_sigma_deg, land.search_samples,
                                     [land.seed, SEARCH_STREAM], land.gimbal_reaim, cfg.drone.pan_range_deg,
                                     cfg.drone.tilt_range_deg)
            state = RobustState(self.evaluator, sampler, committed)

            def extra(cands: Arrangement) -> np.ndarray:
                return state.fitness(cands).mean(axis=0)
        elif cfg.objective == "kview":
            kview = KViewState(self.evaluator, committed, cfg.kview_k, cfg.kview_angle_deg)

            def extra(cands: Arrangement) -> np.ndarray:
                return self.objective_nominal(cands) + cfg.kview_weight * kview.coverage(cands)
        else:
            def extra(cands: Arrangement) -> np.ndarray:
                return self.objective_nominal(cands) + cfg.resilience_weight * worst_loss_coverage(
                    self.evaluator, committed, cands)

        def objective(x: np.ndarray) -> np.ndarray:
            perch = self.perches.decode(x)
            ok = self.perches.feasible(perch, np.array(self.others).reshape(-1, 3), self.exclusions)
            out = np.zeros(len(perch))
            if ok.any():
                out[ok] = extra(perch_arrangement(perch.take(np.flatnonzero(ok))))
            return out
        return objective

    def objective_nominal(self, cands: Arrangement) -> np.ndarray:
        """Fitness (B,) of adding each camera of an arrangement to the committed ones."""
        return self.evaluator.evaluate(cands.camera_position, cands.camera_rotation, cands.zoom)

    def objective(self, x: np.ndarray) -> np.ndarray:
        """Fitness (B,) of adding one camera at each encoding x (B,D); infeasible perches score 0."""
        perch = self.perches.decode(x)
        ok = self.perches.feasible(perch, np.array(self.others).reshape(-1, 3), self.exclusions)
        return self.evaluator.evaluate(perch.camera_position, perch.camera_rotation, perch.zoom, ok)


@dataclass
class SearchOutcome:
    """The chosen perches, in placement order, and why fewer than asked were placed."""

    perches: list                   # Perch of one camera each, in placement order
    stop_reason: str = ""           # why fewer cameras than asked were placed ("" if all)


SEARCH_STREAM = 1  # the robust search draws its landings from this stream of the landing seed

SPACING_SLACK = 1e-3  # m added to the packing's spacing: decoded positions round by far less

# One camera's search: the best encoding found (None if none) and its fitness.
CameraSearch = Callable[[SearchContext], tuple[np.ndarray | None, float]]


def greedy(ctx: SearchContext, k: int, best_camera: CameraSearch) -> SearchOutcome:
    """One camera at a time, each search seeing the ones placed before; stops when none adds fitness.
    When that leaves cameras unplaced although the regions hold more drones, `packed_greedy` tries
    again on a packing of the regions and its answer is taken if it places more cameras."""
    base = (ctx.evaluator.info, ctx.evaluator.seen, list(ctx.others))
    chosen: list[Perch] = []
    for _ in steps(range(k), "camera"):
        before = float(ctx.evaluator.current().fitness)
        x, f = best_camera(ctx)
        if x is None or not f > before + 1e-12:
            packed = packed_greedy(ctx, k, base, len(chosen))
            if len(packed) > len(chosen):
                return SearchOutcome(packed, no_gain_reason(ctx, len(packed)) if len(packed) < k else "")
            _restore(ctx, base, chosen)
            return SearchOutcome(chosen, no_gain_reason(ctx, len(chosen)))
        perch = ctx.perches.decode(x)
        commit(ctx, perch)
        chosen.append(perch)
    return SearchOutcome(chosen)


def packed_greedy(ctx: SearchContext, k: int, base: tuple, placed: int = 0) -> list[Perch]:
    """Up to k cameras on the positions of a packing of the regions (min_spacing apart), chosen
    greedily by fitness with the best of candidate_angles x candidate_angles gimbal settings, each
    polished in its gimbal, then each polished in position and gimbal with the others fixed.

    Greedy placement under a minimum spacing can strand room: on a small region the first drones
    sit where each alone sees best and leave no spot min_spacing from all of them, although the
    region holds more. Starting from a packing keeps room for every camera. Leaves the evaluator
    holding the answer (plane encoding only; [] otherwise, and [] without touching the evaluator when
    the packing holds no more than the `placed` cameras greedy found; [] with the evaluator holding the
    base state as soon as it cannot place more than them: the caller keeps greedy's answer then)."""
    if ctx.perches.encoding != "plane":
        return []
    plane, cfg = ctx.perches, ctx.config
    region, points = plane.packing(cfg.drone.min_spacing + SPACING_SLACK)
    if len(points) <= placed:
        return []
    steps = np.linspace(0.0, 1.0, cfg.candidate_angles) if cfg.candidate_angles > 1 else np.array([0.5])
    gimbal = np.array([(a, b) for a in steps for b in steps])
    if plane.max_zoom > 1:
        gimbal = np.column_stack([gimbal, np.zeros(len(gimbal))])
    positions = np.array([plane.encode_position(int(r), p) for r, p in zip(region, points)]).reshape(-1, 3)
    _restore(ctx, base, [])
    encodings: list[np.ndarray] = []
    free = np.ones(len(positions), bool)
    while len(encodings) < k and free.any():
        if len(encodings) + free.sum() <= placed:
            break  # cannot place more than greedy did: the caller keeps greedy's answer
        spots = np.flatnonzero(free)
        x = np.column_stack([np.repeat(positions[spots], len(gimbal), axis=0), np.tile(gimbal, (len(spots), 1))])
        f = ctx.objective(x)
        j = int(np.argmax(f))
        if not f[j] > float(ctx.evaluator.current().fitness) + 1e-12:
            break
        best, fitness, _ = polish(ctx.objective, x[j], float(f[j]), ctx.rng, cfg.pso.polish_rounds,
                                  cfg.pso.polish_samples, cfg.pso.polish_step, fixed=3)
        commit(ctx, plane.decode(best))
        encodings.append(best)
        free[spots[j // len(gimbal)]] = False
    if len(encodings) <= placed:  # no better than greedy's answer, which the caller keeps
        _restore(ctx, base, [])
        return []
    for i in range(len(encodings)):  # each camera polished with the others fixed
        _restore(ctx, base, [plane.decode(e) for n, e in enumerate(encodings) if n != i])
        f0 = float(ctx.objective(encodings[i][None])[0])
        encodings[i], _, _ = polish(ctx.objective, encodings[i], f0, ctx.rng, cfg.pso.polish_rounds,
                                    cfg.pso.polish_samples, cfg.pso.polish_step)
    chosen = [plane.decode(e) for e in encodings]
    _restore(ctx, base, chosen)
    return chosen


def _restore(ctx: SearchContext, base: tuple, placed: list[Perch]) -> None:
    """Evaluator and spacing constraint holding the state before the search plus `placed`."""
    info, seen, others = base
    ctx.evaluator.set_state(info, seen)
    ctx.others[:] = others
    ctx.placed.clear()
    for perch in placed:
        commit(ctx, perch)


def commit(ctx: SearchContext, perch: Perch) -> None:
    """Add a chosen camera to the evaluator and its drone to the spacing constraint."""
    ctx.evaluator.commit(perch.camera_position, perch.camera_rotation, perch.zoom, views=ctx.perch_views(perch))
    ctx.others.append(perch.drone_position[0])
    ctx.placed.append(perch)


def perch_arrangement(perch: Perch) -> Arrangement:
    """Decoded perches as an arrangement of cameras."""
    return Arrangement(perch.camera_position, perch.camera_rotation, perch.zoom, perch.drone_rotation)


def no_gain_reason(ctx: SearchContext, placed: int) -> str:
    """Why the search stopped before placing every camera."""
    if placed == 0 and not ctx.evaluator.seen.any():
        return "the target is not visible from any feasible perch on the given regions"
    return (f"no feasible perch adds fitness (min spacing {ctx.config.drone.min_spacing:g} m, "
            f"{len(ctx.exclusions)} exclusion zone(s))")


def per_camera_budget(cfg: PlacementConfig) -> int:
    """The evaluations baselines get per camera: the swarm's maximum (particles x iterations)."""
    return cfg.pso.particles * cfg.pso.iterations


def polish(objective, x: np.ndarray, fitness: float, rng: np.random.Generator, rounds: int,
           samples: int, step: float, fixed: int = 1) -> tuple[np.ndarray, float, int]:
    """Batched hill climbing from x with its first `fixed` coordinates kept (1: the region selector;
    3 in the plane encoding: the position too): Gaussian steps in [0,1]^D, the step halving whenever
    a round brings no gain. Returns (x, fitness, evaluations)."""
    evaluations = 0
    for _ in range(rounds):
        trial = np.clip(x + rng.normal(0.0, step, (samples, len(x))), 0.0, 1.0)
        trial[:, :fixed] = x[:fixed]  # stay on the same region (and position)
        f = objective(trial)
        evaluations += samples
        j = int(np.argmax(f))
        if f[j] > fitness:
            x, fitness = trial[j], float(f[j])
        else:
            step *= 0.5
    return x, fitness, evaluations


def candidate_encoding(plane: Perches, cands: CandidateSet, index: int) -> np.ndarray:
    """The plane encoding of candidate `index` (position, gimbal coordinates, no zoom)."""
    position = index // cands.orientations
    x = plane.encode_position(int(cands.region[position]), cands.points[position])
    zoom = [0.0] if plane.max_zoom > 1 else []
    return np.concatenate([x, cands.gimbal[index % cands.orientations], zoom])
