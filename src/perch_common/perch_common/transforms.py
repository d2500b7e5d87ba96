"""Rotations and the up axis (gravity) handling."""

from __future__ import annotations

import numpy as np


def quaternion_from_matrix(r: np.ndarray) -> np.ndarray:
    """(x, y, z, w) unit quaternion of a 3x3 rotation matrix."""
    from scipy.spatial.transform import Rotation

    return Rotation.from_matrix(np.asarray(r, np.float64)[:3, :3]).as_quat()


def matrix_from_quaternion(q: np.ndarray) -> np.ndarray:
    """3x3 rotation of an (x, y, z, w) quaternion; a zero quaternion is the identity."""
    from scipy.spatial.transform import Rotation

    q = np.asarray(q, np.float64)
    if not np.any(q):
        return np.eye(3)
    return Rotation.from_quat(q).as_matrix()


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


UP_AXES = {"+x": (1, 0, 0), "-x": (-1, 0, 0), "+y": (0, 1, 0), "-y": (0, -1, 0),
           "+z": (0, 0, 1), "-z": (0, 0, -1)}


def parse_up_axis(text: str) -> np.ndarray:
    """'+z', '-y', ... or 'x y z' components as a unit vector."""
    key = text.strip().lower()
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


def estimate_up(normals: np.ndarray, areas: np.ndarray, bins: int = 2000,
                max_samples: int = 8000) -> tuple[np.ndarray, float]:
    """Up direction from the dominant horizontal planes (floor and ceiling).

    Floors and ceilings are the largest areas sharing one normal axis up to sign; walls spread
    around the circle orthogonal to it. Returns (up, confidence in [0, 1]): the share of area whose
    normals lie within 10 degrees of +-up. The sign is chosen so most of that area faces up
    (a scanned room sees more floor than ceiling from above; callers may flip with other evidence).
    """
    normals = np.asarray(normals, np.float64)
    areas = np.asarray(areas, np.float64)
    ok = np.linalg.norm(normals, axis=1) > 0.5
    normals, areas = normals[ok], areas[ok]
    if len(normals) == 0 or areas.sum() <= 0:
        return np.array([0.0, 0.0, 1.0]), 0.0
    # Fold antipodal normals together, then take the area-weighted densest direction. The
    # search runs on an area-weighted sample (seeded: the answer is deterministic).
    sample = np.arange(len(normals))
    if len(normals) > max_samples:
        rng = np.random.default_rng(0)
        sample = rng.choice(len(normals), max_samples, replace=True, p=areas / areas.sum())
    fib = _fibonacci_sphere(bins)
    fib = fib[fib[:, 2] >= 0]
    weights = areas[sample] if len(sample) == len(normals) else np.ones(len(sample))
    score = weights @ (np.abs(normals[sample] @ fib.T) > np.cos(np.radians(10)))
    best = fib[int(np.argmax(score))]
    near = np.abs(normals @ best) > np.cos(np.radians(10))
    signs = np.sign(normals[near] @ best)
    axis = (normals[near] * signs[:, None] * areas[near, None]).sum(axis=0)
    axis /= np.linalg.norm(axis)
    up_area = areas[near][normals[near] @ axis > 0].sum()
    down_area = areas[near][normals[near] @ axis < 0].sum()
    if down_area > up_area:
        axis = -axis
    return axis, float(areas[near].sum() / areas.sum())


def _fibonacci_sphere(n: int) -> np.ndarray:
    i = np.arange(n) + 0.5
    phi = np.arccos(1 - 2 * i / n)
    theta = np.pi * (1 + 5 ** 0.5) * i
    return np.stack([np.cos(theta) * np.sin(phi), np.sin(theta) * np.sin(phi), np.cos(phi)], axis=1)
