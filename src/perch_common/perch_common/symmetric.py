"""Symmetric 3x3 matrices packed as 6 components (xx yy zz xy xz yz) and their closed-form eigenvalues.

Segmentation packs surface covariances this way and placement packs fused information; both need
eigenvalues of millions of them, which the trigonometric closed form gives without a batched eigh.
"""

from __future__ import annotations

import numpy as np

# (row, column) of each packed component.
SYM6 = ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2))


def unpack(packed: np.ndarray) -> np.ndarray:
    """(..., 6) packed components to full (..., 3, 3) symmetric matrices."""
    out = np.empty(packed.shape[:-1] + (3, 3))
    for k, (i, j) in enumerate(SYM6):
        out[..., i, j] = packed[..., k]
        out[..., j, i] = packed[..., k]
    return out


def pack(matrices: np.ndarray) -> np.ndarray:
    """(..., 3, 3) symmetric matrices to (..., 6) packed components."""
    return np.stack([matrices[..., i, j] for i, j in SYM6], axis=-1)


def _trigonometric(packed: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """q (mean eigenvalue), p (spread), phi (angle) and whether p is non-degenerate."""
    a, d, f, b, c, e = (packed[..., k] for k in range(6))  # xx yy zz xy xz yz
    q = (a + d + f) / 3
    p1 = b * b + c * c + e * e
    p2 = (a - q) ** 2 + (d - q) ** 2 + (f - q) ** 2 + 2 * p1
    p = np.sqrt(np.maximum(p2, 0) / 6)
    spread = p > 1e-300
    safe = np.where(spread, p, 1.0)
    ba, bd, bf, bb, bc, be = (a - q) / safe, (d - q) / safe, (f - q) / safe, b / safe, c / safe, e / safe
    det = ba * (bd * bf - be * be) - bb * (bb * bf - be * bc) + bc * (bb * be - bd * bc)
    phi = np.arccos(np.clip(det / 2, -1.0, 1.0)) / 3
    return q, p, phi, spread


def smallest_eigenvalue(packed: np.ndarray) -> np.ndarray:
    """Smallest eigenvalue of each packed symmetric 3x3 matrix (..., 6)."""
    q, p, phi, spread = _trigonometric(packed)
    return np.where(spread, q + 2 * p * np.cos(phi + 2 * np.pi / 3), q)


def eigenvalues(packed: np.ndarray) -> np.ndarray:
    """(..., 3) ascending eigenvalues of packed symmetric 3x3 matrices (..., 6)."""
    q, p, phi, spread = _trigonometric(packed)
    largest = np.where(spread, q + 2 * p * np.cos(phi), q)
    smallest = np.where(spread, q + 2 * p * np.cos(phi + 2 * np.pi / 3), q)
    middle = 3 * q - largest - smallest
    return np.stack([smallest, middle, largest], axis=-1)
