"""The safety model on the shared real scans, judged by the independent scan checker (scan_checker).

The apartment is z-up; the ICL-NUIM rooms are -y up and are rotated to z-up here (the frames
engineer's up estimate does this for missions). Every filtered region is sampled, and 5 cameras
are placed on the regions: no placement may fail the checker.
"""

import re

import numpy as np
import pytest
from filtering_accuracy import spec_from
from filtering_checker import sample_mesh_surface
from scan_checker import ScanOracle

from perch_common.data import shared_file

pytestmark = pytest.mark.data

SCANS = [("apartment.ply", "+z"), ("icl_livingroom_kt2.obj", "-y"), ("icl_office_kt2.obj", "-y")]


def load_scan(name: str, up: str):
    """The scan rotated to z-up and its target (the apartment's footprint, else the floor's)."""
    from perch_common.mesh import load_mesh
    from perch_common.target import TargetVolume
    from perch_common.transforms import rotation_between
    from perch_operator.coordinator.crop import floor_target

    path = shared_file("meshes", name)
    if path is None:
        pytest.skip(f"../shared/data not found: meshes/{name}")
    mesh = load_mesh(path)
    if up == "-y":
        m = np.eye(4)
        m[:3, :3] = rotation_between(np.array([0, -1.0, 0]), np.array([0, 0, 1.0]))
        mesh = mesh.transformed(m)
    footprint = shared_file("meshes", "apartment_target.ply") if name == "apartment.ply" else None
    target = TargetVolume.from_footprint_mesh(load_mesh(footprint), 1.2) if footprint else floor_target(mesh)
    return mesh, target


@pytest.mark.slow
@pytest.mark.parametrize("name,up", SCANS, ids=[n.split(".")[0] for n, _ in SCANS])
def test_regions_and_placements_pass_the_scan_checker(name, up):
    segmentation = pytest.importorskip("perch_segmentation.core")
    from perch_filtering.core import FilterConfig, filter_surfaces
    from perch_placement.core import optimise

    mesh, target = load_scan(name, up)
    z = np.array([0.0, 0.0, 1.0])
    surfaces = segmentation.segment_mesh(mesh, segmentation.SegmentationConfig()).surfaces
    config = FilterConfig()
    result = filter_surfaces(mesh, surfaces, target, z, config)
    assert result.regions, result.message
    oracle = ScanOracle(mesh, target, z, spec_from(config))
    rng = np.random.default_rng(0)
    failing, total = 0, 0
    for region in result.regions:
        points, _ = sample_mesh_surface(region.mesh, max(5, int(region.area * 100)), rng)
        failing += sum(bool(oracle.failures(p, region.frame.normal)) for p in points)
        total += len(points)
    assert failing / total <= 0.01, (failing, total)  # measured 0-0.2 % (region borders)
    placed = optimise(mesh, result.regions, target, 5)
    for p in placed.placements:
        assert oracle.failures(p.drone_pose[:3, 3], p.drone_pose[:3, 2]) == [], p.drone_index
    if name != "apartment.ply":  # the ICL rooms hold 5 safe perches 1 m apart
        assert len(placed.placements) == 5, placed.message
    else:
        # The apartment's regions (whole scan segmented) hold fewer than 5 drones 1 m apart, as many are
        # placed and the shortfall says so: 4 (2026-12-07). Not pinned: until face_adjacency sorted stably
        # the count followed the CPU (4 on the AVX-512 machines this was written on, 3 on an AVX2 EPYC),
        # and the placement search still sums in an order that follows numpy's SIMD level.
        held = re.search(r"hold (\d+) drone\(s\) 1 m apart", placed.message)
        assert held, placed.message
        assert len(placed.placements) == int(held.group(1)) >= 3, placed.message
        assert placed.message.startswith(f"{len(placed.placements)} of 5 cameras: the "), placed.message


@pytest.mark.slow
def test_scan_checker_is_not_a_rubber_stamp():
    """Regions filtered without the fall, approach and support rules mostly fail the checker."""
    segmentation = pytest.importorskip("perch_segmentation.core")
    from perch_filtering.core import FilterConfig, filter_surfaces

    mesh, target = load_scan("apartment.ply", "+z")
    z = np.array([0.0, 0.0, 1.0])
    surfaces = segmentation.segment_mesh(mesh, segmentation.SegmentationConfig()).surfaces
    loose = FilterConfig(min_recovery_height=0.0, approach_distance=0.0, approach_margin=0.0, min_support=0.0,
                         max_support_rms=1.0)
    result = filter_surfaces(mesh, surfaces, target, z, loose)
    oracle = ScanOracle(mesh, target, z, spec_from(FilterConfig()))
    rng = np.random.default_rng(1)
    verdicts = []
    for region in result.regions:
        points, _ = sample_mesh_surface(region.mesh, max(3, int(region.area * 20)), rng)
        verdicts += [bool(oracle.failures(p, region.frame.normal)) for p in points]
    assert len(verdicts) > 100 and np.mean(verdicts) > 0.5, (len(verdicts), np.mean(verdicts))
