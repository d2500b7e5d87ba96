"""Cross-process: the live perch_filtering node serves /perch/filter."""

import copy

import pytest
from filtering_scenes import Builder, structure

pytestmark = pytest.mark.ros


@pytest.fixture(scope="module")
def ros_node():
    import rclpy

    from perch_common.ros.node_main import ros_context
    from perch_common.ros.testing import node_process, use_isolated_ros_env

    use_isolated_ros_env()
    with ros_context(), node_process("perch_filtering.node", params={"introspection": True}) as proc:
        node = rclpy.create_node("test_filter_client")
        yield node, proc
        node.destroy_node()


@pytest.fixture(scope="module")
def room_request():
    from perch_common.ros.conversions import mesh_to_msg, surface_to_msg, target_to_msg
    from perch_common.target import TargetVolume
    from perch_interfaces.srv import Filter

    b = Builder()
    b.room("room", [[0, 0], [6, 0], [6, 5], [0, 5]], 2.8)
    b.box("table", [2.0, 0.05, 0.0], [3.2, 0.85, 0.75])
    surfaces = b.surfaces(structure(b))
    request = Filter.Request(mesh=mesh_to_msg(b.mesh()), surfaces=[surface_to_msg(s) for s in surfaces],
                             target=target_to_msg(TargetVolume(center=[3.0, 2.5, 1.0], size=[2.0, 1.5, 1.2])))
    return request, surfaces  # up left zero: the node's up_axis (+z)


def call(node, request):
    from perch_common.ros.testing import call_service
    from perch_interfaces.srv import Filter

    return call_service(node, Filter, "/perch/filter", request, timeout=60)


def test_filter_service_answers_and_explains(ros_node, room_request):
    from perch_common.ros.conversions import region_from_msg, removal_from_msg, surface_from_msg
    from perch_common.types import SurfaceClass

    node, proc = ros_node
    request, surfaces = room_request
    reply = call(node, request)
    assert reply.success, reply.message
    regions = [region_from_msg(r) for r in reply.regions]
    removals = [removal_from_msg(r) for r in reply.removals]
    assert len(regions) >= 5 and reply.message.startswith(f"{len(regions)} perch regions")
    assert [r.surface_id for r in removals] == [s.id for s in surfaces]
    classes = ["FLOOR", "CEILING", "WALL", "WALL", "WALL", "WALL"]
    assert [SurfaceClass(r.surface_class).name for r in reply.removals] == classes
    assert len(reply.surfaces) == 0  # not echoed unless asked
    asked = copy.copy(request)
    asked.return_surfaces = True
    echoed = call(node, asked)
    oriented = [surface_from_msg(s) for s in echoed.surfaces]
    assert [s.surface_class.name for s in oriented] == classes
    assert [r.surface_class for r in echoed.removals] == [r.surface_class for r in reply.removals]
    floor = removals[0]
    assert floor.orientation == pytest.approx(floor.area_total, rel=1e-5)  # floor landing is off
    for region in regions:
        assert region.mesh.num_faces > 0 and region.area > 0.25
        assert region.mesh.face_areas().sum() == pytest.approx(region.area, rel=1e-3)
    assert sum(r.area_kept for r in removals) == pytest.approx(sum(r.area for r in regions), rel=0.05)
    assert reply.seconds > 0


def test_spec_and_error_replies_keep_the_node_serving(ros_node, room_request):
    from perch_interfaces.msg import PerchSpec, TargetVolume

    node, proc = ros_node
    request, _ = room_request
    # A spec that allows nothing: a valid empty answer naming the filter that removed the most.
    spec_request = copy.copy(request)
    spec_request.spec = PerchSpec(specified=True, allow_walls=False, allow_ceiling=False, class_angle=0.26,
                                  min_recovery_height=0.5, approach_distance=0.5, approach_margin=0.1,
                                  window_width=0.5, window_height=0.5, raster_density=50.0, drone_radius=0.35,
                                  standoff=0.5, min_support=0.9, max_support_rms=0.02, min_visible_share=0.2)
    reply = call(node, spec_request)
    assert reply.success and len(reply.regions) == 0
    assert reply.message.startswith("no perch region survived: orientation removed the most")
    # Absurd spec values.
    bad_spec = copy.copy(spec_request)
    bad_spec.spec = copy.copy(spec_request.spec)
    bad_spec.spec.raster_density = 0.0
    reply = call(node, bad_spec)
    assert not reply.success and reply.message.startswith("perch spec: filter configuration: raster_density=0.0")
    # A surface pointing at faces the mesh does not have.
    broken = copy.copy(request)
    broken.surfaces = copy.deepcopy(list(request.surfaces))
    broken.surfaces[2].face_indices.append(999_999)
    reply = call(node, broken)
    assert not reply.success and "face indices" in reply.message and "outside the mesh" in reply.message
    # No target.
    no_target = copy.copy(request)
    no_target.target = TargetVolume()
    reply = call(node, no_target)
    assert not reply.success and "target volume kind DEFAULT" in reply.message
    assert proc.poll() is None
    assert call(node, request).success
