"""The reconstruction core: RGB-D frames (with or without poses) -> TSDF -> cleaned z-up mesh.

Pure Python over Open3D/fast-simplification; never imports rclpy. The node, the CLI and the benchmark all
drive `Reconstructor`, so live and offline runs integrate identically.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterable

import numpy as np

from perch_common.cancellation import checkpoint
from perch_common.errors import PerchError
from perch_common.frames import aligned_frame_name
from perch_common.mesh import Mesh
from perch_common.viewpoints import pinhole_half_angle, select_viewpoints, viewpoint_rows
from perch_reconstruction.bag_write import BagTopics
from perch_reconstruction.cleaning import CleanReport, clean_mesh, clean_mesh_with_report
from perch_reconstruction.config import ReconstructionConfig
from perch_reconstruction.frames import Intrinsics, RGBDFrame, check_depth
from perch_reconstruction.volume import Tracker, TsdfVolume

ODOMETRY_FRAME = "odom"  # the world frame of RGB-D odometry: the first tracked camera's pose (REP 105 name)

__all__ = ["ReconstructionConfig", "ReconstructionStats", "Reconstructor", "clean_mesh", "reconstruct_bag",
           "reconstruct_frames"]

Progress = Callable[["ReconstructionStats"], None]


@dataclass
class ReconstructionStats:
    """What happened to the frames of a reconstruction, and the resulting mesh sizes."""

    frames_received: int = 0
    frames_integrated: int = 0
    frames_dropped: int = 0         # live only: frames discarded because integration fell behind
    frames_without_pose: int = 0    # use_poses and no pose within pose_tolerance
    frames_lost: int = 0            # odometry could not place the frame
    frames_over_budget: int = 0     # the block budget (max_blocks) was full
    seconds_integrate: float = 0.0
    seconds_track: float = 0.0
    seconds_clean: float = 0.0
    blocks: int = 0
    image_size: tuple = (0, 0)      # width, height of the integrated frames
    faces_raw: int = 0
    faces: int = 0
    trajectory: list = field(default_factory=list, repr=False)  # (stamp_ns, 4x4) integrated poses
    recorded: list = field(default_factory=list, repr=False)    # (stamp_ns, 4x4) recorded poses, if any
    clean: CleanReport | None = field(default=None, repr=False)
    raw_mesh: Mesh | None = field(default=None, repr=False)       # the TSDF surface before cleaning
    frame_id: str = "map"           # the volume's (input) frame: the recorded poses' world frame, or odometry's

    def summary(self) -> dict:
        """The statistics as a plain dict for reports."""
        keys = ("frames_received", "frames_integrated", "frames_dropped", "frames_without_pose", "frames_lost",
                "frames_over_budget", "blocks", "faces_raw", "faces")
        out = {k: getattr(self, k) for k in keys}
        out.update(seconds_integrate=round(self.seconds_integrate, 3), seconds_track=round(self.seconds_track, 3),
                   seconds_clean=round(self.seconds_clean, 3))
        return out


class Reconstructor:
    """Stateful integration of a frame stream; `finish` extracts and cleans."""

    def __init__(self, config: ReconstructionConfig, use_poses: bool):
        self.config = config.validate()
        self.use_poses = use_poses
        self.reset()

    def reset(self) -> None:
        """Forget every integrated frame."""
        self.stats = ReconstructionStats()
        self.intrinsics: Intrinsics | None = None
        self._volume: TsdfVolume | None = None
        self._tracker: Tracker | None = None
        self._first_recorded: np.ndarray | None = None

    def add_frame(self, frame: RGBDFrame, intrinsics: Intrinsics, what: str = "depth") -> bool:
        """Integrate one frame; True when it went into the volume. Raises PerchError for bad input
        (the volume is left as it was)."""
        self.stats.frames_received += 1
        if self.intrinsics is None:
            self.intrinsics = intrinsics
            self.stats.image_size = (intrinsics.width, intrinsics.height)
            self._volume = TsdfVolume(self.config, intrinsics)
            self._tracker = None if self.use_poses else Tracker(self._volume)
        elif intrinsics != self.intrinsics:
            raise PerchError(f"camera intrinsics changed from {self.intrinsics} to {intrinsics} mid-stream; "
                             "reset the reconstruction before switching cameras")
        if frame.depth.shape != (intrinsics.height, intrinsics.width) or frame.color.shape[:2] != frame.depth.shape:
            raise PerchError(f"frame sizes differ: colour {frame.color.shape[1]}x{frame.color.shape[0]}, depth "
                             f"{frame.depth.shape[1]}x{frame.depth.shape[0]}, camera info "
                             f"{intrinsics.width}x{intrinsics.height}")
        check_depth(frame.depth[::4, ::4], what)
        if frame.pose is not None:
            self.stats.recorded.append((frame.stamp_ns, frame.pose))
        start = time.perf_counter()
        if self.use_poses:
            pose = frame.pose
            if pose is None:
                self.stats.frames_without_pose += 1
                return False
        else:
            if not self._tracker.started:  # this frame defines the odometry world frame
                self._first_recorded = frame.pose
            pose = self._tracker.track(frame)
            self.stats.seconds_track += time.perf_counter() - start
            if pose is None:
                self.stats.frames_lost = self._tracker.frames_lost
                return False
        start = time.perf_counter()
        ok = self._volume.integrate(frame, pose)
        self.stats.seconds_integrate += time.perf_counter() - start
        self.stats.frames_over_budget = self._volume.frames_over_budget
        self.stats.blocks = self._volume.blocks
        if ok:
            self.stats.frames_integrated += 1
            self.stats.trajectory.append((frame.stamp_ns, pose))
        return ok

    def gravity_in_volume(self, gravity_world: np.ndarray | None) -> np.ndarray | None:
        """Gravity in the volume's frame: the recorded world frame with poses, else the first camera's."""
        if gravity_world is None:
            return None
        if self.use_poses:
            return gravity_world
        if self._first_recorded is None:
            return None  # odometry world frame unrelated to the gravity's frame: estimate instead
        return self._first_recorded[:3, :3].T @ gravity_world

    def camera_down(self) -> np.ndarray | None:
        """Mean image-down (optical y) axis of the integrated cameras: a rough gravity for hand-held
        and drone footage, used to tell the floor from the walls."""
        if not self.stats.trajectory:
            return None
        return np.mean([pose[:3, 1] for _, pose in self.stats.trajectory], axis=0)

    def viewpoints(self) -> np.ndarray | None:
        """The integrated cameras' distinct views (perch_common.viewpoints) in the volume's frame: what
        the filter counts as observed free space. None before any frame."""
        if not self.stats.trajectory or self.intrinsics is None:
            return None
        poses = np.array([pose for _, pose in self.stats.trajectory])   # world from camera
        k = self.intrinsics
        return select_viewpoints(viewpoint_rows(poses[:, :3, 3], poses[:, :3, 2], self.config.depth_max,
                                                pinhole_half_angle(k.width, k.height, k.fx, k.fy)))

    def extract(self, frame_id: str = "map") -> Mesh:
        """The mesh of the integrated frames (PerchError when nothing was integrated)."""
        if self._volume is None or self.stats.frames_integrated == 0:
            raise PerchError("nothing integrated yet: no frame could be used (check topics, camera info and poses)")
        mesh = self._volume.extract(frame_id)
        mesh.viewpoints = self.viewpoints()
        self.stats.faces_raw = mesh.num_faces
        if mesh.num_faces == 0:
            raise PerchError(f"the volume holds no surface after {self.stats.frames_integrated} frames "
                             f"(weight_threshold {self.config.weight_threshold}); integrate more frames")
        return mesh

    def finish(self, gravity_world: np.ndarray | None = None, clean: bool = True, frame_id: str = "map") -> Mesh:
        """Extract the surface and (optionally) clean and gravity-align it.

        frame_id names the volume's frame (the poses' world frame); stats.frame_id keeps it, while a
        cleaned mesh is in its gravity-aligned frame (stats.clean.rotation from the former).
        """
        self.stats.frame_id = frame_id
        mesh = self.extract(frame_id)
        self.stats.raw_mesh = mesh
        if not clean:
            self.stats.faces = mesh.num_faces
            return mesh
        mesh, report = clean_mesh_with_report(mesh, self.gravity_in_volume(gravity_world), self.config,
                                              self.camera_down())
        self.stats.clean = report
        mesh.frame_id = aligned_frame_name(frame_id)
        self.stats.seconds_clean = report.seconds
        self.stats.faces = mesh.num_faces
        return mesh


def reconstruct_frames(frames: Iterable[RGBDFrame], intrinsics: Intrinsics, config: ReconstructionConfig,
                       use_poses: bool, gravity: np.ndarray | None = None, clean: bool = True,
                       progress: Progress | None = None, progress_every: int = 30,
                       frame_id: str = "map") -> tuple[Mesh, ReconstructionStats]:
    """Integrate `frames` and finish (extract, clean); the input frame is named `frame_id`."""
    recon = Reconstructor(config, use_poses)
    recon.stats.frame_id = frame_id  # known before the first frame: progress reports name it
    for i, frame in enumerate(frames):
        checkpoint(f"frame {i}")
        recon.add_frame(frame, intrinsics)
        if progress and (i + 1) % progress_every == 0:
            progress(recon.stats)
    mesh = recon.finish(gravity, clean=clean, frame_id=frame_id)
    if progress:
        progress(recon.stats)
    return mesh, recon.stats


def reconstruct_bag(path: str | Path, config: ReconstructionConfig, use_poses: bool,
                    topics: BagTopics = BagTopics(), clean: bool = True,
                    progress: Progress | None = None) -> tuple[Mesh, ReconstructionStats]:
    """Reconstruct a recorded bag offline (poses from topics.pose, or odometry)."""
    from perch_reconstruction.bag_read import read_bag_frames

    config = config.validate()
    bag = read_bag_frames(path, topics, config.depth_scale, int(config.sync_tolerance * 1e9),
                          int(config.pose_tolerance * 1e9), config.tf_world_frame, config.tf_camera_frame)
    if use_poses and not bag.has_poses:
        raise PerchError(f"{path}: no pose topic {topics.pose} (PoseStamped or Odometry) and no /tf chain from the "
                         f"images' frame up to '{config.tf_world_frame}' (tf_world_frame); reconstruct with "
                         "odometry instead (--odometry / use_poses=false)")
    # The mesh's own frame: the recorded poses' world frame, or with odometry the first camera's.
    frame_id = (bag.pose_frame_id or "map") if use_poses else ODOMETRY_FRAME
    mesh, stats = reconstruct_frames(bag.frames, bag.intrinsics, config, use_poses, bag.gravity, clean, progress,
                                     frame_id=frame_id)
    if bag.damage and stats.clean is not None:   # said in the reply, first
        stats.clean.warnings.insert(0, bag.damage)
    return mesh, stats
