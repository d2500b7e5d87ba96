"""The real apartment scan (../shared/data), segmented by perch_segmentation, through the filter."""

import numpy as np
import pytest

from perch_common.data import shared_file

pytestmark = pytest.mark.data


def test_real_apartment_regions_see_the_target_from_the_free_side():
    mesh_path = shared_file("meshes", "apartment.ply")
    target_path = shared_file("meshes", "apartment_target.ply")
    if mesh_path is None or target_path is None:
        pytest.skip("../shared/data not found: meshes/apartment.ply and apartment_target.ply")
    segmentation = pytest.importorskip("perch_segmentation.core")
    from perch_common.mesh import load_mesh
    from perch_common.raycast import RayScene
    from perch_common.target import TargetVolume
    from perch_filtering.core import filter_surfaces

    mesh = load_mesh(mesh_path)
    target = TargetVolume.from_footprint_mesh(load_mesh(target_path), 1.2)
    surfaces = segmentation.segment_mesh(mesh, segmentation.SegmentationConfig()).surfaces
    result = filter_surfaces(mesh, surfaces, target, np.array([0.0, 0.0, 1.0]))
    assert result.regions, result.message
    # The floor is the scan's lowest large horizontal surface (the scan's floor lies near z = 0).
    assert -0.1 < result.floor_height < 0.15
    assert {r.surface_class.name for r in result.regions} <= {"WALL", "CEILING"}
    # Yield. The original system placed 5 perches on walls and ceilings of this apartment (85 % passed
    # operator review), without the fall-corridor obstacle test and with centroid-oriented normals.
    # Under this rules (h_min 0.5 m, clearance 0.5 m by 3D distance, 0.5 x 0.5 m window) the scan
    # keeps one ceiling strip of ~0.79 m^2: furniture up to ~0.9 m high stands within 0.7 m in front of
    # the walls (free fall from >= ~1.4 m) and the ceiling (2.35-2.45 m) clears wall points only below
    # ~1.85-1.95 m, a band lower than the 0.5 m window on every wall. Ablations: without the obstacle
    # part of the fall test ~0.96 m^2, without the clearance ~1.1 m^2 (each alone still kills the walls).
    # This guards that yield against regressions; it does not reach the original's 5 perches.
    total = sum(r.area for r in result.regions)
    assert len(result.regions) >= 1 and total >= 0.7, (len(result.regions), total)
    assert len({r.source_surface for r in result.regions}) >= 1
    assert any(r.surface_class.name == "CEILING" and r.area >= 0.7 for r in result.regions)
    removed = result.removed_area()
    assert removed["recovery_height"] == max(v for k, v in removed.items() if k != "orientation"), removed
    scene = RayScene(mesh)
    centre = target.centroid()
    for r in result.regions:
        points = r.mesh.vertices + 0.05 * r.frame.normal
        assert np.all((centre - points) @ r.frame.normal > 0)
        assert not scene.occluded(points, np.repeat(centre[None], len(points), axis=0)).any()
        assert r.frame.origin[2] - result.floor_height > 0.5
