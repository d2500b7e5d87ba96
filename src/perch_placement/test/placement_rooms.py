"""Test rooms for the placement tests: a closed box room with hand-made perch regions."""

from __future__ import annotations

import numpy as np

from perch_common.mesh import Mesh
from perch_common.types import PerchRegion, PlaneFrame, SurfaceClass


def box_mesh(lo, hi) -> Mesh:
    """A closed axis-aligned box, faces wound to point inwards (a room seen from inside)."""
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    v = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    faces = [f for a, b, c, d in quads for f in ((a, b, c), (a, c, d))]
    return Mesh(v, np.array(faces))


def rectangle_region(region_id: int, centre, normal, width: float, height: float,
                     surface_class: SurfaceClass = SurfaceClass.WALL, up=(0.0, 0.0, 1.0)) -> PerchRegion:
    """A width x height rectangle centred on `centre` in the plane with `normal` (into free space)."""
    frame = PlaneFrame.from_normal(np.asarray(centre, np.float64), normal, np.asarray(up, np.float64))
    ring = np.array([[-width / 2, -height / 2], [width / 2, -height / 2], [width / 2, height / 2],
                     [-width / 2, height / 2]])
    mesh = Mesh(frame.to_world(ring), np.array([[0, 1, 2], [0, 2, 3]]))
    return PerchRegion(region_id, region_id, surface_class, frame, [[ring]], mesh, width * height)


def box_room(size=(6.0, 5.0, 3.0), inset: float = 0.3, ceiling: bool = True) -> tuple[Mesh, list[PerchRegion]]:
    """A room [0,size] with one region per wall (inset from the edges) and optionally the ceiling."""
    sx, sy, sz = size
    mesh = box_mesh((0, 0, 0), size)
    h = sz - 2 * inset
    regions = [
        rectangle_region(0, (sx / 2, 0, sz / 2), (0, 1, 0), sx - 2 * inset, h),
        rectangle_region(1, (sx / 2, sy, sz / 2), (0, -1, 0), sx - 2 * inset, h),
        rectangle_region(2, (0, sy / 2, sz / 2), (1, 0, 0), sy - 2 * inset, h),
        rectangle_region(3, (sx, sy / 2, sz / 2), (-1, 0, 0), sy - 2 * inset, h),
    ]
    if ceiling:
        regions.append(rectangle_region(4, (sx / 2, sy / 2, sz), (0, 0, -1), sx - 2 * inset, sy - 2 * inset,
                                        SurfaceClass.CEILING))
    return mesh, regions
