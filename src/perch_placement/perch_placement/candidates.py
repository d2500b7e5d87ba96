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
    """Candidate perches with their visibility and information, grouped by position (A orientations
    each). The candidates' poses are made on demand (`take`): a set holds hundreds of thousands of
    candidates and a search poses a few of them."""

    perches: Perches        # poses the candidates
    region: np.ndarray      # (P,) region index of each position
    points: np.ndarray      # (P,3) drone position (on the surface) of each position
    mounts: tuple           # drone rotations (P,3,3), camera positions (P,3), gimbal windows (P,4)
    gimbal: np.ndarray      # (A,2) pan/tilt coordinates in [0,1] of each orientation
    visible: np.ndarray     # (P,A,N) bool, occlusion and range included
    # (R,6) scaled information of a camera (zoom 1) at each reached (position, point), position by
    # position, points ascending (np.nonzero(reach) order): a dense (P,N,6) array is ~25x larger and
    # writing it cost more than the rest of the set (0.45 of 1.0 CPU s on a multi-storey building).
    pair_info: np.ndarray
    reach: np.ndarray       # (P,N) bool: some orientation at the position sees the point
    parent: "CandidateSet | None" = None   # the set this one is a subset of (shares its derived masks)
    kept: np.ndarray | None = None         # (P,) indices of this set's positions in the parent
    _undominated: np.ndarray | None = None
    _live: np.ndarray | None = None

    def __post_init__(self) -> None:
        self.pair_start = np.concatenate([[0], np.cumsum(self.reach.sum(axis=1))])  # position p's pairs begin here

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
        return self.points

    def pair_index(self, positions: np.ndarray) -> np.ndarray:
        """Indices into pair_info of the points reached from `positions`, in np.nonzero(reach[positions]) order."""
        start = self.pair_start[positions]
        counts = self.pair_start[np.asarray(positions) + 1] - start
        return np.repeat(start - np.cumsum(counts) + counts, counts) + np.arange(counts.sum())

    def info_rows(self, positions) -> np.ndarray:
        """(..., N, 6) information of a camera at each of `positions` (an index array), 0 at unreached points."""
        positions = np.asarray(positions)
        flat = positions.reshape(-1)
        out = np.zeros((len(flat), self.reach.shape[1], 6))
        p, n = np.nonzero(self.reach[flat])
        out[p, n] = self.pair_info[self.pair_index(flat)]
        return out.reshape(positions.shape + out.shape[1:])

    @property
    def info(self) -> np.ndarray:
        """(P,N,6) information of a camera at every position (made now: prefer info_rows)."""
        return self.info_rows(np.arange(self.positions))

    def take(self, index) -> Perch:
        """The perches of candidates `index` (candidate c is orientation c % A at position c // A)."""
        return _pose(self.perches, self.region, self.points, self.mounts, self.gimbal, index)

    @property
    def perch(self) -> Perch:
        """Every candidate's perch, in candidate order (posed now: prefer `take`)."""
        return self.take(np.arange(len(self)))

    def live(self) -> np.ndarray:
        """Indices of the positions that see some point (every other position's gains are 0)."""
        if self._live is None:
            self._live = np.flatnonzero(self.reach.any(axis=1))
        return self._live

    def subset(self, keep: np.ndarray) -> "CandidateSet":
        """The candidates at the positions where `keep` (P,) is true."""
        root, kept = (self, np.flatnonzero(keep)) if self.parent is None else (self.parent, self.kept[keep])
        return CandidateSet(self.perches, self.region[keep], self.points[keep], tuple(m[keep] for m in self.mounts),
                            self.gimbal, self.visible[keep], self.pair_info[self.pair_index(np.flatnonzero(keep))],
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


def _pose(perches: Perches, region: np.ndarray, points: np.ndarray, mounts: tuple, gimbal: np.ndarray,
          index) -> Perch:
    """The perches of candidates `index` (orientation c % A at position c // A) of positions on a grid."""
    p, o = np.divmod(np.asarray(index, np.int64).reshape(-1), len(gimbal))
    return perches.pose(region[p], points[p], gimbal[o], mounts=tuple(m[p] for m in mounts))


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
    probe = full.take(np.arange(0, len(full), full.orientations))
    keep = perches.feasible(probe, fixed, exclusions)
    return full if keep.all() else full.subset(keep)  # the whole set is never modified: no copy


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
    mounts = tuple(m[keep] for m in perches.mounts(probe.region, probe.drone_position))
    targets, cam_pos = evaluator.points, mounts[1]
    reach = evaluator.in_reach(cam_pos)
    visible = np.zeros((len(region), a, len(targets)), bool)
    # Only positions that reach a point can see one: their orientations' frustum tests are one matrix
    # product per position, local[p, n, a, j] = sum_k delta[p, n, k] R[p, a, k, j] (row-vector R^T d),
    # read at the reached points only (about 1 in 25 on a building).
    live = np.flatnonzero(reach.any(axis=1))
    per_chunk = max(1, chunk // (a * len(targets)))
    for start in range(0, len(live), per_chunk):
        rows = live[start:start + per_chunk]
        index = (rows[:, None] * a + np.arange(a)).reshape(-1)
        rotations = _pose(perches, region, points, mounts, gimbal, index).camera_rotation
        rotations = rotations.reshape(-1, a, 3, 3).transpose(0, 2, 1, 3).reshape(-1, 3, a * 3)
        delta = targets[None] - cam_pos[rows][:, None]   # as Evaluator.reach computes it
        local = np.matmul(delta.astype(np.float32), rotations.astype(np.float32))
        p, n = np.nonzero(reach[rows])
        visible[rows[p], :, n] = on_sensor(evaluator.camera, local[p, n].reshape(len(p), a, 3))
    reach = visible.any(axis=1)
    p, n = np.nonzero(reach)
    delta = targets[n] - cam_pos[p]
    distance = np.linalg.norm(delta, axis=-1)
    info = evaluator.information(distance, delta / np.maximum(distance, 1e-12)[:, None])
    return CandidateSet(perches, region, points, mounts, gimbal, visible, info, reach)


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
        new = point_score(self.info[n] + self.c.pair_info[self.c.pair_index(positions)], np.ones(len(n), bool))[0]
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
        self.info = self.info + self.c.info_rows(p) * seen[:, None]
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

    def online_bound(self, k: int, gains: np.ndarray | None = None) -> float:
        """f(S) + the k largest marginal gains over the candidate set (spacing among the new cameras
        ignored), at most one per position when drones must be apart (an optimal set then holds at
        most one camera per position). An upper bound on the best k-subset only if f is submodular,
        which covariance fusion is not (see perch_placement.optimality). `gains`: every candidate's
        gain on this state when already known (GainMemo)."""
        if self.c.positions == 0 or k <= 0:
            return self.fitness
        return min(1.0, self.fitness + self._top_sum(self.gains() if gains is None else gains, k))  # f <= 1 always

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


class GainMemo:
    """Every candidate's marginal gain on a base state that changes between calls (a search's committed
    cameras), as CandidateGreedy.gains computes it. A position's gains depend only on the state of the
    points it reaches: they are recomputed only where one of those changed since the last call (the
    others are the same numbers), and are 0 at positions that reach no point."""

    def __init__(self, cands: CandidateSet):
        self.c = cands
        self.values = np.zeros((cands.positions, cands.orientations))
        self.fresh = np.zeros(cands.positions, bool)   # values[p] hold for the last state
        self.live = np.zeros(cands.positions, bool)
        self.live[cands.live()] = True
        self.info: np.ndarray | None = None
        self.seen: np.ndarray | None = None

    def gains(self, info: np.ndarray, seen: np.ndarray, positions: np.ndarray | None = None) -> np.ndarray:
        """(P',A) marginal gains of the candidates at `positions` (default: all) on the state (info, seen)."""
        positions = np.arange(self.c.positions) if positions is None else np.asarray(positions)
        if self.info is None:
            changed = np.arange(len(seen))
        else:
            changed = np.flatnonzero((info != self.info).any(axis=1) | (seen != self.seen))
        if len(changed):
            self.fresh &= ~self.c.reach[:, changed].any(axis=1)
            self.info, self.seen = info.copy(), seen.copy()
        need = positions[self.live[positions] & ~self.fresh[positions]]
        if len(need):
            self.values[need] = CandidateGreedy(self.c, info, seen, 0.0).gains(need)
            self.fresh[need] = True
        return self.values[positions]
