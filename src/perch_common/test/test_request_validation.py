"""The shared request validation layer: every bad request of issue 11 gets a reply naming field and value."""

from __future__ import annotations

import copy
import math

import numpy as np
import pytest

from perch_common.request_validation import RequestError, validate_request


@pytest.fixture(scope="module")
def scene():
    from perch_common.scene_generator import generate_scene

    return generate_scene(3, "room")


@pytest.fixture(scope="module")
def messages(scene):
    """Valid requests of every stage built from a generated room."""
    from perch_common.ros.conversions import mesh_to_msg, target_to_msg
    from perch_interfaces import msg as pm
    from perch_interfaces import srv

    mesh = mesh_to_msg(scene.mesh)
    target = target_to_msg(scene.target)
    box = pm.OrientedBox()
    box.pose.position.x, box.pose.position.y, box.pose.position.z = scene.target.center
    box.size.x = box.size.y = box.size.z = 2.0
    return {
        "crop": srv.Crop.Request(mesh=mesh, keep_boxes=[box], target=target),
        "segment": srv.Segment.Request(mesh=mesh),
        "filter": srv.Filter.Request(mesh=mesh, target=target),
        "optimise": srv.Optimise.Request(mesh=mesh, target=target, num_cameras=3,
                                         exclusions=[pm.ExclusionZone(radius=0.3)]),
        "clean": srv.CleanMesh.Request(mesh=mesh),
        "reconstruct": srv.Reconstruct.Request(bag_path="x.mcap"),
    }


def rejected(request) -> str:
    with pytest.raises(RequestError) as info:
        validate_request(request)
    return str(info.value)


def test_valid_requests_pass(messages):
    for request in messages.values():
        validate_request(request)


def test_crop_with_nan_centre_zero_quaternion_or_huge_box_is_refused(messages):
    nan_centre = copy.deepcopy(messages["crop"])
    nan_centre.keep_boxes[0].pose.position.y = math.nan
    assert "keep_boxes[0].pose.position.y = nan: must be a finite number" in rejected(nan_centre)
    nan_target = copy.deepcopy(messages["crop"])
    nan_target.target.box.pose.position.x = math.nan
    assert "target.box.pose.position.x = nan" in rejected(nan_target)
    zero_q = copy.deepcopy(messages["crop"])
    zero_q.keep_boxes[0].pose.orientation.w = 0.0
    message = rejected(zero_q)
    assert "keep_boxes[0].pose.orientation = (0, 0, 0, 0): not a unit quaternion (norm 0)" in message
    huge = copy.deepcopy(messages["crop"])
    huge.keep_boxes[0].size.x = 1e9
    assert "keep_boxes[0].size.x = 1e+09: beyond 10 km" in rejected(huge)
    flat = copy.deepcopy(messages["crop"])
    flat.keep_boxes[0].size.z = 0.0
    assert "keep_boxes[0].size.z = 0: box edge lengths must be > 0" in rejected(flat)


def test_optimise_with_negative_or_zero_drone_and_zero_camera_is_refused(messages):
    from perch_interfaces import msg as pm

    negative_radius = copy.deepcopy(messages["optimise"])
    negative_radius.drone = pm.DroneSpec(specified=True, radius=-1.0, pan_range=3.0, min_spacing=0.5)
    assert "drone.radius = -1" in rejected(negative_radius)
    spacing = copy.deepcopy(messages["optimise"])
    spacing.drone = pm.DroneSpec(specified=True, radius=0.2, pan_range=3.0, min_spacing=-5.0)
    assert "drone.min_spacing = -5: must be >= 0" in rejected(spacing)
    zero_drone = copy.deepcopy(messages["optimise"])
    zero_drone.drone = pm.DroneSpec(specified=True)
    assert "drone.radius = 0" in rejected(zero_drone)
    zero_camera = copy.deepcopy(messages["optimise"])
    zero_camera.camera = pm.CameraSpec(specified=True)
    assert "camera.width = 0: a specified camera needs it > 0" in rejected(zero_camera)
    unspecified = copy.deepcopy(messages["optimise"])
    unspecified.camera, unspecified.drone = pm.CameraSpec(), pm.DroneSpec()  # node defaults: fine
    validate_request(unspecified)
    nan_zone = copy.deepcopy(messages["optimise"])
    nan_zone.exclusions[0].center.x = math.nan
    assert "exclusions[0].center.x = nan: must be a finite number" in rejected(nan_zone)
    zero_zone = copy.deepcopy(messages["optimise"])
    zero_zone.exclusions[0].radius = 0.0
    assert "exclusions[0].radius = 0" in rejected(zero_zone)
    many = copy.deepcopy(messages["optimise"])
    many.num_cameras = 5000
    assert "num_cameras = 5000" in rejected(many)


def test_far_coordinates_and_targets_are_refused(messages, scene):
    from perch_common.mesh import Mesh
    from perch_common.ros.conversions import mesh_to_msg

    far = copy.deepcopy(messages["segment"])
    vertices = scene.mesh.vertices.copy()
    vertices[5] = 1e30
    far.mesh = mesh_to_msg(Mesh(vertices, scene.mesh.faces))
    message = rejected(far)
    assert "mesh.vertices[15] = 1e+30: beyond 10 km" in message and "--scale 0.001" in message
    big_target = copy.deepcopy(messages["filter"])
    big_target.target.box.size.x = 1e6
    assert "target.box.size.x = 1e+06: beyond 10 km" in rejected(big_target)
    extent = float(np.ptp(scene.mesh.vertices, axis=0).max())
    oversized = copy.deepcopy(messages["filter"])
    oversized.target.box.size.x = 11 * extent
    assert "more than 10x larger" in rejected(oversized)


@pytest.mark.parametrize("scale, unit, hint", [(1000.0, "millimetres", "--scale 0.001"),
                                               (100.0, "centimetres", "--scale 0.01")])
def test_a_room_in_mm_or_cm_gets_a_scale_hint(scene, scale, unit, hint):
    from perch_common.mesh import Mesh, inspect_mesh
    from perch_common.ros.conversions import mesh_to_msg
    from perch_interfaces import srv

    mesh = Mesh(scene.mesh.vertices * scale, scene.mesh.faces)
    message = rejected(srv.Segment.Request(mesh=mesh_to_msg(mesh)))
    assert unit in message and hint in message
    # `perch mesh info` reports the same instead of "problems: none".
    assert any(unit in w and hint in w for w in inspect_mesh(mesh).warnings)


def test_index_ranges_target_faces_and_footprints(messages, scene):
    from perch_common.mesh import Mesh
    from perch_common.ros.conversions import mesh_to_msg, to_array
    from perch_interfaces import msg as pm
    from perch_interfaces import srv

    footprint = Mesh([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 7]])
    bad_footprint = copy.deepcopy(messages["optimise"])
    bad_footprint.target = pm.TargetVolume(kind=pm.TargetVolume.KIND_EXTRUDED_FOOTPRINT,
                                           footprint=mesh_to_msg(footprint), height=1.2)
    assert "target.footprint.triangles: 1 faces index vertices outside 0..2" in rejected(bad_footprint)
    flat_footprint = copy.deepcopy(bad_footprint)
    flat_footprint.target.footprint = mesh_to_msg(Mesh([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]]))
    flat_footprint.target.height = 0.0
    assert "target.height = 0" in rejected(flat_footprint)
    partial = srv.Segment.Request()
    partial.mesh.vertices = to_array(np.zeros(7), np.float32)
    assert "multiples of 3" in rejected(partial)
    for request in (srv.CleanMesh.Request(mesh=messages["clean"].mesh, target_faces=1),
                    srv.Reconstruct.Request(bag_path="x.mcap", target_faces=1)):
        assert "target_faces = 1: give 0" in rejected(request)


def test_a_room_in_georeferenced_coordinates_is_refused_naming_the_shift_that_brings_it_near(scene):
    from perch_common.mesh import Mesh, inspect_mesh
    from perch_common.ros.conversions import mesh_to_msg
    from perch_interfaces import srv

    utm = np.array([450123.25, 5201234.5, 312.0])   # a room placed in UTM coordinates
    mesh = Mesh(scene.mesh.vertices + utm, scene.mesh.faces)
    message = rejected(srv.Segment.Request(mesh=mesh_to_msg(mesh)))
    assert "georeferenced" in message and "5,201.2 km from its origin" in message and "--scale" not in message
    shift = np.array([float(v) for v in message.split("--shift=")[1].split(";")[0].split(",")])
    # The shift it names is whole tens of metres and brings the room within a few metres of the origin.
    assert np.all(shift % 10 == 0)
    assert np.abs(scene.mesh.vertices + utm + shift).max() < np.ptp(scene.mesh.vertices, axis=0).max() + 10
    assert any("georeferenced" in p for p in inspect_mesh(mesh).fatal)   # `perch mesh info` and load_mesh refuse it
