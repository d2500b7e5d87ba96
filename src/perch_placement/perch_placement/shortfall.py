"""Why fewer cameras were placed than asked, in one sentence with the numbers."""

from __future__ import annotations

import numpy as np

from perch_common.types import PerchRegion

PACKING_GRID = 0.05  # m, grid of candidate drone positions on the regions for the packing count


def region_capacity(regions: list[PerchRegion], min_spacing: float) -> int:
    """Drones that fit on the regions at least `min_spacing` apart (greedy packing on a 5 cm grid of
    region points, largest regions first: a lower bound on the true maximum, usually equal)."""
    import shapely

    points = []
    for r in sorted(regions, key=lambda r: -r.area):
        for rings in r.polygons:
            poly = shapely.Polygon(rings[0], rings[1:])
            lo, hi = np.min(rings[0], axis=0), np.max(rings[0], axis=0)
            u, v = np.meshgrid(np.arange(lo[0], hi[0] + PACKING_GRID, PACKING_GRID),
                               np.arange(lo[1], hi[1] + PACKING_GRID, PACKING_GRID))
            uv = np.column_stack([u.ravel(), v.ravel()])
            inside = shapely.intersects_xy(poly, uv[:, 0], uv[:, 1])
            points.append(r.frame.to_world(uv[inside]) if inside.any() else r.frame.to_world(np.array([[0.0, 0.0]])))
    if not points:
        return 0
    free = np.concatenate(points)
    count = 0
    while len(free):
        count += 1
        free = free[np.linalg.norm(free - free[0], axis=1) >= min_spacing - 1e-9]
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
    capacity = region_capacity(regions, min_spacing)
    where = (f"the only perch region, {area:.2f} m^2," if len(regions) == 1 else
             f"the {len(regions)} perch regions, {area:.2f} m^2 in all (largest {max(r.area for r in regions):.2f} m^2),")
    holds = "holds" if len(regions) == 1 else "hold"
    if capacity <= placed:
        return f"{head}: {where} {holds} {capacity} drone(s) {min_spacing:g} m apart"
    return (f"{head}: {where} {holds} {capacity} drones {min_spacing:g} m apart, but no further perch adds "
            f"fitness ({reason or 'the rest see nothing new of the target'})")
