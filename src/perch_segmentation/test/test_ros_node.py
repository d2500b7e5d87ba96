"""Cross-process: the live perch_segmentation node serves /perch/segment, errors included."""

import numpy as np
import pytest

pytestmark = pytest.mark.ros


@pytest.fixture(scope="module")
def ros_node():
    import rclpy

    from perch_common.ros.node_main import ros_context
    from perch_common.ros.testing import node_process, use_isolated_ros_env

    use_isolated_ros_env()
    with ros_context(), node_process("perch_segmentation.node", params={"min_area": 0.2}) as proc:
        node = rclpy.create_node("test_segmentation_client")
        yield node, proc
        node.destroy_node()


def call(node, mesh_msg):
    from perch_common.ros.testing import call_service
    from perch_interfaces.srv import Segment

    return call_service(node, Segment, "/perch/segment", Segment.Request(mesh=mesh_msg), timeout=60)


def test_segment_service_answers_surfaces_and_labels(ros_node):
    from perch_common.ros.conversions import from_array, mesh_to_msg, surface_from_msg
    from perch_segmentation.testing import box_room

    node, _ = ros_node
    mesh, plane = box_room(door=True, noise=0.002)
    reply = call(node, mesh_to_msg(mesh))
    assert reply.success, reply.message
    surfaces = [surface_from_msg(s) for s in reply.surfaces]
    assert len(surfaces) == 7  # floor, ceiling, four walls, the door (colour on)
    assert [s.id for s in surfaces] == list(range(7))
    labels = from_array(reply.face_labels, np.uint32)
    assert len(labels) == mesh.num_faces
    floor = surfaces[int(np.bincount(labels[plane == 0]).argmax())]
    np.testing.assert_allclose(floor.frame.normal, [0, 0, 1], atol=0.01)
    assert floor.area == pytest.approx(12.0, rel=0.01)
    assert len(floor.boundary) == 1 and len(floor.boundary[0][0]) >= 4
    assert reply.seconds > 0


def test_bad_requests_get_clear_replies_and_the_node_keeps_serving(ros_node):
    from perch_common.mesh import Mesh
    from perch_common.ros.conversions import mesh_to_msg
    from perch_segmentation.testing import box_room

    node, proc = ros_node
    empty = call(node, mesh_to_msg(Mesh(np.zeros((0, 3)), np.zeros((0, 3)))))
    assert not empty.success and "mesh is empty" in empty.message
    nan = call(node, mesh_to_msg(Mesh([[0, 0, np.nan], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]])))
    assert not nan.success and "NaN or infinite" in nan.message
    bad_index = call(node, mesh_to_msg(Mesh(np.eye(3), [[0, 1, 7]])))
    assert not bad_index.success and "outside 0..2" in bad_index.message
    tiny = call(node, mesh_to_msg(Mesh(np.eye(3) * 0.1, [[0, 1, 2]])))
    assert not tiny.success and "no planar region" in tiny.message
    assert proc.poll() is None
    good = call(node, mesh_to_msg(box_room()[0]))
    assert good.success and len(good.surfaces) == 6


def _set_parameter(node, name, value):
    from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
    from rcl_interfaces.srv import SetParameters

    from perch_common.ros.testing import call_service

    request = SetParameters.Request(parameters=[Parameter(
        name=name, value=ParameterValue(type=ParameterType.PARAMETER_DOUBLE, double_value=value))])
    return call_service(node, SetParameters, "/perch_segmentation/set_parameters", request, timeout=10).results[0]


def test_absurd_parameters_are_rejected_with_a_reason(ros_node):
    """A value outside the range, or one the whole configuration forbids, is refused; the node keeps serving."""
    from perch_common.ros.conversions import mesh_to_msg
    from perch_segmentation.testing import box_room

    node, proc = ros_node
    out_of_range = _set_parameter(node, "theta_max_deg", 200.0)
    assert not out_of_range.successful and "out of range" in out_of_range.reason
    forbidden = _set_parameter(node, "theta_max_deg", 90.0)  # in [0, 90] but the config needs < 90
    assert not forbidden.successful and "theta_max_deg=90.0 must be in (0, 90)" in forbidden.reason
    assert _set_parameter(node, "theta_max_deg", 14.0).successful
    assert _set_parameter(node, "theta_max_deg", 15.0).successful
    assert proc.poll() is None
    assert call(node, mesh_to_msg(box_room()[0])).success
