"""The frame contract: stages work in a gravity-aligned frame (z up); users get the input's own frame.

The gravity-aligned frame is the input frame rotated about its origin so that up becomes +z and
the room's walls face +-x and +-y (gravity_aligned_rotation): a property of the room, so that the
same room given in any orientation is planned in the same aligned frame. Its name is the input
frame's plus ALIGNED_SUFFIX; the transform between the two is published on /tf_static and recorded
with every mission.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from perch_common.transforms import rotation_between
from perch_common.types import CameraPlacement

ALIGNED_SUFFIX = "_gravity_aligned"
UNCONFIRMED_SOURCE = "file convention"   # the up source of a fallback (perch_common.up_axis.choose_up)
Z_UP = np.array([0.0, 0.0, 1.0])


def gravity_aligned_rotation(up: np.ndarray, axes: np.ndarray | None = None,
                             reference: np.ndarray | None = None) -> np.ndarray:
    """The rotation taking `up` onto +z and, given the room's plane directions `axes` (rows), its walls
    onto +-x and +-y; without axes the smallest rotation taking up onto +z.

    Which wall direction becomes +x is the one pointing most towards `reference` (a point of the room
    such as its area-weighted centroid, seen from the frame's origin), so the choice rotates with the
    room rather than with the input's axes.
    """
    up = np.asarray(up, np.float64) / np.linalg.norm(up)
    tilt = rotation_between(up, Z_UP)
    if axes is None or reference is None:
        return tilt
    axes = np.asarray(axes, np.float64)
    walls = axes[np.argsort(np.abs(axes @ up))[:2]] @ tilt.T  # the two directions across up, after the tilt
    walls[:, 2] = 0.0
    lengths = np.linalg.norm(walls, axis=1)
    if np.any(lengths < 0.5):  # no clear wall direction across up: keep the smallest rotation
        return tilt
    first = walls[0] / lengths[0]
    towards = tilt @ np.asarray(reference, np.float64)
    towards[2] = 0.0
    second = np.array([-first[1], first[0], 0.0])
    candidates = np.stack([first, -first, second, -second])
    x = candidates[int(np.argmax(candidates @ towards))] if np.linalg.norm(towards) > 1e-9 else first
    yaw = np.stack([x, np.cross(Z_UP, x), Z_UP])  # rows: the new axes in the tilted frame
    return yaw @ tilt


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
    def from_up(input_frame: str, up: np.ndarray, up_source: str = "given", up_confidence: float = 1.0,
                axes: np.ndarray | None = None, reference: np.ndarray | None = None) -> "Alignment":
        """The alignment that turns `up` (in the input frame) onto +z (see gravity_aligned_rotation)."""
        return Alignment(input_frame, gravity_aligned_rotation(up, axes, reference), up_source, up_confidence)

    @property
    def up_unconfirmed(self) -> str:
        """'' when the up axis was given, recorded or estimated confidently; otherwise the note every
        proposal of the mission carries (the up axis is the file's convention, a fallback)."""
        if self.up_source != UNCONFIRMED_SOURCE:
            return ""
        return (f"up axis unconfirmed: the estimate was not confident ({self.up_confidence:.2f}); up "
                f"{_axis_text(self.up)} is a fallback; check it (perch mesh info FILE) or pass --up AXIS")

    @property
    def up_estimated(self) -> str:
        """'' when the up axis was given or recorded; else what a failure that a wrong up axis would
        explain should add (a stage finding no floor, no surface, no perch)."""
        if self.up_source in ("given", "gravity", "none"):
            return ""
        how = ("is the file's convention" if self.up_source == UNCONFIRMED_SOURCE else
               "was estimated from the mesh as")
        return (f"the up axis {how} {_axis_text(self.up)} (confidence {self.up_confidence:.2f}): if that is not "
                "up, pass --up AXIS (perch mesh info FILE shows the evidence)")

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


def _axis_text(up: np.ndarray) -> str:
    from perch_common.up_axis import axis_name

    return axis_name(up)
