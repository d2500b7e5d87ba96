"""Precise errors for malformed filter input (the node turns them into success=false replies)."""

from __future__ import annotations

import functools

import numpy as np

from perch_common.mesh import Mesh
from perch_common.target import TargetVolume
from perch_common.types import Surface

FOREIGN_FACES_M = 0.25  # a surface's faces lying (median) farther than this from its plane are not its own


def validate_inputs(mesh: Mesh, surfaces: list[Surface], target: TargetVolume | None, up: np.ndarray) -> np.ndarray:
    """Check surfaces, target and up axis against the mesh; return the unit up vector."""
    up = np.asarray(up, np.float64).reshape(-1)
    if up.shape != (3,) or not np.isfinite(up).all() or np.linalg.norm(up) < 1e-9:
        raise ValueError(f"up axis {up.tolist()} must be a finite, non-zero 3-vector")
    up = up / np.linalg.norm(up)
    if target is None:
        raise ValueError("target volume: none given (the filter needs a box or footprint target)")
    lo, hi = mesh.bounds()
    if not np.isfinite(target.centroid()).all() or target.centre_outside(lo, hi):
        raise ValueError(f"target volume: its centre {np.round(target.centroid(), 3).tolist()} lies outside the mesh bounds "
                         f"{np.round(lo, 3).tolist()} .. {np.round(hi, 3).tolist()}")
    seen: set[int] = set()
    centroids = functools.cache(mesh.face_centroids)  # once, and only when a surface has faces

    for k, s in enumerate(surfaces):
        name = f"surface {s.id} (input #{k})"
        if s.id in seen:
            raise ValueError(f"{name}: duplicate surface id {s.id}")
        seen.add(s.id)
        f = s.frame
        parts = np.concatenate([np.ravel(f.origin), np.ravel(f.normal), np.ravel(f.axis_u), np.ravel(f.axis_v)])
        if parts.shape != (12,) or not np.isfinite(parts).all():
            raise ValueError(f"{name}: frame has NaN, infinite or missing components")
        if abs(np.linalg.norm(f.normal) - 1.0) > 1e-3:
            raise ValueError(f"{name}: frame normal has length {np.linalg.norm(f.normal):.4f}, expected 1")
        faces = np.asarray(s.face_indices)
        if len(faces) and (faces.min() < 0 or faces.max() >= mesh.num_faces):
            raise ValueError(f"{name}: face indices {int(faces.min())}..{int(faces.max())} outside the mesh's "
                             f"0..{mesh.num_faces - 1}")
        if not s.boundary and not len(faces):
            raise ValueError(f"{name}: has neither a boundary nor faces")
        if len(faces):
            # Indices in range may still be another mesh's: a plane's own faces lie on it (segmentation
            # keeps them within centimetres); the filter would judge a surface that is not there.
            off = float(np.median(np.abs((centroids()[faces] - f.origin) @ np.asarray(f.normal, np.float64))))
            if off > FOREIGN_FACES_M:
                raise ValueError(f"{name}: its faces lie {off:.2f} m (median) from its plane: they are not this "
                                 "mesh's faces of it (segment the mesh you filter, and send both)")
        for poly in s.boundary:
            for ring in poly:
                ring = np.asarray(ring, np.float64)
                if ring.ndim != 2 or ring.shape[1] != 2 or not np.isfinite(ring).all():
                    raise ValueError(f"{name}: boundary ring of shape {ring.shape} is not finite (K,2)")
    return up
