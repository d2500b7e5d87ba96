"""The shortfall sentence: why fewer cameras than asked, with the region area and its capacity."""

import numpy as np
import pytest

from perch_common.mesh import Mesh
from perch_common.types import PerchRegion, PlaneFrame, SurfaceClass
from perch_placement.shortfall import region_capacity, shortfall_sentence


def ceiling_strip(length: float, width: float, x0: float = 0.0) -> PerchRegion:
    """A length x width ceiling region at 2.5 m."""
    frame = PlaneFrame.from_normal(np.array([x0, 0.0, 2.5]), np.array([0, 0, -1.0]), np.array([0, 0, 1.0]))
    ring = np.array([[0, 0], [length, 0], [length, width], [0, width]], float)
    return PerchRegion(0, 0, SurfaceClass.CEILING, frame, [[ring]], Mesh(np.eye(3), np.array([[0, 1, 2]])),
                       length * width)


@pytest.mark.parametrize("length,drones", [(0.5, 1), (0.95, 1), (0.99, 2), (1.0, 2), (1.5, 2), (2.0, 3), (3.05, 4)])
def test_capacity_of_a_strip(length, drones):
    """A 0.2 m wide strip: drones 1 m apart along it (its diagonal counts: 0.99 x 0.2 m holds two)."""
    assert region_capacity([ceiling_strip(length, 0.2)], 1.0) == drones


def test_capacity_of_a_square_and_of_two_regions():
    assert region_capacity([ceiling_strip(2.0, 2.0)], 1.0) == 9  # a 3 x 3 lattice, corners included
    assert region_capacity([ceiling_strip(0.3, 0.3), ceiling_strip(0.3, 0.3, x0=5.0)], 1.0) == 2


def test_sentence_names_area_capacity_and_spacing():
    one = ceiling_strip(2.05, 0.4)
    assert shortfall_sentence([one], 5, 3, 1.0) == "3 of 5 cameras: the only perch region, 0.82 m^2, holds 3 drone(s) 1 m apart"
    two = [ceiling_strip(4.0, 0.5), ceiling_strip(0.5, 0.5, x0=9.0)]
    text = shortfall_sentence(two, 5, 2, 1.0, "no feasible perch adds fitness")
    assert text.startswith("2 of 5 cameras: the 2 perch regions, 2.25 m^2 in all (largest 2.00 m^2), hold 6 drones 1 m apart")
    assert text.endswith("but no further perch adds fitness (no feasible perch adds fitness)")
    assert shortfall_sentence([one], 3, 3, 1.0) == ""
    assert shortfall_sentence([], 2, 0, 1.0) == "0 of 2 cameras: the filter left no perch region"


def test_greedy_that_strands_room_is_completed_on_a_packing():
    """A 2.2 m ceiling strip holds 3 drones 1 m apart (2.14 m inside the 3 cm border margin), but the
    best single perch lies above the target, 0.6 m from the strip's end: greedy placement then fits
    only 2. The packing completion places all 3, 1 m apart and inside the border margin."""
    from placement_rooms import box_mesh, rectangle_region

    from perch_common.target import TargetVolume
    from perch_placement.core import optimise

    mesh = box_mesh((0, 0, 0), (6, 5, 3))
    strip = rectangle_region(0, (3.0, 2.5, 3.0), (0, 0, -1), 2.2, 0.3, SurfaceClass.CEILING)
    target = TargetVolume(center=[2.6, 2.5, 1.0], size=[1.0, 1.0, 1.0])
    placed = optimise(mesh, [strip], target, 3)
    assert len(placed.placements) == 3, placed.message
    at = np.array([p.drone_pose[:3, 3] for p in placed.placements])
    gaps = np.linalg.norm(at[:, None] - at[None], axis=-1)[np.triu_indices(3, 1)]
    assert gaps.min() >= 1.0 - 1e-9
    assert at[:, 0].min() >= 1.9 + 0.03 - 1e-6 and at[:, 0].max() <= 4.1 - 0.03 + 1e-6  # border margin kept
    assert np.all(np.abs(at[:, 1] - 2.5) <= 0.15 - 0.03 + 1e-6)
    assert placed.message.startswith("placed 3 of 3")
    one_more = optimise(mesh, [strip], target, 4)
    assert len(one_more.placements) == 3
    assert one_more.message.startswith("3 of 4 cameras: the only perch region, 0.66 m^2, holds 3 drone(s) 1 m apart")


def test_principal_axis_packing_is_the_sequential_greedy_one():
    """The vectorised packing takes exactly the points the one-point-at-a-time greedy along the
    principal axis takes: each at least min_spacing from those taken before, every other point closer."""
    from perch_placement.shortfall import _greedy_packing

    rng = np.random.default_rng(5)
    for _ in range(20):
        cloud = np.round(rng.random((int(rng.integers(1, 600)), 3)) * [3.0, 1.0, 0.2] / 0.05) * 0.05
        for spacing in (0.05, 0.4, 1.0):
            centred = cloud - cloud.mean(axis=0)
            order = np.argsort(centred @ np.linalg.svd(centred, full_matrices=False)[2][0], kind="stable")
            expected: list[int] = []
            for i in order:
                if not expected or np.linalg.norm(cloud[expected] - cloud[i], axis=1).min() >= spacing - 1e-9:
                    expected.append(int(i))
            assert _greedy_packing(cloud, spacing).tolist() == expected
