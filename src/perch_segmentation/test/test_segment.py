"""segment_mesh on synthetic rooms: surfaces, frames, labels, outlines, colour, errors."""

import dataclasses

import numpy as np
import pytest
import shapely

from perch_common.errors import PerchError
from perch_common.mesh import Mesh, MeshError
from perch_common.polygons import to_shapely
from perch_common.types import SurfaceClass
from perch_segmentation.core import SegmentationConfig, segment_mesh
from perch_segmentation.testing import box_room


def planes_of(result, plane, count):
    """Map ground-truth plane -> the surface holding most of its faces, and check purity."""
    owner = {}
    for p in range(count):
        labels = result.face_labels[plane == p]
        values, counts = np.unique(labels, return_counts=True)
        owner[p] = int(values[np.argmax(counts)])
    return owner


def test_box_room_gives_one_surface_per_wall_floor_and_ceiling():
    mesh, plane = box_room(noise=0.003, seed=1)
    result = segment_mesh(mesh, SegmentationConfig())
    assert len(result.surfaces) == 6
    owner = planes_of(result, plane, 6)
    assert sorted(owner.values()) == list(range(6))
    areas = mesh.face_areas()
    expected = {0: 12.0, 1: 12.0, 2: 7.5, 3: 7.5, 4: 10.0, 5: 10.0}
    for p, surface_id in owner.items():
        surface = result.surfaces[surface_id]
        assert surface.id == surface_id
        assert surface.surface_class == SurfaceClass.UNKNOWN
        assert surface.area == pytest.approx(expected[p], rel=0.01)
        # Every face of the plane is on its surface, no other face is.
        np.testing.assert_array_equal(np.sort(surface.face_indices), np.flatnonzero(plane == p))
        assert surface.area == pytest.approx(areas[surface.face_indices].sum())
        assert surface.rms_distance == pytest.approx(0.003, abs=0.0015)
    # Largest first, ids are list indices.
    assert [s.area for s in result.surfaces] == sorted((s.area for s in result.surfaces), reverse=True)
    assert result.face_labels.dtype == np.int64 and result.face_labels.shape == (mesh.num_faces,)


def test_frames_are_pca_frames_with_winding_normals():
    mesh, plane = box_room()
    result = segment_mesh(mesh)
    owner = planes_of(result, plane, 6)
    inward = {0: [0, 0, 1], 1: [0, 0, -1], 2: [1, 0, 0], 3: [-1, 0, 0], 4: [0, 1, 0], 5: [0, -1, 0]}
    centroids, areas = mesh.face_centroids(), mesh.face_areas()
    for p, surface_id in owner.items():
        frame = result.surfaces[surface_id].frame
        np.testing.assert_allclose(frame.normal, inward[p], atol=1e-9)  # winding majority, into the room
        np.testing.assert_allclose(np.cross(frame.axis_u, frame.axis_v), frame.normal, atol=1e-9)
        faces = plane == p
        np.testing.assert_allclose(frame.origin, np.average(centroids[faces], axis=0, weights=areas[faces]),
                                   atol=1e-9)
    floor = result.surfaces[owner[0]].frame
    assert abs(floor.axis_u[0]) == pytest.approx(1.0)  # main axis along the 4 m side


def test_flipped_winding_flips_the_normal():
    mesh, plane = box_room()
    flipped = Mesh(mesh.vertices, mesh.faces[:, ::-1], mesh.vertex_colors)
    result = segment_mesh(flipped)
    floor = result.surfaces[planes_of(result, plane, 6)[0]]
    np.testing.assert_allclose(floor.frame.normal, [0, 0, -1], atol=1e-9)


def test_boundary_polygons_match_the_surface_and_its_hole():
    mesh, plane = box_room()
    centre = mesh.face_centroids()
    hole = (plane == 4) & (np.abs(centre[:, 0] - 2.0) < 0.3) & (np.abs(centre[:, 2] - 1.2) < 0.3)
    holed = mesh.submesh(~hole)
    result = segment_mesh(holed)
    wall = max((s for s in result.surfaces if abs(s.frame.normal[1] - 1) < 1e-6), key=lambda s: s.area)
    assert wall.area == pytest.approx(10.0 - 0.36, abs=1e-6)
    assert len(wall.boundary) == 1 and len(wall.boundary[0]) == 2  # outline with one hole
    shape = to_shapely(wall.boundary)
    assert shape.area == pytest.approx(wall.area, abs=0.08)
    assert shapely.Polygon(wall.boundary[0][1]).area == pytest.approx(0.36, abs=0.04)
    # The outline lies in plane coordinates of the surface's frame: its extent is the wall's.
    xmin, ymin, xmax, ymax = shape.bounds
    assert sorted([xmax - xmin, ymax - ymin]) == pytest.approx([2.5, 4.0], abs=0.03)


def test_door_flush_with_wall_is_its_own_surface_only_with_colour():
    mesh, plane = box_room(door=True, noise=0.002)
    with_colour = segment_mesh(mesh, SegmentationConfig(use_color=True))
    owner = planes_of(with_colour, plane, 7)
    assert owner[6] != owner[2]
    door = with_colour.surfaces[owner[6]]
    assert door.area == pytest.approx(0.9 * 2.0, rel=0.15)
    np.testing.assert_allclose(door.mean_color, np.array([96, 64, 40]) / 255.0, atol=0.08)
    without = segment_mesh(mesh, SegmentationConfig(use_color=False))
    owner = planes_of(without, plane, 7)
    assert owner[6] == owner[2]
    assert without.surfaces[owner[2]].area == pytest.approx(7.5, rel=0.01)


def test_small_pieces_below_min_area_are_unlabelled():
    mesh, _ = box_room(size=(2.0, 1.0, 0.3))  # walls of 0.3 m: 0.3 m^2 and 0.6 m^2
    result = segment_mesh(mesh, SegmentationConfig(min_area=0.5))
    assert sorted(round(s.area, 3) for s in result.surfaces) == [0.6, 0.6, 2.0, 2.0]
    assert np.isclose(mesh.face_areas()[result.face_labels < 0].sum(), 0.6)


def test_input_mesh_is_not_altered():
    mesh, _ = box_room(noise=0.002)
    before = (mesh.vertices.copy(), mesh.faces.copy(), mesh.vertex_colors.copy())
    segment_mesh(mesh)
    for a, b in zip(before, (mesh.vertices, mesh.faces, mesh.vertex_colors)):
        np.testing.assert_array_equal(a, b)


def test_deterministic():
    mesh, _ = box_room(noise=0.004, seed=3)
    a, b = segment_mesh(mesh), segment_mesh(mesh)
    np.testing.assert_array_equal(a.face_labels, b.face_labels)


@pytest.mark.parametrize("kind", ["room", "l_shaped", "apartment"])
def test_the_rounding_of_another_orientation_changes_nothing(kind):
    """A room given tilted reaches the stage gravity-aligned again, its vertices moved by float32
    rounding (~5e-7 m): coplanar neighbours (energy ~0), equal-area surfaces and a surface of exactly
    min_area must come out the same, not as rounding decides."""
    from perch_common.scan_orientations import ORIENTATIONS
    from perch_common.scene_generator import generate_scene

    scene = generate_scene(0, kind)  # noise-free: exactly coplanar faces, equal walls
    vertices = scene.mesh.vertices.astype(np.float32).astype(np.float64)
    base = segment_mesh(Mesh(vertices, scene.mesh.faces, scene.mesh.vertex_colors))
    for tilt in ("tilt-25", "tilt-35"):
        r = ORIENTATIONS[tilt]
        back = (vertices @ r.T).astype(np.float32).astype(np.float64) @ r  # there as float32, and back
        assert 1e-7 < np.abs(back - vertices).max() < 1e-6
        moved = segment_mesh(Mesh(back, scene.mesh.faces, scene.mesh.vertex_colors))
        assert np.array_equal(moved.face_labels, base.face_labels), (kind, tilt)
        assert [s.area for s in moved.surfaces] == pytest.approx([s.area for s in base.surfaces], abs=1e-6)


@pytest.mark.parametrize("mesh, message", [
    (Mesh(np.zeros((0, 3)), np.zeros((0, 3))), "mesh is empty"),
    (Mesh(np.array([[0, 0, 0], [1, 0, 0], [np.nan, 1, 0]]), [[0, 1, 2]]), "NaN or infinite"),
    (Mesh(np.eye(3), [[0, 1, 5]]), "outside 0..2"),
])
def test_unusable_meshes_raise_precise_errors(mesh, message):
    with pytest.raises(MeshError, match=message):
        segment_mesh(mesh)


def test_mesh_without_planar_region_raises():
    import trimesh

    sphere = trimesh.creation.icosphere(subdivisions=3, radius=0.3)  # 0.03 m facets, no plane of 0.2 m^2
    with pytest.raises(PerchError, match="no planar region of at least min_area=0.2"):
        segment_mesh(Mesh(sphere.vertices, sphere.faces))


@pytest.mark.parametrize("change, message", [
    ({"theta_max_deg": 120.0}, "theta_max_deg=120.0 must be in"),
    ({"d_max": -1.0}, "d_max=-1.0 must be a positive distance"),
    ({"energy_bound": float("nan")}, "energy_bound=nan"),
    ({"target_clusters": 0}, "target_clusters=0"),
    ({"up_axis": "sideways"}, "up axis 'sideways'"),
])
def test_absurd_parameters_raise(change, message):
    mesh, _ = box_room()
    with pytest.raises(ValueError, match=message):
        segment_mesh(mesh, dataclasses.replace(SegmentationConfig(), **change))


def test_config_fields_carry_descriptions():
    for f in dataclasses.fields(SegmentationConfig):
        assert f.metadata.get("description"), f.name
    defaults = SegmentationConfig()
    assert (defaults.target_clusters, defaults.theta_max_deg, defaults.theta_min_deg, defaults.d_max,
            defaults.min_area) == (2000, 15.0, 70.0, 0.2, 0.2)
