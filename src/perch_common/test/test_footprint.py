"""Target footprints traced on a raster agree with the exact shapely union of the projected triangles."""

import numpy as np
import pytest
import shapely

from perch_common.data import shared_file
from perch_common.mesh import Mesh, load_mesh
from perch_common.polygons import raster_outline
from perch_common.target import TargetVolume, footprint_cell
from perch_common.transforms import rotation_between


def exact_outline(mesh: Mesh) -> shapely.Polygon:
    """The slow reference: exterior of the largest piece of the shapely union of the projected triangles."""
    tris = mesh.triangles()[:, :, :2]
    union = shapely.union_all(shapely.polygons(tris))
    largest = max(getattr(union, "geoms", [union]), key=lambda g: g.area)
    return shapely.Polygon(largest.exterior)


def assert_outlines_agree(mesh: Mesh, exact: shapely.Polygon) -> None:
    target = TargetVolume.from_footprint_mesh(mesh, 1.2)
    traced = shapely.Polygon(target.footprint)
    cell = footprint_cell(mesh.triangles()[:, :, :2])
    assert traced.is_valid
    assert traced.area == pytest.approx(exact.area, rel=0.005)
    assert traced.symmetric_difference(exact).area < 0.01 * exact.area
    # Outlines within two cells of each other (a few vertices may differ more where the raster joins
    # a piece that touches the largest at a point, which the exact union keeps apart).
    for a, b in ((exact, traced), (traced, exact)):
        gaps = shapely.distance(shapely.points(np.asarray(a.exterior.coords)), b.exterior)
        assert np.percentile(gaps, 95) < 2 * cell
    assert target.base == pytest.approx(float(mesh.vertices[:, 2].min()))


def floor_with_holes() -> Mesh:
    """An L-shaped 0.1 m grid floor with two holes, its faces doubled as a slab's top and (flipped) bottom."""
    n = 40
    x, y = np.meshgrid(np.arange(n + 1) * 0.1, np.arange(n + 1) * 0.1, indexing="ij")
    jitter = np.random.default_rng(5).uniform(-0.02, 0.02, (n + 1, n + 1, 2))
    jitter[[0, -1]] = jitter[:, [0, -1]] = 0.0
    vertices = np.column_stack([(x + jitter[..., 0]).ravel(), (y + jitter[..., 1]).ravel(), np.zeros(x.size)])
    faces = []
    for i in range(n):
        for j in range(n):
            centre = np.array([i + 0.5, j + 0.5]) * 0.1
            if centre[0] > 2.0 and centre[1] > 2.0:   # the L's missing quarter
                continue
            if (0.5 < centre[0] < 1.2 and 0.5 < centre[1] < 0.9) or np.hypot(*(centre - [3.0, 1.0])) < 0.35:
                continue                               # two holes
            a, b, c, d = i * (n + 1) + j, (i + 1) * (n + 1) + j, (i + 1) * (n + 1) + j + 1, i * (n + 1) + j + 1
            faces += [[a, b, c], [a, c, d]]
    faces = np.array(faces)
    bottom = vertices - [0, 0, 0.05]
    return Mesh(np.vstack([vertices, bottom]), np.vstack([faces, faces[:, ::-1] + len(vertices)]))


def test_generated_footprint_with_holes_matches_the_exact_union():
    mesh = floor_with_holes()
    exact = exact_outline(mesh)
    assert exact.area == pytest.approx(16 - 4 - 0.0, abs=0.05)  # holes are ignored: the L's outer outline
    assert_outlines_agree(mesh, exact)
    target = TargetVolume.from_footprint_mesh(mesh, 1.0)
    inside_hole, outside = [0.85, 0.7, -0.02], [3.0, 3.0, -0.02]
    assert target.contains(np.array([inside_hole, outside])).tolist() == [True, False]


@pytest.mark.parametrize("turn_deg", [0.0, 30.0])
def test_real_apartment_target_matches_the_exact_union(turn_deg):
    path = shared_file("meshes", "apartment_target.ply")
    if path is None:
        pytest.skip("../shared/data/meshes/apartment_target.ply is absent (set PERCH_SHARED_DATA)")
    mesh = load_mesh(path)
    turn = np.radians(turn_deg)
    rotation = np.array([[np.cos(turn), -np.sin(turn), 0], [np.sin(turn), np.cos(turn), 0], [0, 0, 1]])
    mesh = Mesh(mesh.vertices @ rotation.T, mesh.faces)
    assert_outlines_agree(mesh, exact_outline(mesh))


def test_tilted_footprint_projects_along_z():
    """A tilted floor patch: the outline is its shadow on the xy plane, as the exact union's."""
    mesh = floor_with_holes()
    tilt = rotation_between(np.array([0, 0, 1.0]), np.array([0.3, 0.1, 1.0]))
    tilted = Mesh(mesh.vertices @ tilt.T, mesh.faces)
    assert_outlines_agree(tilted, exact_outline(tilted))


def test_raster_outline_errors_and_closing():
    square = np.array([[[0, 0], [1, 0], [1, 1]], [[0, 0], [1, 1], [0, 1]]], np.float64)
    apart = np.concatenate([square, square + [1.05, 0]])   # two squares 5 cm apart
    outline, area = raster_outline(apart, 0.01)
    assert area == pytest.approx(1.0, rel=0.03) and np.ptp(outline[:, 0]) == pytest.approx(1.0, abs=0.02)
    closed, area = raster_outline(apart, 0.01, close_radius=0.05)
    assert area == pytest.approx(2.05, rel=0.03) and np.ptp(closed[:, 0]) == pytest.approx(2.05, abs=0.02)
    with pytest.raises(ValueError, match="too large to outline"):
        raster_outline(square * 1000, 0.01)
    with pytest.raises(ValueError, match="no area"):
        TargetVolume.from_footprint_mesh(Mesh([[0, 0, 0], [0, 0, 1], [1, 0, 0.5]], [[0, 1, 2]]), 1.0)
