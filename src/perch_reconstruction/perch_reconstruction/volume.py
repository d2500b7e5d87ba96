"""The TSDF volume (Open3D VoxelBlockGrid via t.pipelines.slam.Model) and RGB-D tracking against it.

Tracking without poses is frame-to-model: the TSDF is rendered at a constant-velocity prediction and
the new frame aligned to it point-to-plane (no drift accumulates while the model explains the view);
when that fails, frame-to-frame hybrid (depth + colour) odometry to the previous frame takes over.
"""

from __future__ import annotations

import numpy as np

from perch_common.mesh import Mesh
from perch_reconstruction.config import ReconstructionConfig
from perch_reconstruction.frames import Intrinsics, RGBDFrame

INITIAL_BLOCKS = 2000  # the hash map grows on demand up to config.max_blocks
DEPTH_SCALE = 1000.0  # Open3D integrates (uint16 depth, uint8 colour): depth goes in as millimetres
MAX_MODEL_CORRECTION_M = 0.1  # larger frame-to-model corrections are treated as failures
BUDGET_MARGIN_FACTOR = 4
MIN_TRACKING_WIDTH = 160  # px


def depth_mm(depth_m: np.ndarray) -> np.ndarray:
    """Depth in metres as 16-bit millimetres."""
    return np.clip(np.round(depth_m * DEPTH_SCALE), 0, 65535).astype(np.uint16)


def _o3d():
    from perch_common.open3d_loader import open3d
    o3d = open3d()

    # Open3D logs warnings on stdout (per frame from the SLAM model), which would corrupt JSON output.
    o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)
    return o3d


class TsdfVolume:
    """Integrates RGB-D frames at given poses; extracts the coloured surface mesh."""

    def __init__(self, config: ReconstructionConfig, intrinsics: Intrinsics):
        o3d = _o3d()
        self.config = config
        self.intrinsics = intrinsics
        self._device = o3d.core.Device("CPU:0")
        self._model = o3d.t.pipelines.slam.Model(config.voxel_size, config.block_resolution, INITIAL_BLOCKS,
                                                 o3d.core.Tensor(np.eye(4)), self._device)
        self._k = o3d.core.Tensor(intrinsics.matrix(), o3d.core.float64)
        self._frame = o3d.t.pipelines.slam.Frame(intrinsics.height, intrinsics.width, self._k, self._device)
        self.frames_integrated = 0
        self.frames_over_budget = 0
        self._budget_margin: int | None = None  # unknown until a first frame shows what one frame adds

    @property
    def blocks(self) -> int:
        """Number of allocated TSDF blocks."""
        return int(self._model.get_hashmap().size())

    def _image(self, array: np.ndarray):
        o3d = _o3d()
        return o3d.t.geometry.Image(o3d.core.Tensor(np.ascontiguousarray(array)))

    def integrate(self, frame: RGBDFrame, pose: np.ndarray) -> bool:
        """Fuse the frame at world-from-camera `pose`; False (and counted) when over the block budget."""
        o3d = _o3d()
        c = self.config
        near = frame.depth < c.depth_min
        depth = self._image(depth_mm(np.where(near, 0.0, frame.depth) if near.any() else frame.depth))
        extrinsic = o3d.core.Tensor(np.linalg.inv(pose), o3d.core.float64)
        if self._budget_margin is None or self.blocks + self._budget_margin > c.max_blocks:
            # Near the budget: count exactly which blocks this frame would add.
            needed = self._model.voxel_grid.compute_unique_block_coordinates(
                depth, self._k, extrinsic, DEPTH_SCALE, c.depth_max, c.trunc_voxel_multiplier)
            _, found = self._model.get_hashmap().find(needed)
            new_blocks = int(needed.shape[0]) - int(found.numpy().sum())
            if self.blocks + new_blocks > c.max_blocks:
                self.frames_over_budget += 1
                return False
        self._frame.set_data_from_image("depth", depth)
        self._frame.set_data_from_image("color", self._image(frame.color))
        self._model.update_frame_pose(self.frames_integrated, o3d.core.Tensor(np.asarray(pose, np.float64)))
        before = self.blocks
        self._model.integrate(self._frame, DEPTH_SCALE, c.depth_max, c.trunc_voxel_multiplier)
        # Far from the budget the exact check is skipped: no frame adds more than a few times the
        # blocks the largest one so far added.
        self._budget_margin = max(self._budget_margin or 0, BUDGET_MARGIN_FACTOR * (self.blocks - before))
        self.frames_integrated += 1
        return True

    def extract(self, frame_id: str = "map") -> Mesh:
        """The zero crossing where the weight reaches config.weight_threshold, vertex colours in 0..255."""
        if self.frames_integrated == 0:
            return Mesh(np.zeros((0, 3)), np.zeros((0, 3), np.int64), frame_id=frame_id)
        mesh = self._model.extract_trianglemesh(self.config.weight_threshold)
        vertices = mesh.vertex.positions.numpy().astype(np.float64)
        faces = mesh.triangle.indices.numpy().astype(np.int64) if "indices" in mesh.triangle else np.zeros((0, 3))
        colors = None
        if "colors" in mesh.vertex:
            raw = mesh.vertex.colors.numpy().astype(np.float64)
            scale = 255.0 if raw.size and raw.max() <= 1.0 + 1e-6 else 1.0
            colors = np.clip(np.round(raw * scale), 0, 255).astype(np.uint8)
        return Mesh(*in_canonical_order(vertices, faces, colors), frame_id=frame_id)

    def render_depth(self, pose: np.ndarray, intrinsics: Intrinsics):
        """Ray-cast the volume at `pose` into an slam.Frame of the given intrinsics."""
        o3d = _o3d()
        c = self.config
        k = o3d.core.Tensor(intrinsics.matrix(), o3d.core.float64)
        rendered = o3d.t.pipelines.slam.Frame(intrinsics.height, intrinsics.width, k, self._device)
        self._model.update_frame_pose(self.frames_integrated, o3d.core.Tensor(np.asarray(pose, np.float64)))
        self._model.synthesize_model_frame(rendered, DEPTH_SCALE, c.depth_min, c.depth_max, c.trunc_voxel_multiplier,
                                           False)
        return rendered

    def track_to_model(self, frame_small, pose_guess: np.ndarray, intrinsics: Intrinsics):
        """Point-to-plane alignment of a (tracking-scale) slam.Frame to the volume seen from pose_guess.

        Returns (pose, fitness, correction length in m)."""
        o3d = _o3d()
        odo = o3d.t.pipelines.odometry
        rendered = self.render_depth(pose_guess, intrinsics)
        criteria = [odo.OdometryConvergenceCriteria(i) for i in (10, 5, 3)]
        try:
            result = self._model.track_frame_to_model(frame_small, rendered, DEPTH_SCALE, self.config.depth_max,
                                                      self.config.tracking_depth_diff, odo.Method.PointToPlane,
                                                      criteria)
        except RuntimeError:  # "Singular 6x6 linear system": too little geometry in view
            return pose_guess, 0.0, 0.0
        delta = result.transformation.numpy()
        return pose_guess @ delta, float(result.fitness), float(np.linalg.norm(delta[:3, 3]))


class Tracker:
    """Camera poses from RGB-D alone (the first frame defines the world frame)."""

    def __init__(self, volume: TsdfVolume):
        o3d = _o3d()
        self.volume = volume
        self.config = volume.config
        # Three pyramid levels need enough pixels at the coarsest one: never below MIN_TRACKING_WIDTH.
        scale = min(1.0, max(volume.config.tracking_scale, MIN_TRACKING_WIDTH / volume.intrinsics.width))
        self.small = volume.intrinsics.scaled(scale)
        self._k_small = o3d.core.Tensor(self.small.matrix(), o3d.core.float64)
        self._previous = None           # last tracked RGBDImage (tracking scale)
        self._pose = np.eye(4)
        self._velocity = np.eye(4)      # last relative motion, the next guess
        self.frames_lost = 0
        self.model_corrections = 0

    @property
    def started(self) -> bool:
        """True once a first frame fixed the world frame (its camera frame)."""
        return self._previous is not None

    def _downscale(self, frame: RGBDFrame):
        import cv2

        o3d = _o3d()
        size = (self.small.width, self.small.height)
        depth = depth_mm(frame.depth)
        if depth.shape[::-1] != size:
            depth = cv2.resize(depth, size, interpolation=cv2.INTER_NEAREST)
        color = frame.color if frame.color.shape[1::-1] == size else cv2.resize(frame.color, size,
                                                                               interpolation=cv2.INTER_AREA)
        return (o3d.t.geometry.Image(o3d.core.Tensor(np.ascontiguousarray(depth))),
                o3d.t.geometry.Image(o3d.core.Tensor(np.ascontiguousarray(color))))

    def track(self, frame: RGBDFrame) -> np.ndarray | None:
        """World-from-camera pose of the frame, or None when tracking is lost (frame not to integrate)."""
        o3d = _o3d()
        c = self.config
        depth, color = self._downscale(frame)
        current = o3d.t.geometry.RGBDImage(color, depth)
        if self._previous is None:
            self._previous = current
            return self._pose.copy()
        guess = self._pose @ self._velocity
        pose = None
        if self.volume.frames_integrated:
            small = o3d.t.pipelines.slam.Frame(self.small.height, self.small.width, self._k_small,
                                               self.volume._device)
            small.set_data_from_image("depth", depth)
            small.set_data_from_image("color", color)
            refined, fitness, shift = self.volume.track_to_model(small, guess, self.small)
            if fitness >= c.tracking_min_fitness and shift < MAX_MODEL_CORRECTION_M:
                pose = refined
                self.model_corrections += 1
        if pose is None:
            pose = self._frame_to_frame(current)
        if pose is None:
            self.frames_lost += 1
            return None
        self._velocity = np.linalg.inv(self._pose) @ pose
        self._pose = pose
        self._previous = current
        return pose.copy()

    def _frame_to_frame(self, current) -> np.ndarray | None:
        """Fallback when the model does not explain the frame: hybrid odometry to the previous frame."""
        o3d = _o3d()
        odo = o3d.t.pipelines.odometry
        c = self.config
        criteria = [odo.OdometryConvergenceCriteria(i) for i in (10, 5, 3)]
        try:
            result = odo.rgbd_odometry_multi_scale(
                current, self._previous, self._k_small, o3d.core.Tensor(self._velocity), DEPTH_SCALE, c.depth_max,
                criteria, odo.Method.Hybrid, odo.OdometryLossParams(c.tracking_depth_diff, 0.05, 0.1))
        except RuntimeError:  # singular system: nothing to align to
            return None
        if result.fitness < c.tracking_min_fitness:
            return None
        return self._pose @ result.transformation.numpy()


def in_canonical_order(vertices: np.ndarray, faces: np.ndarray, colors: np.ndarray | None):
    """Vertices sorted by position, then faces by their vertices. Open3D's parallel extraction lists
    the same triangles (each in the same turn) in a different order from run to run, and decimation
    breaks ties by order: sorted, the same volume gives the same mesh."""
    order = np.lexsort(vertices.T[::-1])
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    faces = rank[faces]
    if len(vertices) < 1 << 21:   # three indices fit one int64 key: one argsort instead of a lexsort
        key = (faces[:, 0] << 42) | (faces[:, 1] << 21) | faces[:, 2]
        faces = faces[np.argsort(key)]
    else:
        faces = faces[np.lexsort(faces.T[::-1])]
    return vertices[order], faces, None if colors is None else colors[order]
