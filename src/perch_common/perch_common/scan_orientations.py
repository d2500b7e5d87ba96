"""The orientations a scan is tried in (z-up, y-up, y-down, x-up, two tilts) and the shared real scans'
true up, for the rotated-world tests and `perch bench up`."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from perch_common.transforms import rotation_between

Z = np.array([0.0, 0.0, 1.0])


def _tilt(degrees: float, seed: int) -> np.ndarray:
    """A rotation by `degrees` about a seeded random axis."""
    axis = np.random.default_rng(seed).normal(size=3)
    return Rotation.from_rotvec(np.radians(degrees) * axis / np.linalg.norm(axis)).as_matrix()


# Rotation applied to a z-up scan: the copy's up is ORIENTATIONS[name] @ z. Rotations, not just
# up vectors, so that the copies differ in yaw too.
ORIENTATIONS: dict[str, np.ndarray] = {
    "z-up": np.eye(3),
    "y-up": Rotation.from_euler("x", -90, degrees=True).as_matrix(),
    "y-down": Rotation.from_euler("x", 90, degrees=True).as_matrix(),
    "x-up": Rotation.from_euler("y", 90, degrees=True).as_matrix(),
    "tilt-25": _tilt(25.0, seed=1),
    "tilt-35": _tilt(35.0, seed=2),
}

# The shared real scans (../shared/data/meshes) and their true up in the file's own frame.
REAL_SCANS: dict[str, np.ndarray] = {
    "apartment.ply": np.array([0.0, 0.0, 1.0]),
    "icl_livingroom_kt2.obj": np.array([0.0, -1.0, 0.0]),
    "icl_office_kt2.obj": np.array([0.0, -1.0, 0.0]),
}


def orientation_transform(true_up: np.ndarray, orientation: str) -> np.ndarray:
    """4x4 rotation taking a scan whose up is `true_up` into `orientation` (its up ends on ORIENTATIONS @ z)."""
    out = np.eye(4)
    out[:3, :3] = ORIENTATIONS[orientation] @ rotation_between(np.asarray(true_up, np.float64), Z)
    return out


def oriented(mesh, true_up: np.ndarray, orientation: str):
    """(the mesh rotated into `orientation`, its true up there, the 4x4 applied)."""
    transform = orientation_transform(true_up, orientation)
    return mesh.transformed(transform), transform[:3, :3] @ (np.asarray(true_up, np.float64)
                                                             / np.linalg.norm(true_up)), transform
