"""perch_segmentation node: serves /perch/segment (perch_interfaces/srv/Segment)."""

from __future__ import annotations

import sys

import numpy as np
from rclpy.node import Node

from perch_common.conventions import STAGE_SERVICES
from perch_common.ros.conversions import mesh_from_request, surface_to_msg, to_array
from perch_common.ros.node_main import run_node
from perch_common.ros.params import declare_config, read_config
from perch_common.ros.service import answering, create_stage_action, create_stage_service, set_work_budget
from perch_interfaces import action, srv
from perch_segmentation.config import SegmentationNodeConfig
from perch_segmentation.core import segment_mesh

NO_SURFACE = np.uint32(0xFFFFFFFF)  # Segment.srv: face_labels entry of a face on no surface
SERVICE = STAGE_SERVICES["segment"]


def face_labels_array(labels: np.ndarray):
    """Face labels for the message: -1 (no surface) becomes 0xFFFFFFFF."""
    return to_array(np.where(labels >= 0, labels, NO_SURFACE).astype(np.uint32), np.uint32)


class SegmentationNode(Node):
    """Serves the segment service: a mesh in, planar surfaces and face labels out."""

    def __init__(self) -> None:
        super().__init__("perch_segmentation")
        config = declare_config(self, SegmentationNodeConfig, check=lambda c: c.stage_config().validate())
        self.service = create_stage_service(self, srv.Segment, SERVICE, self._segment, config.introspection)
        self.action = create_stage_action(self, action.Segment, srv.Segment, SERVICE, self._segment,
                                          result_timeout=config.action_server_result_timeout)
        self.get_logger().info(f"ready: {SERVICE}")

    @answering
    def _segment(self, request: srv.Segment.Request, response: srv.Segment.Response) -> srv.Segment.Response:
        node_config = read_config(self, SegmentationNodeConfig)
        config = node_config.stage_config()  # valid: checked when set
        mesh = mesh_from_request(request.mesh, "request mesh")
        set_work_budget(self, node_config, mesh.num_faces)
        result = segment_mesh(mesh, config)
        response.surfaces = [surface_to_msg(s) for s in result.surfaces]
        response.face_labels = face_labels_array(result.face_labels)
        labelled = float(np.mean(result.face_labels >= 0)) if len(result.face_labels) else 0.0
        response.success = True
        response.message = (f"{len(result.surfaces)} surfaces from {mesh.num_faces} faces "
                            f"({100 * labelled:.0f}% of faces on a surface)")
        return response


COMPONENT = SegmentationNode  # what a one-process graph (perch_common.ros.container) hosts


def main(args: list[str] | None = None) -> int:
    """Run the perch_segmentation node until Ctrl-C."""
    return run_node(lambda: SegmentationNode(), args)


if __name__ == "__main__":
    sys.exit(main())
