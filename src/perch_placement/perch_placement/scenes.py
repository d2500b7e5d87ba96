"""Scenes for tests, the CLI and benchmarks: a box room with hand-made regions, and regions from
the segmentation + filtering stages (or, when those are not installed, unfiltered surfaces)."""

from __future__ import annotations

import numpy as np

from perch_common.mesh import Mesh
from perch_common.polygons import faces_outline
from perch_common.types import PerchRegion, PlaneFrame, Surface, SurfaceClass


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


def unfiltered_regions(mesh: Mesh, surfaces: list[Surface], up=(0.0, 0.0, 1.0), min_area: float = 0.5,
                       towards: np.ndarray | None = None) -> list[PerchRegion]:
    """Every wall and ceiling surface as a perch region (no filtering).

    A stand-in for the filtering stage (benchmarks, tests). Generated scenes' surfaces already face
    free space; segmented ones are unoriented, so give `towards` (the target centre) to turn each
    normal towards it."""
    up = np.asarray(up, np.float64)
    regions = []
    for s in surfaces:
        frame, polygons = s.frame, s.boundary
        if towards is not None and (np.asarray(towards) - frame.origin) @ frame.normal < 0:
            # The flipped frame swaps u and v, so the outline's coordinates swap too.
            frame, polygons = frame.flipped(), [[ring[:, ::-1] for ring in poly] for poly in polygons]
        tilt = float(frame.normal @ up)
        if s.area < min_area or tilt > 0.7:  # floors and upward-facing tops are not perches here
            continue
        cls = SurfaceClass.CEILING if tilt < -0.7 else SurfaceClass.WALL
        polygons = polygons or faces_outline(frame, mesh.triangles()[s.face_indices])
        regions.append(PerchRegion(len(regions), s.id, cls, frame, polygons,
                                   mesh.submesh(s.face_indices), float(s.area)))
    return regions


def regions_for(mesh: Mesh, target, surfaces: list[Surface] | None = None, up=(0.0, 0.0, 1.0),
                route: str = "filtered") -> list[PerchRegion]:
    """Perch regions of a mesh. route "filtered": segmentation (unless `surfaces` are given) and the
    filtering stage; "unfiltered": every wall/ceiling surface (segmented unless given)."""
    if route == "filtered":
        from perch_placement.stages import filtered_regions

        return filtered_regions(mesh, target, up, surfaces)
    if route != "unfiltered":
        raise ValueError(f"regions route '{route}': use filtered or unfiltered")
    if surfaces is None:
        from perch_segmentation.core import segment_mesh

        surfaces = segment_mesh(mesh).surfaces
        return unfiltered_regions(mesh, surfaces, up, towards=target.centroid())
    return unfiltered_regions(mesh, surfaces, up)
