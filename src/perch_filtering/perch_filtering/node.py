"""perch_filtering node: serves /perch/filter (perch_interfaces/srv/Filter)."""

from __future__ import annotations

import dataclasses
import math
import sys

import numpy as np
from rclpy.node import Node

from perch_common.conventions import STAGE_SERVICES
from perch_common.mesh_cache import add_preparer, remove_preparer
from perch_common.ros.conversions import (
    mesh_from_request,
    region_to_msg,
    removal_to_msg,
    surface_from_msg,
    surface_to_msg,
    target_from_msg,
    xyz,
)
from perch_common.ros.node_main import run_node
from perch_common.ros.params import declare_config, read_config
from perch_common.ros.service import answering, create_stage_action, create_stage_service, set_work_budget
from perch_common.transforms import parse_up_axis
from perch_filtering.config import FilterConfig, FilterNodeConfig
from perch_filtering.core import filter_surfaces, prepare_mesh
from perch_interfaces import action, srv
from perch_interfaces import msg as pm


def config_from_spec(spec, base: FilterConfig) -> FilterConfig:
    """The request's PerchSpec over the node's configuration (specified=false: the node's as is)."""
    if not spec.specified:
        return base
    return dataclasses.replace(
        base, allow_walls=bool(spec.allow_walls), allow_ceiling=bool(spec.allow_ceiling),
        allow_floor=bool(spec.allow_floor), allow_intermediate=bool(spec.allow_intermediate),
        class_angle_deg=math.degrees(spec.class_angle), min_recovery_height=spec.min_recovery_height,
        approach_distance=spec.approach_distance, approach_margin=spec.approach_margin,
        window_width=spec.window_width, window_height=spec.window_height, window_ellipse=bool(spec.window_ellipse),
        raster_density=spec.raster_density, drone_radius=spec.drone_radius, standoff=spec.standoff,
        min_support=spec.min_support, max_support_rms=spec.max_support_rms,
        min_visible_share=spec.min_visible_share)


class FilterNode(Node):
    """Serves the filter service: surfaces in, safe perch regions and per-filter removals out."""

    def __init__(self) -> None:
        super().__init__("perch_filtering")
        config = declare_config(self, FilterNodeConfig, check=FilterNodeConfig.validate)
        self._warm_up()
        self._preparer = None
        if config.prepare_meshes:
            self._preparer = self._prepare_mesh
            add_preparer(self._preparer)
        self.service = create_stage_service(self, srv.Filter, STAGE_SERVICES["filter"], self._filter, config.introspection)
        self.action = create_stage_action(self, action.Filter, srv.Filter, STAGE_SERVICES["filter"], self._filter,
                                          result_timeout=config.action_server_result_timeout)
        self.get_logger().info(f"ready: {STAGE_SERVICES['filter']}")

    @staticmethod
    def _warm_up() -> None:
        """Load and initialise the ray caster (Embree) before the first request, and import Open3D (a
        large mesh's closest-point scene): ~0.5 s of interpreter work that otherwise ran during a
        mission, in the preparer beside segmentation (holding the interpreter lock it needs) or in the
        filter's reachability."""
        from perch_common.mesh import Mesh
        from perch_common.open3d_loader import open3d
        from perch_common.raycast import RayScene

        RayScene(Mesh(np.eye(3), np.array([[0, 1, 2]]))).occluded(np.zeros((1, 3)), np.ones((1, 3)))
        open3d()

    def _prepare_mesh(self, mesh) -> None:
        """What the filter derives from a mesh before knowing its request: the ray scene, the surface
        samples at the configured voxel size and, for a large mesh, the closest-point scene (kept with
        the mesh, see mesh_cache.prepare)."""
        prepare_mesh(mesh, float(self.get_parameter("voxel_size").value),
                     float(self.get_parameter("raster_density").value))

    def destroy_node(self) -> None:
        """Stop preparing this process's meshes for a filter that is gone, then destroy the node."""
        if self._preparer is not None:
            remove_preparer(self._preparer)
            self._preparer = None
        super().destroy_node()

    @answering
    def _filter(self, request: srv.Filter.Request, response: srv.Filter.Response) -> srv.Filter.Response:
        node_config = read_config(self, FilterNodeConfig)
        try:
            config = config_from_spec(request.spec, node_config.stage_config()).validate()
        except ValueError as exc:
            raise ValueError(f"perch spec: {exc}") from exc
        target = target_from_msg(request.target)
        if target is None:
            raise ValueError("target volume kind DEFAULT: the filter needs an explicit target "
                             "(box or extruded footprint)")
        up = xyz(request.up)
        if not np.any(up):
            up = parse_up_axis(node_config.up_axis)
        surfaces = [surface_from_msg(s) for s in request.surfaces]
        mesh = mesh_from_request(request.mesh, "environment mesh")
        set_work_budget(self, node_config, mesh.num_faces)
        result = filter_surfaces(mesh, surfaces, target, up, config)
        if result.second_process not in ("", "done"):  # the same answer, computed here instead
            self.get_logger().warning(f"the second process's surfaces were judged in this one "
                                      f"({result.second_process.splitlines()[0]})")
        response.regions = [region_to_msg(r) for r in result.regions]
        classes = {s.id: int(s.surface_class) for s in result.surfaces}
        response.removals = [removal_to_msg(r) for r in result.removals]
        for removal in response.removals:
            removal.surface_class = classes.get(removal.surface_id, pm.Surface.CLASS_UNKNOWN)
        if request.return_surfaces:   # only when asked: the caller holds the surfaces it sent
            response.surfaces = [surface_to_msg(s) for s in result.surfaces]
        response.success, response.message = True, result.message
        return response


COMPONENT = FilterNode  # what a one-process graph (perch_common.ros.container) hosts


def main(args: list[str] | None = None) -> int:
    """Run the perch_filtering node until Ctrl-C."""
    return run_node(lambda: FilterNode(), args)


if __name__ == "__main__":
    sys.exit(main())
