"""perch_placement node: serves /perch/optimise (perch_interfaces/srv/Optimise)."""

from __future__ import annotations

import math
import sys

from rclpy.node import Node

from perch_common.conventions import STAGE_SERVICES
from perch_common.ros.conversions import (
    exclusion_from_msg,
    mesh_from_request,
    placement_from_msg,
    placement_to_msg,
    region_from_msg,
    target_from_msg,
)
from perch_common.ros.node_main import run_node
from perch_common.ros.params import declare_config, read_config
from perch_common.ros.service import answering, create_stage_action, create_stage_service, set_work_budget
from perch_interfaces import action, srv
from perch_placement.config import CameraSpec, DroneSpec, PlacementConfig, PlacementNodeConfig
from perch_placement.core import PlacementCache, optimise


def camera_from_msg(msg) -> CameraSpec:
    """The camera of a perch_interfaces/CameraSpec."""
    return CameraSpec(name=msg.name or "custom", width=int(msg.width), height=int(msg.height), fx=msg.fx,
                      fy=msg.fy, cx=msg.cx, cy=msg.cy, distortion=tuple(float(c) for c in msg.distortion),
                      baseline=msg.baseline, subpixel_error=msg.subpixel_error, min_range=msg.min_range,
                      max_range=msg.max_range, min_feature_size=msg.min_feature_size,
                      min_feature_pixels=msg.min_feature_pixels, max_zoom=max(msg.max_zoom, 1.0))


def drone_from_msg(msg) -> DroneSpec:
    """The drone of a perch_interfaces/DroneSpec (angles in radians on the wire)."""
    return DroneSpec(radius=msg.radius, camera_offset=msg.camera_offset,
                     pan_range_deg=math.degrees(msg.pan_range), tilt_range_deg=math.degrees(msg.tilt_range),
                     gimbal_limited_targeting=bool(msg.gimbal_limited_targeting),
                     target_deviation_deg=math.degrees(msg.target_deviation), min_spacing=msg.min_spacing)


class PlacementNode(Node):
    """Serves the optimise service: perch regions and a target in, camera placements out."""

    def __init__(self) -> None:
        super().__init__("perch_placement")
        config = declare_config(self, PlacementNodeConfig, check=PlacementNodeConfig.validate)
        # Re-optimising after a rejection reuses the scene and candidates (scenes bounded in faces).
        self.cache = PlacementCache(max_scene_faces=config.scene_cache_faces)
        self.service = create_stage_service(self, srv.Optimise, STAGE_SERVICES["optimise"], self.optimise,
                                            config.introspection)
        self.action = create_stage_action(self, action.Optimise, srv.Optimise, STAGE_SERVICES["optimise"], self.optimise,
                                          result_timeout=config.action_server_result_timeout)
        self.get_logger().info(f"ready: {STAGE_SERVICES['optimise']}")

    def _request_config(self, request) -> PlacementConfig:
        config = read_config(self, PlacementNodeConfig).stage_config().resolved()
        if request.camera.specified:
            config.camera = camera_from_msg(request.camera).validate()
        if request.drone.specified:
            config.drone = drone_from_msg(request.drone)
        return config

    @answering
    def optimise(self, request: srv.Optimise.Request, response: srv.Optimise.Response) -> srv.Optimise.Response:
        """Answer one optimise request (success=false with the reason for unusable input)."""
        config = self._request_config(request)
        target = target_from_msg(request.target)
        if target is None:
            raise ValueError("target volume kind DEFAULT: the placement stage needs an explicit target "
                             "(box or extruded footprint)")
        if not request.regions:
            raise ValueError("no perch regions given: nothing to place cameras on")
        count = int(request.num_cameras) if request.num_cameras > 0 else config.num_cameras
        mesh = mesh_from_request(request.mesh, "environment mesh")
        set_work_budget(self, read_config(self, PlacementNodeConfig), mesh.num_faces,
                        hint=f"placing {count} cameras on {len(request.regions)} perch regions took too long")
        result = optimise(
            mesh,
            [region_from_msg(r) for r in request.regions], target, count, config,
            fixed=[placement_from_msg(p) for p in request.fixed],
            exclusions=[exclusion_from_msg(z) for z in request.exclusions],
            method=request.method or config.method,
            seed=int(request.seed) if request.seed >= 0 else config.seed, cache=self.cache)
        response.placements = [placement_to_msg(p) for p in result.placements]
        response.fitness, response.coverage = result.fitness, result.coverage
        response.mean_uncertainty, response.upper_bound = result.mean_uncertainty, result.upper_bound
        response.evaluations = int(result.evaluations)
        a = result.assessment
        response.expected_fitness, response.p5_fitness = a.expected_fitness, a.p5_fitness
        response.kview_coverage = a.kview_coverage
        response.worst_coverage_without_one = a.worst_coverage_without
        response.mean_coverage_without_one = a.mean_coverage_without
        response.worst_kview_coverage_without_one = a.worst_kview_without
        response.mean_kview_coverage_without_one = a.mean_kview_without
        response.coverage_bound = result.coverage_bound
        response.success = len(result.placements) > 0 or count == 0
        response.message = result.message
        return response


COMPONENT = PlacementNode  # what a one-process graph (perch_common.ros.container) hosts


def main(args: list[str] | None = None) -> int:
    """Run the perch_placement node until Ctrl-C."""
    return run_node(lambda: PlacementNode(), args)


if __name__ == "__main__":
    sys.exit(main())
