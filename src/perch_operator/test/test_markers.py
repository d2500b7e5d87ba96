"""Mission markers: frustum geometry from the camera spec, regions and target in the input frame, labels."""

from __future__ import annotations

import math

import numpy as np
import pytest
from builtin_interfaces.msg import Time
from visualization_msgs.msg import Marker

from perch_interfaces import msg as pm
from perch_operator.coordinator.markers import frustum_lines, mission_markers


def camera(width=1280, height=720, hfov_deg=87.0, vfov_deg=58.0, max_range=10.0) -> pm.CameraSpec:
    fx = width / 2 / math.tan(math.radians(hfov_deg) / 2)
    fy = height / 2 / math.tan(math.radians(vfov_deg) / 2)
    return pm.CameraSpec(specified=True, width=width, height=height, fx=fx, fy=fy, cx=width / 2, cy=height / 2,
                         max_range=max_range)


def proposal(pid=7, status=pm.Proposal.STATUS_ACCEPTED, gain=0.125) -> pm.Proposal:
    msg = pm.Proposal(id=pid, status=status)
    msg.placement.drone_index = 2
    msg.placement.marginal_gain = gain
    msg.placement.drone_pose.position.x, msg.placement.drone_pose.position.z = 1.0, 2.0
    msg.placement.drone_pose.orientation.w = 1.0
    # optical frame looking along world +x: z_cam = +x, x_cam = -y, y_cam = -z
    rotation = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
    from perch_common.transforms import quaternion_from_matrix

    q = quaternion_from_matrix(rotation)
    pose = msg.placement.camera_pose
    pose.position.x, pose.position.z = 1.0, 2.0
    pose.orientation.x, pose.orientation.y, pose.orientation.z, pose.orientation.w = map(float, q)
    return msg


def test_frustum_opens_at_the_cameras_field_of_view_along_its_view_axis():
    lines = frustum_lines(proposal().placement.camera_pose, camera()).reshape(-1, 2, 3)
    apex = np.array([1.0, 0.0, 2.0])
    np.testing.assert_allclose(lines[:4, 0], np.tile(apex, (4, 1)))
    far = lines[:4, 1]
    np.testing.assert_allclose(far[:, 0], 1.0 + 1.5)  # drawn 1.5 m deep along world +x
    half_width = np.abs(far[:, 1]).max()
    assert math.degrees(2 * math.atan(half_width / 1.5)) == pytest.approx(87.0, abs=1e-6)
    half_height = np.abs(far[:, 2] - 2.0).max()
    assert math.degrees(2 * math.atan(half_height / 1.5)) == pytest.approx(58.0, abs=1e-6)
    zoomed = frustum_lines(proposal().placement.camera_pose, camera(), zoom=2.0).reshape(-1, 2, 3)[:4, 1]
    assert np.abs(zoomed[:, 1]).max() == pytest.approx(half_width / 2)


def test_mission_markers_clear_then_draw_regions_target_and_labelled_proposals():
    region = pm.PerchRegion(id=4, surface_class=pm.Surface.CLASS_WALL)
    region.mesh.vertices = [0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0]
    region.mesh.triangles = [0, 1, 2]
    target = pm.TargetVolume(kind=pm.TargetVolume.KIND_BOX)
    target.box.pose.orientation.w = 1.0
    target.box.size.x, target.box.size.y, target.box.size.z = 2.0, 3.0, 1.0
    to_input = np.eye(4)
    to_input[:3, 3] = [10.0, 0.0, 0.0]  # the stages' frame sits 10 m along x in the input frame
    shown = mission_markers([proposal(), proposal(8, pm.Proposal.STATUS_REJECTED, 0.5)], [region], target,
                            camera(), to_input, "scan", None)
    markers = shown.markers
    assert markers[0].action == Marker.DELETEALL
    by_ns = {}
    for m in markers[1:]:
        by_ns.setdefault(m.ns, []).append(m)
        assert m.header.frame_id == "scan"
    [region_marker] = by_ns["perch_regions"]
    assert [(p.x, p.y) for p in region_marker.points] == [(10.0, 0.0), (11.0, 0.0), (10.0, 1.0)]
    [box] = by_ns["target_volume"]
    assert (box.type, box.pose.position.x, box.scale.y) == (Marker.CUBE, 10.0, 3.0)
    labels = sorted(m.text for m in by_ns["proposal_labels"])
    assert labels == ["#7", "#8"]   # short: status is the colour, the numbers are in the console and report
    assert len(by_ns["camera_frustums"]) == 2 and all(len(m.points) == 16 for m in by_ns["camera_frustums"])
    accepted, rejected = sorted(by_ns["perch_proposals"], key=lambda m: m.id)
    assert accepted.color.g > accepted.color.r and rejected.color.r > rejected.color.g


def test_a_camera_without_intrinsics_is_a_clear_error():
    with pytest.raises(ValueError, match="camera spec without intrinsics"):
        frustum_lines(proposal().placement.camera_pose, pm.CameraSpec())


def test_view_camera_info_scales_the_pinhole_model_with_the_image():
    from perch_operator.coordinator.views import camera_info_msg, image_msg

    spec = camera()
    info = camera_info_msg(spec, 320, 180, "perch_drone_2_camera_optical", None)
    assert (info.width, info.height) == (320, 180)
    assert info.k[0] == pytest.approx(spec.fx / 4) and info.k[2] == pytest.approx(160.0)
    assert info.k[4] == pytest.approx(spec.fy / 4) and info.k[5] == pytest.approx(90.0)
    rgb = np.zeros((180, 320, 3), np.uint8)
    rgb[10, 20] = (255, 0, 7)
    image = image_msg(rgb, "f", None)
    back = np.frombuffer(bytes(image.data), np.uint8).reshape(image.height, image.width, 3)
    assert image.step == 960 and tuple(back[10, 20]) == (255, 0, 7)


def test_surfaces_are_outlined_by_class_and_removals_labelled_by_filter():
    from perch_common.conventions import FILTER_COLOURS, FILTER_NAMES

    surface = pm.Surface(id=3, surface_class=pm.Surface.CLASS_CEILING)
    surface.frame.origin.z = 2.5
    surface.frame.axis_u.x, surface.frame.axis_v.y = 1.0, 1.0
    surface.boundary.points_xy = [0.0, 0.0, 2.0, 0.0, 2.0, 1.0, 0.0, 1.0]
    surface.boundary.ring_starts, surface.boundary.ring_polygon = [0], [0]
    removal = pm.FilterRemoval(surface_id=3, area_total=2.0, area_kept=0.5)
    setattr(removal, FILTER_NAMES[0], 0.25)
    setattr(removal, FILTER_NAMES[2], 1.25)
    markers = mission_markers([], [], pm.TargetVolume(), camera(), np.eye(4), "map", None, [surface], [removal]).markers
    [outline] = [m for m in markers if m.ns == "surfaces"]
    assert len(outline.points) == 8 and {p.z for p in outline.points} == {2.5}  # 4 edges of the ring
    assert (outline.points[0].x, outline.points[1].x) == (0.0, 2.0)
    [label] = [m for m in markers if m.ns == "area_removed"]
    assert label.text == "S3"   # short: how much each filter removed is in the report and the console
    assert label.color.r == pytest.approx(FILTER_COLOURS[2][0] / 255)


def scan(faces_per_side: int = 60, coloured: bool = True):
    """A coloured open box (floor and four walls) of 5 x (2 * faces_per_side^2) triangles."""
    import trimesh

    from perch_common.mesh import Mesh

    box = trimesh.creation.box(extents=(4.0, 3.0, 2.5))
    box = box.subdivide_to_size(max(box.extents) / faces_per_side)
    keep = box.face_normals[:, 2] < 0.5   # no ceiling: a viewer looks in from above
    mesh = Mesh(box.vertices, box.faces[keep])
    if coloured:
        red = (mesh.vertices[:, 0] > 0).astype(np.uint8) * 200   # the +x half red, the other blue
        mesh.vertex_colors = np.stack([red + 30, np.full_like(red, 40), 230 - red], axis=1)
    return mesh


def scan_marker_message(*args, **kwargs) -> Marker:
    """scan_marker as the message a viewer receives."""
    from rclpy.serialization import deserialize_message

    from perch_common.ros.marker_wire import serialized_marker
    from perch_operator.coordinator.markers import scan_marker

    return deserialize_message(serialized_marker(*scan_marker(*args, **kwargs)), Marker)


def test_scan_marker_is_a_coloured_triangle_list_within_its_budget_in_the_input_frame():

    mesh = scan()
    assert mesh.num_faces > 20_000
    to_input = np.eye(4)
    to_input[:3, 3] = [0.0, 0.0, 1.0]
    marker = scan_marker_message(mesh, to_input, "map", Time(), max_triangles=5_000)
    assert (marker.type, marker.header.frame_id, marker.ns) == (Marker.TRIANGLE_LIST, "map", "scan")
    triangles = len(marker.points) // 3
    assert len(marker.points) % 3 == 0 and 1_000 < triangles <= 5_000
    assert len(marker.colors) == len(marker.points)   # per-vertex colours
    xyz = np.array([(p.x, p.y, p.z) for p in marker.points])
    np.testing.assert_allclose(xyz.min(axis=0), [-2.0, -1.5, -0.25], atol=0.15)   # shape kept, shifted 1 m up
    np.testing.assert_allclose(xyz.max(axis=0), [2.0, 1.5, 2.25], atol=0.15)
    rgb = np.array([(c.r, c.g, c.b) for c in marker.colors])
    far_red, far_blue = xyz[:, 0] > 1.0, xyz[:, 0] < -1.0
    assert rgb[far_red, 0].min() > 0.8 and rgb[far_blue, 2].min() > 0.8   # colours stay where they were


def test_scan_marker_without_colours_is_grey_and_a_small_scan_is_sent_whole():
    from perch_operator.coordinator.markers import SCAN_GREY, scan_marker

    mesh = scan(faces_per_side=8, coloured=False)
    marker = scan_marker_message(mesh, np.eye(4), "odom", Time())
    assert len(marker.points) == 3 * mesh.num_faces and not marker.colors
    assert (marker.color.r, marker.color.a) == (pytest.approx(SCAN_GREY[0]), 1.0)
    with pytest.raises(ValueError, match="max_triangles must be positive"):
        scan_marker(mesh, np.eye(4), "odom", None, max_triangles=0)
