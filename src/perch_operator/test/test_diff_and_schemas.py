"""Reply comparison for replay --check, and the MCAP schema texts (decodable by mcap_ros2)."""

import array

import pytest

from perch_common.ros.msgdefs import full_definition, message_class
from perch_interfaces import msg as pm
from perch_interfaces import srv
from perch_operator.diff import Tolerance, diff_messages


def optimise_reply(x: float, fitness: float = 0.5, count: int = 2) -> srv.Optimise.Response:
    reply = srv.Optimise.Response(success=True, message="anything", fitness=fitness, seconds=1.0)
    for i in range(count):
        p = pm.CameraPlacement(drone_index=i, region_id=3)
        p.drone_pose.position.x = x + i
        reply.placements.append(p)
    return reply


def test_equal_replies_match_ignoring_time_and_message():
    a, b = optimise_reply(1.0), optimise_reply(1.0)
    b.seconds, b.message = 9.0, "other words"
    assert diff_messages(a, b) == []


def test_numbers_within_tolerance_match_and_outside_are_reported_with_path():
    a, b = optimise_reply(1.0), optimise_reply(1.0 + 1e-7)
    assert diff_messages(a, b) == []
    c = optimise_reply(1.25)
    [line, line2] = diff_messages(a, c)
    assert line.startswith("placements[0].drone_pose.position.x: recorded 1, replayed 1.25")
    assert "placements[1]" in line2
    assert diff_messages(a, c, Tolerance(rtol=0.0, atol=0.3)) == []


def test_length_and_integer_differences():
    a, b = optimise_reply(1.0, count=2), optimise_reply(1.0, count=3)
    assert diff_messages(a, b) == ["placements: 2 recorded, 3 replayed"]
    b = optimise_reply(1.0)
    b.placements[1].region_id = 4
    assert diff_messages(a, b) == ["placements[1].region_id: recorded 3, replayed 4"]


def test_numeric_arrays_report_count_and_worst_value():
    a, b = pm.TriangleMesh(), pm.TriangleMesh()
    a.vertices = array.array("f", [0.0, 1.0, 2.0, 3.0])
    b.vertices = array.array("f", [0.0, 1.0, 2.5, 3.0])
    [line] = diff_messages(a, b)
    assert line == "vertices: 1 of 4 values differ (worst at [2]: recorded 2, replayed 2.5)"
    b.vertices = array.array("f", [0.0, 1.0])
    assert diff_messages(a, b) == ["vertices: 4 values recorded, 2 replayed"]
    a.triangles, b.triangles = array.array("I", [0, 1, 2]), array.array("I", [0, 2, 1])
    assert "triangles: 2 of 3 values differ" in diff_messages(a, b)[1]


def test_limit_caps_the_output():
    a, b = optimise_reply(1.0, count=30), optimise_reply(2.0, count=30)
    lines = diff_messages(a, b, limit=5)
    assert len(lines) == 6 and lines[-1].startswith("... and more")


@pytest.mark.parametrize("type_name", ["perch_interfaces/msg/Proposal", "perch_interfaces/msg/PerchWaypoint",
                                       "geometry_msgs/msg/PoseArray", "perch_interfaces/msg/PerchRegion"])
def test_topic_schemas_decode_with_mcap_ros2(type_name):
    from mcap_ros2._dynamic import generate_dynamic
    from rclpy.serialization import serialize_message

    message = message_class(type_name)()
    if type_name.endswith("Proposal"):
        message.id, message.reason = 42, "too close to the lamp"
        message.placement.drone_pose.position.z = 2.5
    decoded = generate_dynamic(type_name, full_definition(type_name))[type_name](serialize_message(message))
    if type_name.endswith("Proposal"):
        assert decoded.id == 42 and decoded.reason == "too close to the lamp"
        assert decoded.placement.drone_pose.position.z == 2.5


def test_event_schema_lists_request_response_and_dependencies_once():
    text = full_definition("perch_interfaces/srv/Optimise_Event")
    lines = text.splitlines()
    assert lines[:3] == ["service_msgs/ServiceEventInfo info",
                         "perch_interfaces/Optimise_Request[<=1] request",
                         "perch_interfaces/Optimise_Response[<=1] response"]
    sections = [line for line in lines if line.startswith("MSG: ")]
    assert len(sections) == len(set(sections))
    for needed in ("perch_interfaces/srv/Optimise_Request", "perch_interfaces/srv/Optimise_Response",
                   "perch_interfaces/msg/CameraPlacement", "geometry_msgs/msg/Pose", "std_msgs/msg/Header",
                   "builtin_interfaces/msg/Time", "service_msgs/msg/ServiceEventInfo"):
        assert f"MSG: {needed}" in sections
    assert message_class("perch_interfaces/srv/Optimise_Event") is srv.Optimise.Event
