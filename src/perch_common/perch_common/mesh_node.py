"""perch_mesh_tools node: `/perch/inspect_mesh` validates any mesh a robot node sends."""

from __future__ import annotations

import sys
from dataclasses import dataclass

from rclpy.node import Node

from perch_common.config import param
from perch_common.mesh import inspect_mesh
from perch_common.ros.conversions import mesh_from_msg, point_msg, vector_msg
from perch_common.ros.node_main import run_node
from perch_common.ros.params import declare_config
from perch_common.ros.service import answering
from perch_common.up_axis import estimate_mesh_up
from perch_interfaces.srv import InspectMesh


@dataclass
class MeshToolsConfig:
    """The perch_mesh_tools node's parameters."""

    service_name: str = param("perch/inspect_mesh", "service to offer", read_only=True)


class MeshToolsNode(Node):
    """Serves the mesh inspection service: problems, size, bounds and an up estimate of any mesh."""

    def __init__(self) -> None:
        super().__init__("perch_mesh_tools")
        self.config = declare_config(self, MeshToolsConfig)
        self.create_service(InspectMesh, self.config.service_name, self.on_inspect)
        self.get_logger().info(f"serving {self.config.service_name}")

    @answering
    def on_inspect(self, request: InspectMesh.Request, response: InspectMesh.Response) -> InspectMesh.Response:
        """Answer one inspection request (success=false with the problems for an unusable mesh)."""
        mesh = mesh_from_msg(request.mesh)  # a malformed message raises: answered success=false
        problems = inspect_mesh(mesh)
        response.problems = problems.fatal + problems.warnings
        response.faces, response.vertices = mesh.num_faces, mesh.num_vertices
        response.success = not problems.fatal
        if problems.fatal:
            response.message = "unusable mesh: " + "; ".join(problems.fatal)
        else:
            lo, hi = mesh.bounds()
            response.bounds_min, response.bounds_max = point_msg(lo), point_msg(hi)
            response.up_estimate = vector_msg(estimate_mesh_up(mesh).up)
            response.message = f"{mesh.num_faces} faces, {mesh.num_vertices} vertices" + (
                f" ({len(problems.warnings)} warning(s))" if problems.warnings else "")
        if request.echo:
            response.mesh = request.mesh
        return response


COMPONENT = MeshToolsNode  # what a one-process graph (perch_common.ros.container) hosts


def main(args: list[str] | None = None) -> int:
    """Run the perch_mesh_tools node until Ctrl-C."""
    return run_node(MeshToolsNode, args)


if __name__ == "__main__":
    sys.exit(main())
