"""Cross-process: the perch_placement node answers /perch/optimise, including error replies."""

import math

import numpy as np
import pytest
from placement_rooms import box_room

from perch_common.target import TargetVolume

pytestmark = pytest.mark.ros


@pytest.fixture(scope="module")
def ros_node():
    import rclpy

    from perch_common.ros.node_main import ros_context
    from perch_common.ros.testing import node_process, use_isolated_ros_env

    use_isolated_ros_env()
    params = {"pso.particles": 30, "pso.iterations": 20, "candidate_spacing": 0.5}
    with ros_context(), node_process("perch_placement.node", params=params) as proc:
        node = rclpy.create_node("test_placement_client")
        yield node, proc
        node.destroy_node()


def request(num_cameras=2, regions=True, **fields):
    from perch_common.ros.conversions import mesh_to_msg, region_to_msg, target_to_msg
    from perch_interfaces.srv import Optimise

    mesh, room_regions = box_room()
    target = TargetVolume(center=np.array([3.0, 2.5, 0.8]), size=np.array([2.0, 2.0, 1.2]))
    req = Optimise.Request(mesh=mesh_to_msg(mesh), target=target_to_msg(target), num_cameras=num_cameras,
                           seed=-1, **fields)
    if regions:
        req.regions = [region_to_msg(r) for r in room_regions]
    return req


def call(node, req):
    from perch_common.ros.testing import call_service
    from perch_interfaces.srv import Optimise

    return call_service(node, Optimise, "/perch/optimise", req, timeout=60)


def test_optimise_places_cameras_and_reoptimises_after_a_rejection(ros_node):
    from perch_common.ros.conversions import point_msg, pose_matrix
    from perch_interfaces.msg import ExclusionZone

    node, proc = ros_node
    reply = call(node, request(2))
    assert reply.success, reply.message
    assert len(reply.placements) == 2 and 0 < reply.fitness <= 1
    assert reply.placements[1].fitness == pytest.approx(reply.fitness)
    assert reply.coverage == pytest.approx(reply.placements[1].coverage) and reply.coverage > 0.5
    assert reply.upper_bound >= reply.fitness - 1e-6 and reply.evaluations > 0 and reply.seconds > 0
    # Robustness of the whole arrangement and of each camera travel with the reply.
    assert 0 <= reply.p5_fitness <= reply.expected_fitness <= 1 and 0 <= reply.kview_coverage <= reply.coverage
    assert reply.worst_coverage_without_one <= reply.mean_coverage_without_one <= reply.coverage
    assert reply.coverage <= reply.coverage_bound + 1e-9 or "off its grid" in reply.message
    without = [p.coverage_without for p in reply.placements]
    assert min(without) == pytest.approx(reply.worst_coverage_without_one, abs=1e-12)
    assert np.mean(without) == pytest.approx(reply.mean_coverage_without_one, abs=1e-12)
    assert all(math.isfinite(p.expected_contribution) for p in reply.placements)
    first, second = reply.placements
    drone = pose_matrix(first.drone_pose)
    camera = pose_matrix(first.camera_pose)
    assert np.linalg.norm(camera[:3, 3] - drone[:3, 3]) == pytest.approx(0.1, abs=1e-5)  # camera offset
    assert abs(first.pan) <= math.pi / 4 + 1e-9 and abs(first.tilt) <= math.pi / 4 + 1e-9
    # Reject the second camera: keep the first, exclude the second's perch.
    zone = ExclusionZone(center=point_msg(pose_matrix(second.drone_pose)[:3, 3]), radius=0.5)
    again = call(node, request(1, fixed=[first], exclusions=[zone], method="celf"))
    assert again.success, again.message
    new = pose_matrix(again.placements[0].drone_pose)[:3, 3]
    assert np.linalg.norm(new - pose_matrix(second.drone_pose)[:3, 3]) >= 0.5
    assert again.placements[0].drone_index == 1
    assert proc.poll() is None


def test_bad_requests_get_clear_replies_and_the_node_keeps_serving(ros_node):
    node, proc = ros_node
    reply = call(node, request(1, regions=False))
    assert not reply.success and "no perch regions" in reply.message
    reply = call(node, request(1, method="magic"))
    assert not reply.success and "method 'magic'" in reply.message
    bad_target = request(1)
    bad_target.target.kind = 0
    reply = call(node, bad_target)
    assert not reply.success and "needs an explicit target" in reply.message
    broken = request(1)
    broken.mesh.triangles = broken.mesh.triangles[:-1]
    reply = call(node, broken)
    assert not reply.success and "multiples of 3" in reply.message
    assert proc.poll() is None
    assert call(node, request(1)).success
