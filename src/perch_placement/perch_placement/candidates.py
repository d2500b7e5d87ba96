"""Discrete candidate sets: positions on a grid over the regions times a pan/tilt grid.

Occlusion and range depend only on the camera position, so they are ray-cast once per position;
each orientation only adds a frustum test. A greedy step then scores every candidate with one
matrix product: gain(c) = sum_n visible(c, n) * (s_n(with c's position) - s_n) / N. This makes the
dense exhaustive reference, lazy greedy (CELF, perch_placement.search.celf) and the greedy online
bound cheap.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass

import numpy as np

from perch_common.types import ExclusionZone
from perch_placement.cache import PlacementCache
from perch_placement.camera import on_sensor
from perch_placement.fitness import Evaluator, point_score
from perch_placement.perches import Perch, Perches


@dataclass
class CandidateSet:
    """Candidate perches with their visibility and information, grouped by position."""

    perch: Perch            # C = P * A candidates, grouped by position (A orientations each)
    gimbal: np.ndarray      # (A,2) pan/tilt coordinates in [0,1] of each orientation
    visible: np.ndarray     # (P,A,N) bool, occlusion and range included
    info: np.ndarray        # (P,N,6) scaled information of a camera at each position (zoom 1)
    reach: np.ndarray       # (P,N) bool: some orientation at the position sees the point
    parent: "CandidateSet | None" = None   # the set this one is a subset of (shares its derived masks)
    kept: np.ndarray | None = None         # (P,) indices of this set's positions in the parent
    _undominated: np.ndarray | None = None

    @property
    def positions(self) -> int:
        """Number of candidate positions (P)."""
        return self.visible.shape[0]

    @property
    def orientations(self) -> int:
        """Gimbal orientations per position (A)."""
        return self.visible.shape[1]

    def __len__(self) -> int:
        return self.positions * self.orientations

    def drone_positions(self) -> np.ndarray:
        """(P,3) drone position of each candidate position."""
        return self.perch.drone_position[::self.orientations]

    def subset(self, keep: np.ndarray) -> "CandidateSet":
        """The candidates at the positions where `keep` (P,) is true."""
        index = (np.flatnonzero(keep)[:, None] * self.orientations + np.arange(self.orientations)).reshape(-1)
        root, kept = (self, np.flatnonzero(keep)) if self.parent is None else (self.parent, self.kept[keep])
        return CandidateSet(self.perch.take(index), self.gimbal, self.visible[keep], self.info[keep],
                            self.reach[keep], root, kept)

    def undominated(self) -> np.ndarray:
        """(P,A) orientations whose view is not inside another's at the same position (the certificate's
        columns; perch_placement.certificate.undominated), computed once on the unconstrained set."""
        if self.parent is not None:
            return self.parent.undominated()[self.kept]
        if self._undominated is None:
            from perch_placement.certificate import undominated

            self._undominated = undominated(self.visible)
        return self._undominated


def cached_candidates(perches: Perches, evaluator: Evaluator, spacing: float, angles: int,
                      exclusions: tuple[ExclusionZone, ...] = (), fixed: np.ndarray = np.zeros((0, 3)),
                      cache: PlacementCache | None = None, scene_key: str = "") -> CandidateSet:
    """build_candidates, reusing from `cache` the unconstrained set of an identical earlier request (same
    scene content `scene_key`, target points, regions, camera and drone) and applying exclusions and fixed
    drones afterwards: re-optimising after a rejection then costs no candidate ray casting."""
    def build() -> CandidateSet:
        return build_candidates(perches, evaluator, spacing, angles)

    if cache is None or not scene_key:
        full = build()
    else:
        full = cache.candidates(_candidate_key(perches, evaluator, spacing, angles, scene_key), build)
    probe = full.perch.take(np.arange(0, len(full), full.orientations))
    return full.subset(perches.feasible(probe, fixed, exclusions))


def _candidate_key(perches: Perches, evaluator: Evaluator, spacing: float, angles: int, scene_key: str) -> str:
    h = hashlib.blake2b(scene_key.encode(), digest_size=16)
    for region in perches.regions:
        f = region.frame
        h.update(np.concatenate([f.origin, f.axis_u, f.axis_v, f.normal]).tobytes())
        for poly in region.polygons:
            for ring in poly:
                h.update(np.ascontiguousarray(ring, np.float64).tobytes())
    h.update(evaluator.points.tobytes())
    h.update(repr((evaluator.camera, evaluator.epsilon, perches.drone, perches.up.tolist(),
                   perches.target_centre.tolist(), perches.border_margin, spacing, angles)).encode())
    return h.hexdigest()


def build_candidates(perches: Perches, evaluator: Evaluator, spacing: float, angles: int,
                     exclusions: tuple[ExclusionZone, ...] = (), fixed: np.ndarray = np.zeros((0, 3)),
                     chunk: int = 1_000_000) -> CandidateSet:
    """Candidates at `spacing` on every region with `angles` x `angles` gimbal settings, minus those
    inside exclusion zones or closer than the minimum spacing to a fixed drone."""
    region, points = perches.grid(spacing)
    steps = np.linspace(0.0, 1.0, max(angles, 1)) if angles > 1 else np.array([0.5])
    gimbal = np.stack(np.meshgrid(steps, steps, indexing="ij"), -1).reshape(-1, 2)
    a = len(gimbal)
    probe = perches.pose(region, points, np.full((len(region), 2), 0.5))
    keep = perches.feasible(probe, fixed, exclusions)
    region, points = region[keep], points[keep]
    mounts = tuple(np.repeat(m[keep], a, axis=0) for m in perches.mounts(probe.region, probe.drone_position))
    perch = perches.pose(np.repeat(region, a), np.repeat(points, a, axis=0), np.tile(gimbal, (len(region), 1)),
                         mounts=mounts)
    cam = evaluator.camera
    targets = evaluator.points
    cam_pos = perch.camera_position[::a]
    reach, delta, distance, unit = evaluator.reach(cam_pos)
    # Frustum tests for every orientation at a position as one matrix product:
    # local[p, n, a, j] = sum_k delta[p, n, k] R[p, a, k, j] (row-vector R^T d).
    visible = np.zeros((len(region), a, len(targets)), bool)
    rotations = perch.camera_rotation.reshape(-1, a, 3, 3).transpose(0, 2, 1, 3).reshape(-1, 3, a * 3)
    per_chunk = max(1, chunk // (a * len(targets)))
    for start in range(0, len(region), per_chunk):
        sl = slice(start, start + per_chunk)
        local = np.matmul(delta[sl].astype(np.float32), rotations[sl].astype(np.float32))
        in_frame = on_sensor(cam, local.reshape(local.shape[0], len(targets), a, 3))
        visible[sl] = (in_frame & reach[sl, :, None]).transpose(0, 2, 1)
    reach = visible.any(axis=1)
    info = np.zeros(distance.shape + (6,))
    info[reach] = evaluator.information(distance[reach], unit[reach])
    return CandidateSet(perch, gimbal, visible, info, reach)


@dataclass
class GreedyPick:
    """Candidates chosen by a greedy run, their gains and the work it took."""

    chosen: list            # candidate indices, in order
    gains: list             # marginal fitness gains
    evaluations: int        # candidate gains computed


class CandidateGreedy:
    """Greedy selection over a candidate set on top of a base information state."""

    def __init__(self, cands: CandidateSet, base_info: np.ndarray, base_seen: np.ndarray, min_spacing: float):
        self.c = cands
        self.info = base_info.copy()
        self.seen = base_seen.copy()
        self.min_spacing = min_spacing
        self.valid = np.ones(cands.positions, bool)
        self.evaluations = 0
        self.scores = point_score(self.info, self.seen)[0]  # (N,) per-point scores of the current set

    @property
    def fitness(self) -> float:
        """Fitness of the base state plus the candidates added so far."""
        return float(self.scores.mean())

    def point_gains(self, positions: np.ndarray) -> np.ndarray:
        """(P',N) score gain of each point if a camera at these positions saw it."""
        out = np.zeros((len(positions), len(self.scores)))
        p, n = np.nonzero(self.c.reach[positions])
        new = point_score(self.info[n] + self.c.info[positions[p], n], np.ones(len(n), bool))[0]
        out[p, n] = np.maximum(new - self.scores[n], 0.0)
        return out

    def gains(self, positions: np.ndarray | None = None, chunk: int = 512) -> np.ndarray:
        """(P',A) marginal gains of the candidates at the given positions (default: all)."""
        positions = np.arange(self.c.positions) if positions is None else np.asarray(positions)
        out = np.zeros((len(positions), self.c.orientations))
        for start in range(0, len(positions), chunk):
            sel = positions[start:start + chunk]
            delta = self.point_gains(sel)
            out[start:start + chunk] = np.matmul(self.c.visible[sel].astype(np.float32),
                                                 delta[..., None].astype(np.float32))[..., 0]
        self.evaluations += out.size
        return out / len(self.scores)

    def add(self, index: int) -> float:
        """Commit candidate `index`; returns its marginal gain."""
        p, o = divmod(int(index), self.c.orientations)
        before = self.fitness
        seen = self.c.visible[p, o]
        self.info = self.info + self.c.info[p] * seen[:, None]
        self.seen = self.seen | seen
        self.scores = point_score(self.info, self.seen)[0]
        if self.min_spacing > 0:
            where = self.c.drone_positions()
            self.valid &= np.linalg.norm(where - where[p], axis=1) >= self.min_spacing
        return self.fitness - before

    def step(self) -> tuple[int, float] | None:
        """Plain greedy: score every valid candidate, add the best."""
        pos = np.flatnonzero(self.valid)
        if len(pos) == 0:
            return None
        g = self.gains(pos)
        i, j = np.unravel_index(int(np.argmax(g)), g.shape)
        if g[i, j] <= 0:
            return None
        index = int(pos[i]) * self.c.orientations + int(j)
        return index, self.add(index)

    def run(self, k: int) -> GreedyPick:
        """Plain greedy for up to k candidates (CELF's lazy variant: perch_placement.search.celf)."""
        chosen, gains = [], []
        for _ in range(k):
            picked = self.step()
            if picked is None:
                break
            chosen.append(picked[0])
            gains.append(picked[1])
        return GreedyPick(chosen, gains, self.evaluations)

    def online_bound(self, k: int) -> float:
        """f(S) + the k largest marginal gains over the candidate set (spacing among the new cameras
        ignored), at most one per position when drones must be apart (an optimal set then holds at
        most one camera per position). An upper bound on the best k-subset only if f is submodular,
        which covariance fusion is not (see perch_placement.optimality)."""
        if self.c.positions == 0 or k <= 0:
            return self.fitness
        return min(1.0, self.fitness + self._top_sum(self.gains(), k))  # f <= 1 always

    def coverage_bound(self, k: int) -> float:
        """The same bound for coverage g(S) (fraction of points seen), which is submodular and
        >= f: a guaranteed upper bound on the best k-subset's fitness, looser than online_bound."""
        if self.c.positions == 0 or k <= 0:
            return float(self.seen.mean())
        unseen = (~self.seen).astype(np.float32)
        gains = np.matmul(self.c.visible.astype(np.float32), unseen) / len(unseen)
        self.evaluations += gains.size
        return min(1.0, float(self.seen.mean()) + self._top_sum(gains, k))

    def _top_sum(self, gains: np.ndarray, k: int) -> float:
        g = gains.max(axis=1) if self.min_spacing > 0 else gains.reshape(-1)
        return float(np.maximum(np.sort(g)[::-1][:k], 0).sum())
