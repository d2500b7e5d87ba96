"""Rotations, poses and up-axis parsing (the up estimate itself is in perch_common.up_axis)."""

from __future__ import annotations

import numpy as np

# Imported up front: a lazy import here once stalled a node's first pose callback for ~1 s.
from scipy.spatial.transform import Rotation


def quaternion_from_matrix(r: np.ndarray) -> np.ndarray:
    """(x, y, z, w) unit quaternion of a 3x3 rotation matrix."""
    return Rotation.from_matrix(np.asarray(r, np.float64)[:3, :3]).as_quat()


def matrix_from_quaternion(q: np.ndarray) -> np.ndarray:
    """3x3 rotation of an (x, y, z, w) quaternion; a zero quaternion is the identity."""
    q = np.asarray(q, np.float64)
    if not np.any(q):
        return np.eye(3)
    return Rotation.from_quat(q).as_matrix()


def pose_to_matrix(pose) -> np.ndarray:
    """4x4 of anything shaped like geometry_msgs/Pose (position.x.., orientation.x..w), e.g. a
    message decoded from a bag without the message packages."""
    o, p = pose.orientation, pose.position
    out = np.eye(4)
    out[:3, :3] = matrix_from_quaternion(np.array([o.x, o.y, o.z, o.w], np.float64))
    out[:3, 3] = [p.x, p.y, p.z]
    return out


def rotation_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The smallest rotation taking unit direction a onto unit direction b."""
    a = np.asarray(a, np.float64) / np.linalg.norm(a)
    b = np.asarray(b, np.float64) / np.linalg.norm(b)
    v, c = np.cross(a, b), float(a @ b)
    if c < -1 + 1e-12:  # opposite: turn half a circle about any perpendicular axis
        axis = np.cross(a, [1.0, 0, 0] if abs(a[0]) < 0.9 else [0, 1.0, 0])
        axis /= np.linalg.norm(axis)
        return 2 * np.outer(axis, axis) - np.eye(3)
    k = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + k + k @ k / (1 + c)


def optical_pose_looking_at(position, target, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """4x4 pose of a camera's optical frame (z forward, x right, y down, as REP 103 names it) at
    `position` looking at `target`, level with `up`; ValueError when the target is straight above
    or below (no level view)."""
    position = np.asarray(position, np.float64)
    forward = np.asarray(target, np.float64) - position
    forward /= np.linalg.norm(forward)
    right = np.cross(forward, np.asarray(up, np.float64))
    if np.linalg.norm(right) < 1e-9:
        raise ValueError("the target is straight above or below the camera: no level view of it")
    right /= np.linalg.norm(right)
    pose = np.eye(4)
    pose[:3, :3] = np.column_stack([right, np.cross(forward, right), forward])
    pose[:3, 3] = position
    return pose


UP_AXES = {"+x": (1, 0, 0), "-x": (-1, 0, 0), "+y": (0, 1, 0), "-y": (0, -1, 0),
           "+z": (0, 0, 1), "-z": (0, 0, -1)}


UNCHECKED = "!"  # a given up axis ending in it is taken without checking it against the mesh (up_axis.choose_up)


def parse_up_axis(text: str) -> np.ndarray:
    """'+z', '-y', ... or 'x y z' components as a unit vector (a trailing UNCHECKED is allowed)."""
    key = text.strip().lower().removesuffix(UNCHECKED).strip()
    if key in UP_AXES:
        return np.array(UP_AXES[key], np.float64)
    if key in ("x", "y", "z"):
        return np.array(UP_AXES["+" + key], np.float64)
    try:
        v = np.array([float(t) for t in key.replace(",", " ").split()], np.float64)
    except ValueError:
        v = np.zeros(0)
    if v.shape != (3,) or not np.isfinite(v).all() or np.linalg.norm(v) < 1e-9:
        raise ValueError(f"up axis '{text}': use +x, -x, +y, -y, +z, -z or three numbers")
    return v / np.linalg.norm(v)
