"""Small synthetic meshes and a ROS client node shared by the perch_operator tests (importlib mode: via fixtures)."""

from types import SimpleNamespace

import numpy as np
import pytest

from perch_common.mesh import Mesh


def grid(nx: int, ny: int, size: tuple[float, float], z: float = 0.0, up: bool = True) -> Mesh:
    """A flat grid of 2*nx*ny triangles in [0,size] at height z, facing up (or down)."""
    xs, ys = np.linspace(0, size[0], nx + 1), np.linspace(0, size[1], ny + 1)
    vx, vy = np.meshgrid(xs, ys, indexing="ij")
    vertices = np.column_stack([vx.ravel(), vy.ravel(), np.full(vx.size, z)])
    idx = np.arange(vx.size).reshape(nx + 1, ny + 1)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    faces = np.concatenate([np.column_stack([a, b, c]), np.column_stack([a, c, d])])
    return Mesh(vertices, faces if up else faces[:, ::-1])


def merge(*meshes: Mesh) -> Mesh:
    offsets = np.cumsum([0] + [m.num_vertices for m in meshes[:-1]])
    return Mesh(np.vstack([m.vertices for m in meshes]),
                np.vstack([m.faces + o for m, o in zip(meshes, offsets)]))


def room() -> Mesh:
    """A 4 x 3 m floor at z=0, a ceiling at 2.5 m and a 1 x 1 m table top at 0.7 m."""
    table = grid(5, 5, (1.0, 1.0), 0.7)
    table.vertices[:, :2] += [1.5, 1.0]
    return merge(grid(40, 30, (4.0, 3.0), 0.0), grid(40, 30, (4.0, 3.0), 2.5, up=False), table)


@pytest.fixture
def meshes() -> SimpleNamespace:
    return SimpleNamespace(grid=grid, merge=merge, room=room)


@pytest.fixture(scope="module")
def ros_node():
    """A client node on an isolated ROS domain for one test module (rclpy init ... shutdown around it)."""
    from perch_common.ros import testing

    testing.use_isolated_ros_env()
    import rclpy

    from perch_common.ros.node_main import ros_context

    with ros_context():
        node = rclpy.create_node("test_operator_client")
        try:
            yield node
        finally:
            node.destroy_node()


def operator_process(**params):
    """The perch_operator node as a process, with the repo config and `perch_operator:` parameter overrides."""
    from perch_common.config import default_config_path
    from perch_common.ros import testing

    return testing.node_process("perch_operator.coordinator.node", params_file=default_config_path(),
                                params={f"perch_operator:{k}": v for k, v in params.items()})


@pytest.fixture(scope="session")
def operator():
    """`with operator(param=value): ...` runs the perch_operator node for the block."""
    return operator_process
