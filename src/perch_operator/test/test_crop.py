"""Crop core: keep/remove boxes, kept face indices, default floor target."""

import numpy as np
import pytest

from perch_common.mesh import Mesh, MeshError
from perch_common.target import TargetVolume
from perch_operator.coordinator.crop import Box, CropConfig, crop_mesh, floor_target


def test_no_boxes_keeps_everything_and_input_is_untouched(meshes):
    mesh = meshes.room()
    before = mesh.vertices.copy()
    result = crop_mesh(mesh, target=TargetVolume(center=[2, 1.5, 0.6], size=[1, 1, 1]))
    assert result.mesh.num_faces == mesh.num_faces
    np.testing.assert_array_equal(result.kept_faces, np.arange(mesh.num_faces))
    np.testing.assert_array_equal(mesh.vertices, before)
    assert result.target.is_box


def test_keep_box_keeps_only_faces_inside_and_reports_their_indices(meshes):
    mesh = meshes.room()
    keep = Box(center=[1.0, 1.5, 1.25], size=[2.0, 3.2, 3.0])  # the x < 2 half, floor and ceiling
    result = crop_mesh(mesh, keep_boxes=[keep])
    centroids = mesh.face_centroids()[result.kept_faces]
    assert np.all(centroids[:, 0] < 2.0)
    assert len(result.kept_faces) == np.sum(mesh.face_centroids()[:, 0] < 2.0)
    np.testing.assert_allclose(result.mesh.face_centroids(), centroids)


def test_remove_box_inside_keep_box_and_rotated_boxes(meshes):
    mesh = meshes.room()
    rot = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # 90 deg yaw: size x<->y
    remove = Box(center=[2.0, 1.5, 0.7], size=[1.0, 4.0, 0.2], rotation=rot)  # world: 4 m along x, 1 m along y
    result = crop_mesh(mesh, remove_boxes=[remove])
    c = mesh.face_centroids()
    inside = (np.abs(c[:, 1] - 1.5) <= 0.5) & (np.abs(c[:, 0] - 2.0) <= 2.0) & (np.abs(c[:, 2] - 0.7) <= 0.1)
    assert inside.sum() > 0
    assert len(result.kept_faces) == mesh.num_faces - inside.sum()


def test_default_target_is_floor_outline_extruded_to_configured_height(meshes):
    mesh = meshes.room()
    result = crop_mesh(mesh, config=CropConfig(target_height=1.5))
    target = result.target
    assert not target.is_box
    assert target.base == pytest.approx(0.0, abs=1e-6)
    assert target.height == pytest.approx(1.5)
    lo, hi = target.bounds()
    np.testing.assert_allclose(lo, [0, 0, 0], atol=0.06)
    np.testing.assert_allclose(hi, [4, 3, 1.5], atol=0.06)
    assert target.volume() == pytest.approx(4 * 3 * 1.5, rel=0.03)


def test_floor_is_the_large_level_not_low_noise(meshes):
    noise = meshes.grid(2, 2, (0.2, 0.2), -0.3)  # a small fragment below the floor
    noise.vertices[:, :2] += 1.0
    target = floor_target(meshes.merge(meshes.room(), noise))
    assert target.base == pytest.approx(0.0, abs=1e-6)


def test_a_room_wound_inside_out_has_the_same_floor_target(meshes):
    """Every face reversed (floor facing down, ceiling up: the ICL rooms exported so gave "the floor
    is too small"): the same target as the room; a lone downward grid (a ceiling) is still no floor."""
    room = meshes.room()
    inverted = Mesh(room.vertices, room.faces[:, ::-1])
    target, again = floor_target(room), floor_target(inverted)
    assert again.base == pytest.approx(target.base, abs=1e-9)
    np.testing.assert_allclose(again.bounds(), target.bounds(), atol=1e-9)


def test_errors_are_precise(meshes):
    mesh = meshes.room()
    with pytest.raises(MeshError, match="no faces left"):
        crop_mesh(mesh, keep_boxes=[Box(center=[50, 50, 50], size=[1, 1, 1])])
    with pytest.raises(ValueError, match="size must be positive"):
        Box(center=[0, 0, 0], size=[1, 0, 1])
    ceiling_only = meshes.grid(4, 4, (1, 1), 2.5, up=False)
    with pytest.raises(MeshError, match="no upward-facing faces"):
        crop_mesh(ceiling_only)
    with pytest.raises(MeshError, match="no faces"):
        crop_mesh(Mesh(np.zeros((0, 3)), np.zeros((0, 3), np.int64)))
