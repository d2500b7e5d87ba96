"""Patches over small holes in surfaces, so the target is not 'seen' through gaps in the reconstruction.

A hole in a surface's boundary that a drone could not fly through (no disc of the drone radius
fits in it) is taken as missing reconstruction, not an opening: line-of-sight rays through it
count as blocked. Doors and windows are larger, or are geometry of their own.
"""

from __future__ import annotations

import numpy as np

from perch_common.mesh import Mesh
from perch_common.raycast import RayScene
from perch_common.types import Surface


def hole_patches(surfaces: list[Surface], max_radius: float) -> Mesh | None:
    """Triangulated patches over every boundary hole narrower than 2 * max_radius, or None."""
    import mapbox_earcut
    import shapely

    vertices, faces, offset = [], [], 0
    for s in surfaces:
        for poly in s.boundary:
            for ring in poly[1:]:
                ring = np.asarray(ring, np.float64).reshape(-1, 2)
                if len(ring) < 3:
                    continue
                hole = shapely.Polygon(ring)
                if not hole.is_valid or hole.area <= 0 or not hole.buffer(-max_radius).is_empty:
                    continue
                tri = mapbox_earcut.triangulate_float64(ring, np.array([len(ring)], np.uint32))
                if len(tri) == 0:
                    continue
                vertices.append(s.frame.to_world(ring))
                faces.append(tri.astype(np.int64).reshape(-1, 3) + offset)
                offset += len(ring)
    if not faces:
        return None
    return Mesh(np.concatenate(vertices), np.concatenate(faces))


def patched_occlusion(scene: RayScene, patches: RayScene | None, origins: np.ndarray,
                      targets: np.ndarray) -> np.ndarray:
    """Segments blocked by the mesh or by a hole patch."""
    blocked = scene.occluded(origins, targets)
    if patches is not None and (~blocked).any():
        free = ~blocked
        blocked[free] = patches.occluded(origins[free], targets[free])
    return blocked
