"""Cross-process: a /perch/segment call reports its progress on perch/stage_progress, and a call over its
work budget is refused with the reason while the node keeps serving (perch_common.work)."""

import time

import pytest

pytestmark = pytest.mark.ros


@pytest.fixture(scope="module")
def ros_node():
    import rclpy

    from perch_common.ros.node_main import ros_context
    from perch_common.ros.testing import node_process, use_isolated_ros_env

    use_isolated_ros_env()
    with ros_context(), node_process("perch_segmentation.node", params={"min_area": 0.2}) as proc:
        node = rclpy.create_node("test_segmentation_budget_client")
        yield node, proc
        node.destroy_node()


def _segment(node, mesh, request_id):
    from perch_common.ros.conversions import mesh_to_msg
    from perch_common.ros.testing import call_service
    from perch_interfaces.srv import Segment

    request = Segment.Request(mesh=mesh_to_msg(mesh), request_id=request_id)
    return call_service(node, Segment, "/perch/segment", request, timeout=60)


def _set(node, name, value):
    from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
    from rcl_interfaces.srv import SetParameters

    from perch_common.ros.testing import call_service

    request = SetParameters.Request(parameters=[Parameter(
        name=name, value=ParameterValue(type=ParameterType.PARAMETER_DOUBLE, double_value=value))])
    result = call_service(node, SetParameters, "/perch_segmentation/set_parameters", request, timeout=10,
                          resend_every=5).results[0]
    assert result.successful, result.reason


def test_a_call_reports_its_phases_with_rising_fractions(ros_node):
    import rclpy

    from perch_common.ros.service import STARTED_PHASE
    from perch_interfaces.msg import StageProgress
    from perch_segmentation.testing import box_room

    node, _ = ros_node
    received = []
    subscription = node.create_subscription(StageProgress, "/perch/stage_progress", received.append, 100)
    mesh = box_room(door=True, noise=0.002)[0]
    try:
        # The subscription may match the node's publisher after the first call began: call until one
        # call's reports arrive (a generous deadline, not a sleep).
        deadline, attempt, mine = time.monotonic() + 90, 0, []
        while time.monotonic() < deadline:
            attempt += 1
            reply = _segment(node, mesh, f"progress/{attempt}")
            assert reply.success, reply.message
            end = time.monotonic() + 2
            while time.monotonic() < end:
                rclpy.spin_once(node, timeout_sec=0.1)
            mine = [m for m in received if m.request_id == f"progress/{attempt}"]
            if mine and mine[0].phase == STARTED_PHASE:   # heard from the call's start
                break
        assert mine, "no progress report arrived for any call"
    finally:
        node.destroy_subscription(subscription)
    assert all(m.service == "perch/segment" for m in mine)
    fractions = [m.fraction for m in mine]
    assert fractions == sorted(fractions) and 0.0 <= fractions[0] and fractions[-1] <= 1.0
    phases = [m.phase for m in mine]
    assert phases[:2] == [STARTED_PHASE, "prepare"]   # the call announced as it starts, then its own phases
    assert {"merge planes", "surface outlines"} <= set(phases)   # every phase change is sent
    assert fractions[phases.index("surface outlines")] == pytest.approx(0.8)


def test_a_call_over_its_work_budget_is_refused_with_the_reason_and_the_node_keeps_serving(ros_node):
    from perch_segmentation.testing import box_room

    node, proc = ros_node
    mesh = box_room()[0]
    _set(node, "work_budget_base", 0.001)
    _set(node, "work_budget_rate", 0.0)
    try:
        refused = _segment(node, mesh, "budget/1")
    finally:
        _set(node, "work_budget_base", 120.0)
        _set(node, "work_budget_rate", 0.5)
    assert not refused.success
    assert refused.message.startswith(f"perch/segment exceeded its work budget of 0.001 s for {mesh.num_faces:,} "
                                      "faces: the mesh is likely a triangle soup; run `perch mesh info`; if the "
                                      "input is sound, raise perch_segmentation's work_budget_base"), refused.message
    assert proc.poll() is None
    again = _segment(node, mesh, "budget/2")
    assert again.success and len(again.surfaces) == 6, again.message
