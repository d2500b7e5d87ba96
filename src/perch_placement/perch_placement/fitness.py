"""The fitness of camera arrangements, with the placed cameras' information cached.

f = (1/N) sum_n s_n, s_n = 1 - ||C_n|| / ||C_max|| for points seen by at least one camera, 0 for
unseen points (the original's equation 22, corrected: it dropped unseen points, so seeing nothing
scored best). ||.|| is the spectral norm (largest eigenvalue of the fused covariance = 1 / smallest
eigenvalue of the summed information); C_max is one unzoomed camera's covariance at R_max.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from perch_common.raycast import RayScene
from perch_common.symmetric import smallest_eigenvalue
from perch_placement.camera import in_view, information6, max_covariance_norm
from perch_placement.config import CameraSpec


def point_score(info6: np.ndarray, seen: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-point score s = 1 - ||C||/||C_max|| (0 when unseen) and ||C||/||C_max|| (inf when unseen),
    from information scaled by ||C_max||: the spectral norm of C = J^-1 is 1/lambda_min(J)."""
    lam = smallest_eigenvalue(info6)
    ratio = np.where(seen, 1.0 / np.maximum(lam, 1e-300), np.inf)
    return np.where(seen, np.clip(1.0 - ratio, 0.0, 1.0), 0.0), ratio


@dataclass
class Score:
    """Fitness, coverage (fraction of points seen) and mean spectral norm of the fused covariance
    of the seen points (m^2; NaN when none is seen)."""

    fitness: np.ndarray | float
    coverage: np.ndarray | float
    mean_uncertainty: np.ndarray | float


def placement_cameras(placements) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Camera positions (K,3), world-from-optical rotations (K,3,3) and zooms (K,) (>= 1) of placements."""
    poses = np.array([np.asarray(p.camera_pose, np.float64) for p in placements]).reshape(-1, 4, 4)
    zoom = np.array([max(float(p.zoom), 1.0) for p in placements], np.float64)
    return poses[:, :3, 3], poses[:, :3, :3], zoom


class Evaluator:
    """Scores cameras against N target points; `commit` adds a camera to the cached information sum
    so that scoring one more camera costs only that camera's visibility and information."""

    def __init__(self, scene: RayScene, points: np.ndarray, camera: CameraSpec, epsilon: float = 1e-3):
        self.scene = scene
        self.points = np.asarray(points, np.float64).reshape(-1, 3)
        self.camera = camera
        self.epsilon = epsilon
        self.scale = max_covariance_norm(camera)
        self.info = np.zeros((len(self.points), 6))
        self.seen = np.zeros(len(self.points), bool)
        self._base: np.ndarray | None = None
        self.evaluations = 0   # camera arrangements simulated (visibility, occlusion, fusion)
        self.candidate_evaluations = 0  # candidate gains scored from cached candidate-set visibility
        self.ray_tests = 0

    @property
    def count(self) -> int:
        """Number of target points (N)."""
        return len(self.points)

    def views(self, positions: np.ndarray, rotations: np.ndarray, zoom=1.0) -> tuple[np.ndarray, np.ndarray]:
        """Visibility (B,N) including occlusion, and each camera's information (B,N,6) (0 where unseen)."""
        positions = np.asarray(positions, np.float64).reshape(-1, 3)
        rotations = np.asarray(rotations, np.float64).reshape(-1, 3, 3)
        zoom = np.broadcast_to(np.asarray(zoom, np.float64), (len(positions),))
        mask, distance, unit = in_view(self.camera, positions, rotations, self.points, zoom)
        self.occlude(positions, mask)
        info = np.zeros(mask.shape + (6,))
        info[mask] = self.information(distance[mask], unit[mask], np.broadcast_to(zoom[:, None], mask.shape)[mask])
        return mask, info

    def reach(self, positions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """What an unzoomed camera at each position (P,3) could see by turning: points within range and
        not occluded (P,N), with the offsets (P,N,3), distances (P,N) and unit directions (P,N,3)."""
        delta = self.points[None] - positions[:, None]
        distance = np.linalg.norm(delta, axis=-1)
        unit = delta / np.maximum(distance, 1e-12)[..., None]
        reach = (distance >= self.camera.min_range) & (distance <= self.camera.max_distance())
        self.occlude(positions, reach)
        return reach, delta, distance, unit

    def in_reach(self, positions: np.ndarray, chunk: int = 1 << 20) -> np.ndarray:
        """reach(positions)[0] without its (P,N,3) arrays (hundreds of MB on a building, most of the
        candidate set's cost in fresh memory): ranges by blocks of positions, then one batch of rays."""
        mask = np.empty((len(positions), self.count), bool)
        per = max(1, chunk // max(self.count, 1))
        for start in range(0, len(positions), per):
            distance = np.linalg.norm(self.points[None] - positions[start:start + per, None], axis=-1)
            mask[start:start + per] = (distance >= self.camera.min_range) & (distance <= self.camera.max_distance())
        self.occlude(positions, mask)
        return mask

    def occlude(self, positions: np.ndarray, mask: np.ndarray) -> None:
        """Clear mask[b, n] (in place) where the sight line from camera b to point n is blocked."""
        cam, pt = np.nonzero(mask)
        if len(cam):
            blocked = self.scene.occluded(positions[cam], self.points[pt], self.epsilon)
            mask[cam[blocked], pt[blocked]] = False
            self.ray_tests += len(cam)

    def information(self, distance: np.ndarray, unit: np.ndarray, zoom=1.0) -> np.ndarray:
        """(..., 6) scaled information of seen points at these distances and directions."""
        return information6(self.camera, distance, unit, zoom, self.scale)

    def score(self, info: np.ndarray, seen: np.ndarray) -> Score:
        """Score of summed information (..., N, 6) and seen masks (..., N)."""
        s, ratio = point_score(info, seen)
        seen_count = seen.sum(axis=-1)
        unc = np.where(seen, ratio * self.scale, 0.0).sum(axis=-1)
        with np.errstate(invalid="ignore", divide="ignore"):
            mean_unc = np.where(seen_count > 0, unc / np.maximum(seen_count, 1), np.nan)
        return Score(s.mean(axis=-1), seen_count / self.count, mean_unc)

    def current(self) -> Score:
        """Score of the committed cameras."""
        return self.score(self.info, self.seen)

    def evaluate(self, positions: np.ndarray, rotations: np.ndarray, zoom=1.0,
                 feasible: np.ndarray | None = None) -> np.ndarray:
        """Fitness (B,) of the committed cameras plus each candidate camera; infeasible ones score 0.

        Only the points a candidate sees change score, so only those pairs are fused."""
        positions = np.asarray(positions, np.float64).reshape(-1, 3)
        out = np.zeros(len(positions))
        keep = np.ones(len(positions), bool) if feasible is None else np.asarray(feasible, bool)
        self.evaluations += len(positions)
        if not keep.any():
            return out
        zoom = np.broadcast_to(np.asarray(zoom, np.float64), (len(positions),))
        mask, info = self.views(positions[keep], np.asarray(rotations)[keep], zoom[keep])
        base = self._base_scores()
        cam, pt = np.nonzero(mask)
        gain = point_score(self.info[pt] + info[cam, pt], np.ones(len(pt), bool))[0] - base[pt]
        out[keep] = (base.sum() + np.bincount(cam, gain, minlength=mask.shape[0])) / self.count
        return out

    def _base_scores(self) -> np.ndarray:
        """Per-point scores of the committed cameras (cached until the next commit)."""
        if self._base is None:
            self._base = point_score(self.info, self.seen)[0]
        return self._base

    def evaluate_arrangements(self, positions: np.ndarray, rotations: np.ndarray, zoom: np.ndarray,
                              feasible: np.ndarray) -> np.ndarray:
        """Fitness (B,) of B arrangements of K cameras each (positions (B,K,3)) added to the committed ones."""
        b, k = positions.shape[:2]
        out = np.zeros(b)
        self.evaluations += b
        keep = np.flatnonzero(feasible)
        if len(keep) == 0:
            return out
        mask, info = self.views(positions[keep].reshape(-1, 3), rotations[keep].reshape(-1, 3, 3),
                                zoom[keep].reshape(-1))
        mask = mask.reshape(len(keep), k, -1).any(axis=1)
        info = info.reshape(len(keep), k, self.count, 6).sum(axis=1)
        out[keep] = self.score(self.info[None] + info, self.seen[None] | mask).fitness
        return out

    def commit(self, position: np.ndarray, rotation: np.ndarray, zoom=1.0,
               views: tuple[np.ndarray, np.ndarray] | None = None) -> None:
        """Add one camera (position (3,)) or several (positions (B,3), one batched ray cast); `views`:
        their `views(...)` when already known."""
        mask, info = self.views(position, rotation, zoom) if views is None else views
        self.set_state(self.info + info.sum(axis=0), self.seen | mask.any(axis=0))

    def set_state(self, info: np.ndarray, seen: np.ndarray) -> None:
        """Replace the committed information sum and seen mask."""
        self.info, self.seen, self._base = info, seen, None

    def reset(self) -> None:
        """Forget every committed camera."""
        self.set_state(np.zeros_like(self.info), np.zeros_like(self.seen))
