"""How an arrangement holds up: landing error, k-view coverage and the loss of one camera.

- **Landing error** (`LandingError`): a perching drone lands off its planned point by a Gaussian
  offset in the perch plane (sigma per in-plane axis) and settles at a yaw (rotation about the
  surface normal) off its planned one (Gaussian). The gimbal either keeps its commanded pan/tilt
  relative to the body (default: a gimbal without a heading reference) or re-aims at the planned
  optical axis within its pan/tilt range (`gimbal_reaim`). Every drone of the arrangement (fixed
  ones too) draws its own error. The draws come from one seeded generator and are shared by every
  arrangement scored with the same model (common random numbers): differences between arrangements
  are then not sampling noise.
- **k-view coverage**: the fraction of target points seen by at least k cameras of which at least
  one pair views the point from directions at least theta apart (k = 1: seen at all).
- **Resilience**: coverage and k-view coverage after removing each camera in turn.

Never imports rclpy.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from perch_placement.fitness import Evaluator
from perch_placement.perches import DRONE_FROM_NEUTRAL, gimbal_rotation


@dataclass
class Arrangement:
    """K placed cameras as arrays: camera positions and world-from-optical rotations, zooms, and the
    drones' world-from-drone rotations (z: the surface normal) and gimbal ranges (rad, full width)."""

    camera_position: np.ndarray   # (K,3)
    camera_rotation: np.ndarray   # (K,3,3)
    zoom: np.ndarray              # (K,)
    drone_rotation: np.ndarray    # (K,3,3)

    def __len__(self) -> int:
        return len(self.camera_position)

    @classmethod
    def of(cls, placements) -> "Arrangement":
        """The arrangement of CameraPlacement objects (4x4 poses)."""
        cam = np.array([np.asarray(p.camera_pose, np.float64) for p in placements]).reshape(-1, 4, 4)
        drone = np.array([np.asarray(p.drone_pose, np.float64) for p in placements]).reshape(-1, 4, 4)
        zoom = np.array([max(float(p.zoom), 1.0) for p in placements], np.float64)
        return cls(cam[:, :3, 3], cam[:, :3, :3], zoom, drone[:, :3, :3])


def axis_rotation(axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """(...,3,3) rotations by `angle` (...) about unit `axis` (...,3) (Rodrigues)."""
    x, y, z = axis[..., 0], axis[..., 1], axis[..., 2]
    c, s = np.cos(angle), np.sin(angle)
    t = 1.0 - c
    out = np.empty(np.shape(angle) + (3, 3))
    out[..., 0, 0], out[..., 0, 1], out[..., 0, 2] = c + x * x * t, x * y * t - z * s, x * z * t + y * s
    out[..., 1, 0], out[..., 1, 1], out[..., 1, 2] = y * x * t + z * s, c + y * y * t, y * z * t - x * s
    out[..., 2, 0], out[..., 2, 1], out[..., 2, 2] = z * x * t - y * s, z * y * t + x * s, c + z * z * t
    return out


class LandingSampler:
    """Seeded landing errors shared by every arrangement (common random numbers).

    `draws[s, j]` = (du, dv, dyaw) standard normals for sample s and camera slot j; slots beyond the
    ones drawn so far are drawn on demand from the same generator, so a slot's draws never change."""

    def __init__(self, position_sigma: float, yaw_sigma_deg: float, samples: int, seed: int | list,
                 gimbal_reaim: bool = False, pan_range_deg: float = 90.0, tilt_range_deg: float = 90.0):
        if samples < 1:
            raise ValueError(f"landing error samples must be >= 1, got {samples}")
        self.position_sigma = float(position_sigma)
        self.yaw_sigma = float(np.radians(yaw_sigma_deg))
        self.samples = int(samples)
        self.gimbal_reaim = bool(gimbal_reaim)
        self.half_pan = float(np.radians(pan_range_deg)) / 2
        self.half_tilt = float(np.radians(tilt_range_deg)) / 2
        self._rng = np.random.default_rng(seed)
        self._draws = np.zeros((self.samples, 0, 3))

    def draws(self, k: int) -> np.ndarray:
        """(S,k,3) standard-normal draws of the first k camera slots."""
        if self._draws.shape[1] < k:
            more = self._rng.standard_normal((self.samples, k - self._draws.shape[1], 3))
            self._draws = np.concatenate([self._draws, more], axis=1)
        return self._draws[:, :k]

    def perturb(self, arrangement: Arrangement, slots: np.ndarray | None = None) -> Arrangement:
        """The arrangement as landed in each sample: (S*K) cameras, sample-major. `slots` (K,) names
        the draw slot of each camera (default 0..K-1)."""
        k = len(arrangement)
        slots = np.arange(k) if slots is None else np.asarray(slots)
        d = self.draws(int(slots.max()) + 1 if k else 0)[:, slots] if k else np.zeros((self.samples, 0, 3))
        rot = arrangement.drone_rotation[None]                      # (1,K,3,3)
        normal, ax_u, ax_v = rot[..., 2], rot[..., 0], rot[..., 1]  # drone z, x, y in the world
        shift = self.position_sigma * (d[..., 0:1] * ax_u + d[..., 1:2] * ax_v)  # (S,K,3) in the perch plane
        yaw = axis_rotation(np.broadcast_to(normal, d.shape), self.yaw_sigma * d[..., 2])  # (S,K,3,3)
        drone_rot = yaw @ rot
        position = arrangement.camera_position[None] + shift
        if self.gimbal_reaim:
            camera_rot = self._reaim(arrangement.camera_rotation[None, :, :, 2], drone_rot)
        else:  # the gimbal keeps its angles relative to the body: the view turns with the drone
            camera_rot = yaw @ arrangement.camera_rotation[None]
        s = self.samples
        return Arrangement(position.reshape(s * k, 3), camera_rot.reshape(s * k, 3, 3),
                           np.tile(arrangement.zoom, s), drone_rot.reshape(s * k, 3, 3))

    def _reaim(self, axis: np.ndarray, drone_rot: np.ndarray) -> np.ndarray:
        """Camera rotations of gimbals re-aimed at the planned optical axis (world, (...,3)) from the
        landed drone rotations, clipped to the gimbal range (pan about image-vertical, then tilt)."""
        neutral = drone_rot @ DRONE_FROM_NEUTRAL
        d = np.einsum("...k,...kj->...j", axis, neutral)
        pan = np.clip(np.arctan2(d[..., 0], d[..., 2]), -self.half_pan, self.half_pan)
        tilt = np.clip(np.arctan2(-d[..., 1], np.hypot(d[..., 0], d[..., 2])), -self.half_tilt, self.half_tilt)
        return neutral @ gimbal_rotation(pan, tilt)


def kview_mask(camera_positions: np.ndarray, seen: np.ndarray, points: np.ndarray, k: int,
               angle_deg: float) -> np.ndarray:
    """(...,N) points seen by >= k cameras with at least one pair of seeing cameras whose directions
    to the point are >= angle_deg apart (k <= 1: seen by at least one camera). camera_positions
    (...,K,3), seen (...,K,N)."""
    seen = np.asarray(seen, bool)
    count = seen.sum(axis=-2)
    if k <= 1:
        return count >= 1
    if seen.shape[-2] < 2:
        return np.zeros(count.shape, bool)
    ray = points[..., None, :, :] - camera_positions[..., :, None, :]          # (...,K,N,3)
    ray = ray / np.maximum(np.linalg.norm(ray, axis=-1, keepdims=True), 1e-12)
    cos = np.einsum("...ind,...jnd->...ijn", ray, ray)                          # (...,K,K,N)
    both = seen[..., :, None, :] & seen[..., None, :, :]
    wide = both & (cos <= np.cos(np.radians(angle_deg)) + 1e-12)
    return (count >= k) & wide.any(axis=(-3, -2))


@dataclass
class Assessment:
    """Robustness of one arrangement of K cameras (every array in the arrangement's order)."""

    fitness: float
    coverage: float
    kview_coverage: float
    expected_fitness: float           # mean fitness under the landing error
    p5_fitness: float                 # 5th percentile of it
    contribution: np.ndarray          # (K,) fitness lost when this camera is removed (nominal)
    expected_contribution: np.ndarray  # (K,) its mean under the landing error
    p5_contribution: np.ndarray       # (K,) its 5th percentile
    coverage_without: np.ndarray      # (K,) coverage with this camera removed
    kview_without: np.ndarray         # (K,) k-view coverage with this camera removed
    samples: int
    short_of_views: int = 0           # target points seen by fewer than k cameras
    short_of_angle: int = 0           # points seen by k or more, but from views closer than the angle

    @property
    def worst_coverage_without(self) -> float:
        """Coverage after losing the camera whose loss hurts coverage most (NaN without cameras)."""
        return float(self.coverage_without.min()) if len(self.coverage_without) else float("nan")

    @property
    def mean_coverage_without(self) -> float:
        """Mean coverage over the loss of each camera in turn."""
        return float(self.coverage_without.mean()) if len(self.coverage_without) else float("nan")

    @property
    def worst_kview_without(self) -> float:
        """k-view coverage after losing the camera whose loss hurts it most."""
        return float(self.kview_without.min()) if len(self.kview_without) else float("nan")

    @property
    def mean_kview_without(self) -> float:
        """Mean k-view coverage over the loss of each camera in turn."""
        return float(self.kview_without.mean()) if len(self.kview_without) else float("nan")


def leave_one_out(evaluator: Evaluator, info: np.ndarray, seen: np.ndarray, base_info: np.ndarray,
                  base_seen: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Fitness and coverage of arrangements (...,K,N,6 / ...,K,N) on top of a base state, and with
    each camera removed: (fitness (...), coverage (...), fitness_without (...,K), coverage_without (...,K))."""
    total = base_info + info.sum(axis=-3)
    count = seen.sum(axis=-2) + base_seen
    whole = evaluator.score(total, count > 0)
    without = evaluator.score(total[..., None, :, :] - info, (count[..., None, :] - seen) > 0)
    return (np.asarray(whole.fitness), np.asarray(whole.coverage), np.asarray(without.fitness),
            np.asarray(without.coverage))


def assess(evaluator: Evaluator, arrangement: Arrangement, sampler: LandingSampler, k: int,
           angle_deg: float) -> Assessment:
    """Nominal scores, k-view coverage, the loss of each camera and the landing-error statistics of
    an arrangement (every camera of it; the evaluator's committed state is not used or changed)."""
    n = evaluator.count
    none_info, none_seen = np.zeros((n, 6)), np.zeros(n, bool)
    kk = len(arrangement)
    if kk == 0:
        empty = np.zeros(0)
        return Assessment(0.0, 0.0, 0.0, 0.0, 0.0, empty, empty, empty, empty, empty, sampler.samples)
    seen, info = evaluator.views(arrangement.camera_position, arrangement.camera_rotation, arrangement.zoom)
    fit, cov, fit_wo, cov_wo = leave_one_out(evaluator, info, seen, none_info, none_seen)
    points = evaluator.points
    kview_points = kview_mask(arrangement.camera_position, seen, points, k, angle_deg)
    kview = kview_points.mean()
    enough = seen.sum(axis=0) >= k
    drop = ~np.eye(kk, dtype=bool)
    kview_wo = np.array([kview_mask(arrangement.camera_position[keep], seen[keep], points, k, angle_deg).mean()
                         for keep in drop])
    landed = sampler.perturb(arrangement)
    s_seen, s_info = evaluator.views(landed.camera_position, landed.camera_rotation, landed.zoom)
    s_seen = s_seen.reshape(sampler.samples, kk, n)
    s_info = s_info.reshape(sampler.samples, kk, n, 6)
    s_fit, _, s_fit_wo, _ = leave_one_out(evaluator, s_info, s_seen, none_info, none_seen)
    s_contrib = s_fit[:, None] - s_fit_wo
    return Assessment(float(fit), float(cov), float(kview), float(s_fit.mean()), float(np.percentile(s_fit, 5)),
                      float(fit) - fit_wo, s_contrib.mean(axis=0), np.percentile(s_contrib, 5, axis=0),
                      cov_wo, kview_wo, sampler.samples, int((~enough).sum()), int((enough & ~kview_points).sum()))


class RobustState:
    """Scores of one more camera under landing error, on top of committed cameras that landed with
    error too (each sample s: the committed cameras as landed in s, plus the candidate as landed in s).
    The candidate uses the next draw slot, so every candidate sees the same landings (common random
    numbers) and the comparison between candidates is not sampling noise."""

    def __init__(self, evaluator: Evaluator, sampler: LandingSampler, committed: Arrangement):
        self.evaluator, self.sampler = evaluator, sampler
        self.slot = len(committed)
        s, n = sampler.samples, evaluator.count
        self.info, self.seen = np.zeros((s, n, 6)), np.zeros((s, n), bool)
        if len(committed):
            landed = sampler.perturb(committed)
            seen, info = evaluator.views(landed.camera_position, landed.camera_rotation, landed.zoom)
            self.info = info.reshape(s, len(committed), n, 6).sum(axis=1)
            self.seen = seen.reshape(s, len(committed), n).any(axis=1)

    def fitness(self, candidates: Arrangement) -> np.ndarray:
        """(S,B) fitness in each landing sample of the committed cameras plus each candidate."""
        b, s, n = len(candidates), self.sampler.samples, self.evaluator.count
        landed = self.sampler.perturb(candidates, np.full(b, self.slot))
        seen, info = self.evaluator.views(landed.camera_position, landed.camera_rotation, landed.zoom)
        self.evaluator.evaluations += s * b
        score = self.evaluator.score(self.info[:, None] + info.reshape(s, b, n, 6),
                                     self.seen[:, None] | seen.reshape(s, b, n))
        return np.asarray(score.fitness)


class KViewState:
    """k-view coverage of the committed cameras plus one candidate (nominal poses)."""

    def __init__(self, evaluator: Evaluator, committed: Arrangement, k: int, angle_deg: float):
        self.evaluator, self.k, self.cos = evaluator, k, np.cos(np.radians(angle_deg)) + 1e-12
        points = evaluator.points
        if len(committed):
            self.seen = evaluator.views(committed.camera_position, committed.camera_rotation, committed.zoom)[0]
        else:
            self.seen = np.zeros((0, len(points)), bool)
        self.positions = committed.camera_position
        self.count = self.seen.sum(axis=0)
        self.wide = kview_mask(self.positions, self.seen, points, 2, angle_deg) if len(self.seen) >= 2 else \
            np.zeros(len(points), bool)
        ray = points[None] - self.positions[:, None]
        self.rays = ray / np.maximum(np.linalg.norm(ray, axis=-1, keepdims=True), 1e-12)  # (K,N,3)

    def coverage(self, candidates: Arrangement, seen: np.ndarray | None = None) -> np.ndarray:
        """(B,) k-view coverage with each candidate added (`seen` (B,N): their visibility, if known)."""
        if seen is None:
            seen = self.evaluator.views(candidates.camera_position, candidates.camera_rotation, candidates.zoom)[0]
        count = self.count[None] + seen
        if self.k <= 1:
            return (count >= 1).mean(axis=1)
        ray = self.evaluator.points[None] - candidates.camera_position[:, None]
        ray = ray / np.maximum(np.linalg.norm(ray, axis=-1, keepdims=True), 1e-12)      # (B,N,3)
        cos = np.einsum("bnd,knd->bkn", ray, self.rays)
        new_wide = (seen[:, None] & self.seen[None] & (cos <= self.cos)).any(axis=1)
        return ((count >= self.k) & (self.wide[None] | new_wide)).mean(axis=1)


def worst_loss_coverage(evaluator: Evaluator, committed: Arrangement, candidates: Arrangement) -> np.ndarray:
    """(B,) coverage after losing the worst single camera of the committed cameras plus each candidate."""
    points = evaluator.count
    if len(committed):
        seen = evaluator.views(committed.camera_position, committed.camera_rotation, committed.zoom)[0]
    else:
        seen = np.zeros((0, points), bool)
    cand = evaluator.views(candidates.camera_position, candidates.camera_rotation, candidates.zoom)[0]
    count = seen.sum(axis=0)[None] + cand                                  # (B,N)
    lose_candidate = (count - cand > 0).mean(axis=1)
    if not len(seen):
        return lose_candidate
    lose_committed = ((count[:, None] - seen[None]) > 0).mean(axis=2).min(axis=1)  # (B,)
    return np.minimum(lose_candidate, lose_committed)
