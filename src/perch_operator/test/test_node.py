"""perch_operator node across processes: crop service, confirm without a mission, missing stages."""

import numpy as np
import pytest

from perch_common.ros import testing

pytestmark = pytest.mark.ros


@pytest.fixture(scope="module")
def ros(ros_node, operator):
    """The client node, with the perch_operator node running for the whole module."""
    with operator(service_wait=0.5, clean_given_mesh=False):
        yield ros_node


@pytest.fixture
def room_msg(meshes):
    from perch_common.ros.conversions import mesh_to_msg

    return mesh_to_msg(meshes.room())


def test_crop_service_keeps_box_and_resolves_default_target(ros, room_msg):
    from perch_common.ros.conversions import from_array, mesh_from_msg, pose_msg, target_from_msg, vector_msg
    from perch_interfaces import msg as pm
    from perch_interfaces.srv import Crop

    request = Crop.Request(mesh=room_msg)
    pose = np.eye(4)
    pose[:3, 3] = [1.0, 1.5, 1.25]
    request.keep_boxes = [pm.OrientedBox(pose=pose_msg(pose), size=vector_msg([2.0, 3.2, 3.0]))]
    reply = testing.call_service(ros, Crop, "/perch/crop", request, timeout=20)
    assert reply.success, reply.message
    assert len(reply.kept_faces) == 0  # not sent unless asked
    request.return_kept_faces = True
    reply = testing.call_service(ros, Crop, "/perch/crop", request, timeout=20)
    kept = from_array(reply.kept_faces, np.uint32)
    mesh = mesh_from_msg(reply.mesh)
    assert mesh.num_faces == len(kept) > 0
    assert mesh.bounds()[1][0] <= 2.1 + 1e-6  # centroid inside: faces straddle by < one cell
    target = target_from_msg(reply.target)
    assert target is not None and not target.is_box
    np.testing.assert_allclose(target.bounds()[1], [2.0, 3.0, 1.2], atol=0.06)


def test_crop_bad_input_is_a_clear_error_and_node_survives(ros, room_msg):
    from perch_common.ros.conversions import vector_msg
    from perch_interfaces import msg as pm
    from perch_interfaces.srv import Crop

    bad = Crop.Request(mesh=room_msg)
    bad.keep_boxes = [pm.OrientedBox(size=vector_msg([1.0, -1.0, 1.0]))]
    bad.keep_boxes[0].pose.orientation.w = 1.0
    reply = testing.call_service(ros, Crop, "/perch/crop", bad, timeout=20)
    assert not reply.success and "keep_boxes[0].size.y = -1" in reply.message and "> 0" in reply.message
    empty = testing.call_service(ros, Crop, "/perch/crop", Crop.Request(), timeout=20)
    assert not empty.success and "crop mesh" in empty.message and "0 faces" in empty.message
    again = testing.call_service(ros, Crop, "/perch/crop", Crop.Request(mesh=room_msg), timeout=20)
    assert again.success


def test_confirm_without_a_mission_is_refused(ros):
    from perch_interfaces.srv import Confirm

    reply = testing.call_service(ros, Confirm, "/perch/confirm", Confirm.Request(proposal_id=3), timeout=10)
    assert not reply.success and "no mission" in reply.message


def test_mission_with_a_missing_stage_names_it(ros, room_msg):
    from perch_interfaces.action import PlanPerches
    from perch_operator.api.client import run_mission

    goal = PlanPerches.Goal(mesh=room_msg, auto_accept=True)
    result = run_mission(ros, goal, timeout=30)
    if result.stage_names and "segment" in result.stage_names:
        pytest.skip("a segmentation node is running on this domain")
    assert not result.success
    assert "stage segment (/perch/segment)" in result.message and "not available" in result.message
    assert result.stage_names == ["crop"]
