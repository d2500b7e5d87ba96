"""The frame contract: stages work in a gravity-aligned frame (z up); users get the input's own frame.

The gravity-aligned frame is the input frame rotated about its origin so that up becomes +z (the
smallest such rotation). Its name is the input frame's plus ALIGNED_SUFFIX; the transform between
the two is published on /tf_static and recorded with every mission.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from perch_common.transforms import rotation_between
from perch_common.types import CameraPlacement

ALIGNED_SUFFIX = "_gravity_aligned"
Z_UP = np.array([0.0, 0.0, 1.0])


def aligned_frame_name(input_frame: str) -> str:
    """The name of the gravity-aligned frame of `input_frame` ('map' -> 'map_gravity_aligned')."""
    return input_frame if input_frame.endswith(ALIGNED_SUFFIX) else input_frame + ALIGNED_SUFFIX


@dataclass(frozen=True)
class Alignment:
    """How the gravity-aligned frame sits in the input frame: p_aligned = rotation @ p_input."""

    input_frame: str
    rotation: np.ndarray
    up_source: str = "given"
    up_confidence: float = 1.0

    @staticmethod
    def from_up(input_frame: str, up: np.ndarray, up_source: str = "given", up_confidence: float = 1.0) -> "Alignment":
        """The alignment that turns `up` (in the input frame) onto +z."""
        return Alignment(input_frame, rotation_between(np.asarray(up, np.float64), Z_UP), up_source, up_confidence)

    @property
    def aligned_frame(self) -> str:
        """Name of the gravity-aligned frame."""
        return aligned_frame_name(self.input_frame)

    @property
    def up(self) -> np.ndarray:
        """Up in the input frame."""
        return np.asarray(self.rotation).T @ Z_UP

    def is_identity(self, tolerance: float = 1e-9) -> bool:
        """True when the input frame is already gravity-aligned."""
        return bool(np.allclose(self.rotation, np.eye(3), atol=tolerance))

    def to_aligned(self) -> np.ndarray:
        """4x4 taking input-frame coordinates to the gravity-aligned frame."""
        out = np.eye(4)
        out[:3, :3] = self.rotation
        return out

    def to_input(self) -> np.ndarray:
        """4x4 taking gravity-aligned coordinates to the input frame (the /tf_static transform)."""
        out = np.eye(4)
        out[:3, :3] = np.asarray(self.rotation).T
        return out

    def point_to_input(self, point: np.ndarray) -> np.ndarray:
        """A gravity-aligned point (or (N,3) points) in the input frame."""
        return np.asarray(point, np.float64) @ np.asarray(self.rotation)

    def pose_to_input(self, pose: np.ndarray) -> np.ndarray:
        """A gravity-aligned 4x4 pose in the input frame."""
        return self.to_input() @ np.asarray(pose, np.float64)

    def placement_to_input(self, placement: CameraPlacement) -> CameraPlacement:
        """A placement (drone and camera poses) in the input frame; everything else unchanged."""
        return replace(placement, drone_pose=self.pose_to_input(placement.drone_pose),
                       camera_pose=self.pose_to_input(placement.camera_pose))

    def placement_to_aligned(self, placement: CameraPlacement) -> CameraPlacement:
        """The inverse of placement_to_input."""
        to_aligned = self.to_aligned()
        return replace(placement, drone_pose=to_aligned @ np.asarray(placement.drone_pose, np.float64),
                       camera_pose=to_aligned @ np.asarray(placement.camera_pose, np.float64))
