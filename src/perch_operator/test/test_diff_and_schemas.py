"""Reply comparison for replay --check, and the MCAP schema texts (decodable by mcap_ros2)."""

import array

import pytest

from perch_common.ros.msgdefs import full_definition, message_class
from perch_interfaces import msg as pm
from perch_interfaces import srv
from perch_operator.cli.diff import Tolerance, diff_messages


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


def test_a_meshs_content_id_is_not_compared_its_arrays_are():
    """A recording made when content ids were another hash still checks: the id is a cache key for the
    arrays, and the arrays themselves are compared."""
    a = srv.Crop.Response(success=True, mesh=pm.TriangleMesh(content_id="0" * 32, vertices=[0.0, 1.0, 2.0]))
    b = srv.Crop.Response(success=True, mesh=pm.TriangleMesh(content_id="f" * 32, vertices=[0.0, 1.0, 2.0]))
    assert diff_messages(a, b) == []
    b.mesh.vertices = array.array("f", [0.0, 1.0, 2.5])
    assert diff_messages(a, b) == ["mesh.vertices: 1 of 3 values differ (worst at [2]: recorded 2, replayed 2.5)"]


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
                                       "geometry_msgs/msg/PoseArray", "perch_interfaces/msg/PerchRegion",
                                       "perch_interfaces/msg/ReconstructionProgress"])
def test_topic_schemas_decode_with_mcap_ros2(type_name):
    from mcap_ros2._dynamic import generate_dynamic
    from rclpy.serialization import serialize_message

    message = message_class(type_name)()
    if type_name.endswith("Proposal"):
        message.id, message.reason = 42, "too close to the lamp"
        message.placement.drone_pose.position.z = 2.5
    if type_name.endswith("ReconstructionProgress"):
        message.mode, message.dropped_reasons, message.dropped_counts = message.MODE_LIVE, ["queue_full"], [3]
    decoded = generate_dynamic(type_name, full_definition(type_name))[type_name](serialize_message(message))
    if type_name.endswith("Proposal"):
        assert decoded.id == 42 and decoded.reason == "too close to the lamp"
        assert decoded.placement.drone_pose.position.z == 2.5
    if type_name.endswith("ReconstructionProgress"):
        assert decoded.mode == "live" and decoded.dropped_reasons == ["queue_full"] and list(decoded.dropped_counts) == [3]


PRIMITIVES = {"bool", "byte", "char", "float32", "float64", "int8", "uint8", "int16", "uint16", "int32",
              "uint32", "int64", "uint64", "string", "wstring"}


def _blocks_and_references(text: str) -> tuple[list[str], set[str]]:
    """MSG: block names of a ros2msg schema, and every non-primitive field type it refers to."""
    blocks, references = [], set()
    for line in text.splitlines():
        if line.startswith("MSG: "):
            blocks.append(line[5:])
            continue
        fields = line.split("#", 1)[0].split()
        if len(fields) >= 2 and "=" not in fields[1]:  # a field, not a constant or a separator
            base = fields[0].split("[")[0].split("<=")[0]
            if base not in PRIMITIVES:
                references.add(base)
    return blocks, references


@pytest.mark.parametrize("type_name", ["perch_interfaces/srv/Optimise_Event", "perch_interfaces/srv/Confirm_Event",
                                       "perch_interfaces/action/PlanPerches_FeedbackMessage",
                                       "sensor_msgs/msg/CameraInfo", "visualization_msgs/msg/MarkerArray"])
def test_schema_blocks_are_named_as_their_fields_refer_to_them(type_name):
    """Each dependency once, headed exactly as the fields name it (rosbag2's layout: `MSG: std_msgs/Header`)."""
    blocks, references = _blocks_and_references(full_definition(type_name))
    assert len(blocks) == len(set(blocks))
    assert set(blocks) == references
    assert all("/msg/" not in name for name in blocks)


def test_event_and_feedback_schemas_keep_their_parts_namespaced():
    lines = full_definition("perch_interfaces/srv/Optimise_Event").splitlines()
    assert lines[:3] == ["service_msgs/ServiceEventInfo info",
                         "perch_interfaces/srv/Optimise_Request[<=1] request",
                         "perch_interfaces/srv/Optimise_Response[<=1] response"]
    blocks, _ = _blocks_and_references("\n".join(lines))
    for needed in ("perch_interfaces/srv/Optimise_Request", "perch_interfaces/srv/Optimise_Response",
                   "perch_interfaces/CameraPlacement", "geometry_msgs/Pose", "std_msgs/Header",
                   "builtin_interfaces/Time", "service_msgs/ServiceEventInfo"):
        assert needed in blocks
    assert message_class("perch_interfaces/srv/Optimise_Event") is srv.Optimise.Event
    feedback = full_definition("perch_interfaces/action/PlanPerches_FeedbackMessage").splitlines()
    assert feedback[:2] == ["unique_identifier_msgs/UUID goal_id", "perch_interfaces/action/PlanPerches_Feedback feedback"]
    assert "MSG: perch_interfaces/action/PlanPerches_Feedback" in feedback


def test_unknown_type_is_a_clear_error():
    with pytest.raises(ValueError, match="no message definition for perch_interfaces/msg/NoSuchThing"):
        full_definition("perch_interfaces/msg/NoSuchThing")
    with pytest.raises(ValueError, match="not a ROS type name"):
        full_definition("not a type")
