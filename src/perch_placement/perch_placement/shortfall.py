"""Why fewer cameras were placed than asked, in one sentence with the numbers."""

from __future__ import annotations

import numpy as np

from perch_common.types import PerchRegion

PACKING_GRID = 0.05  # m, grid of candidate drone positions on the regions for the packing count


def region_capacity(regions: list[PerchRegion], min_spacing: float) -> int:
    """Drones that fit on the regions at least `min_spacing` apart: the better of two packings of a
    5 cm grid of region points, farthest-point and greedy along the points' principal axis (a lower
    bound on the true maximum; the greedy one is exact on strips)."""
    import shapely

    points = []
    for r in regions:
        for rings in r.polygons:
            poly = shapely.Polygon(rings[0], rings[1:])
            lo, hi = np.min(rings[0], axis=0), np.max(rings[0], axis=0)
            u, v = np.meshgrid(np.arange(lo[0], hi[0] + PACKING_GRID, PACKING_GRID),
                               np.arange(lo[1], hi[1] + PACKING_GRID, PACKING_GRID))
            uv = np.column_stack([u.ravel(), v.ravel()])
            uv = np.concatenate([uv[shapely.intersects_xy(poly, uv[:, 0], uv[:, 1])], np.asarray(rings[0], float)])
            points.append(r.frame.to_world(uv))
    if not points:
        return 0
    cloud = np.concatenate(points)
    return max(_farthest_point_packing(cloud, min_spacing), _greedy_packing(cloud, min_spacing))


def _greedy_packing(cloud: np.ndarray, min_spacing: float) -> int:
    """Points taken in order along the principal axis, each at least min_spacing from those taken."""
    centred = cloud - cloud.mean(axis=0)
    axis = np.linalg.svd(centred, full_matrices=False)[2][0]
    taken = np.zeros((0, 3))
    for p in cloud[np.argsort(centred @ axis)]:
        if not len(taken) or np.min(np.linalg.norm(taken - p, axis=1)) >= min_spacing - 1e-9:
            taken = np.vstack([taken, p])
    return len(taken)


def _farthest_point_packing(cloud: np.ndarray, min_spacing: float) -> int:
    """Farthest-point sampling from the point farthest from the centroid, while min_spacing holds."""
    nearest = np.linalg.norm(cloud - cloud.mean(axis=0), axis=1)
    count = 0
    while len(cloud) and nearest.max() >= (min_spacing - 1e-9 if count else 0.0):
        chosen = cloud[int(np.argmax(nearest))]
        count += 1
        nearest = np.minimum(nearest, np.linalg.norm(cloud - chosen, axis=1)) if count > 1 else \
            np.linalg.norm(cloud - chosen, axis=1)
    return count


def shortfall_sentence(regions: list[PerchRegion], asked: int, placed: int, min_spacing: float,
                       reason: str = "") -> str:
    """'3 of 5 cameras: the only perch region, 0.80 m^2, holds 3 drones 1.0 m apart' ("" if none short)."""
    if placed >= asked:
        return ""
    head = f"{placed} of {asked} cameras"
    if not regions:
        return f"{head}: the filter left no perch region"
    area = sum(r.area for r in regions)
    capacity = max(region_capacity(regions, min_spacing), placed)  # the placed drones are a packing too
    where = (f"the only perch region, {area:.2f} m^2," if len(regions) == 1 else
             f"the {len(regions)} perch regions, {area:.2f} m^2 in all (largest {max(r.area for r in regions):.2f} m^2),")
    holds = "holds" if len(regions) == 1 else "hold"
    if capacity <= placed:
        return f"{head}: {where} {holds} {capacity} drone(s) {min_spacing:g} m apart"
    return (f"{head}: {where} {holds} {capacity} drones {min_spacing:g} m apart, but no further perch adds "
            f"fitness ({reason or 'the rest see nothing new of the target'})")
