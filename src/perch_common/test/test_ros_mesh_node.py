"""Cross-process: a real perch_mesh_tools node answers a 300k-face TriangleMesh request."""

import numpy as np
import pytest

pytestmark = pytest.mark.ros


@pytest.fixture(scope="module")
def ros_node():
    import rclpy

    from perch_common.ros.node_main import ros_context
    from perch_common.ros.testing import node_process, use_isolated_ros_env

    use_isolated_ros_env()
    with ros_context(), node_process("perch_common.mesh_node") as proc:
        node = rclpy.create_node("test_mesh_node_client")
        yield node, proc
        node.destroy_node()


def call(node, mesh_msg, echo=False):
    from perch_common.ros.testing import call_service
    from perch_interfaces.srv import InspectMesh

    return call_service(node, InspectMesh, "/perch/inspect_mesh", InspectMesh.Request(mesh=mesh_msg, echo=echo), timeout=60)


def test_large_mesh_round_trip(ros_node):
    from perch_common.bench_transport import grid_mesh
    from perch_common.ros.conversions import mesh_from_msg, mesh_to_msg

    node, _ = ros_node
    mesh = grid_mesh(300000)
    reply = call(node, mesh_to_msg(mesh), echo=True)
    assert reply.success, reply.message
    assert reply.faces == mesh.num_faces == 299538 and reply.vertices == mesh.num_vertices
    assert reply.bounds_max.x == pytest.approx(10.0, abs=1e-5)
    echoed = mesh_from_msg(reply.mesh)
    assert np.array_equal(echoed.faces, mesh.faces)
    assert np.array_equal(echoed.vertices, mesh.vertices.astype(np.float32))
    assert np.array_equal(echoed.vertex_colors, mesh.vertex_colors)


def test_bad_meshes_get_clear_replies_and_node_keeps_serving(ros_node):
    from perch_common.mesh import Mesh
    from perch_common.ros.conversions import mesh_to_msg, to_array
    from perch_interfaces.msg import TriangleMesh

    node, proc = ros_node
    nan_mesh = mesh_to_msg(Mesh([[0, 0, np.nan], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]]))
    reply = call(node, nan_mesh)
    assert not reply.success and "NaN or infinite" in reply.message
    broken = TriangleMesh()
    broken.vertices = to_array(np.zeros(7), np.float32)
    reply = call(node, broken)
    assert not reply.success and "multiples of 3" in reply.message
    reply = call(node, TriangleMesh())
    assert not reply.success and "empty" in reply.message
    out_of_range = mesh_to_msg(Mesh([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 5]]))
    assert "outside 0..2" in call(node, out_of_range).message
    assert proc.poll() is None
    good = mesh_to_msg(Mesh([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]]))
    assert call(node, good).success
