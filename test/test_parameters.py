"""One parameter convention for every node: ranges and choices in the descriptors, bad values
refused with a reason while running, a bad start-up value stops the node with one line."""

import dataclasses
import subprocess
import sys

import pytest

from perch_common.config import ConfigError, field_specs, from_parameters, node_parameters, to_parameters

NODE_CONFIGS = {
    "perch_reconstruction": ("perch_reconstruction.config", "ReconstructionNodeConfig"),
    "perch_segmentation": ("perch_segmentation.config", "SegmentationNodeConfig"),
    "perch_filtering": ("perch_filtering.config", "FilterNodeConfig"),
    "perch_placement": ("perch_placement.config", "PlacementNodeConfig"),
    "perch_operator": ("perch_operator.coordinator.config", "OperatorConfig"),
}


def node_config(node: str) -> type:
    import importlib

    module, name = NODE_CONFIGS[node]
    return getattr(importlib.import_module(module), name)


@pytest.mark.parametrize("node", sorted(NODE_CONFIGS))
def test_defaults_and_the_shipped_parameter_file_pass_their_own_checks(node):
    cls = node_config(node)
    defaults = cls()
    assert from_parameters(cls, to_parameters(defaults)) == defaults  # every default inside its range
    shipped = from_parameters(cls, node_parameters(node))  # config/perch.yaml inside the ranges
    shipped.validate()
    specs = field_specs(cls)
    described = [name for name, spec in specs.items() if spec.get("description")]
    assert described == list(specs), f"{node}: parameters without a description"


def test_ranges_and_choices_are_checked_outside_ros_too():
    """(Issue 13 named clearance_radius; the filter's clearance is now the approach prism, approach_distance.)"""
    from perch_filtering.config import FilterConfig
    from perch_placement.config import PlacementConfig

    with pytest.raises(ConfigError, match=r"num_cameras=-3: must be in \[0, 100\]"):
        from_parameters(PlacementConfig, {"num_cameras": -3})
    with pytest.raises(ConfigError, match="method='no_such_method': use one of 'pso', 'celf'"):
        from_parameters(PlacementConfig, {"method": "no_such_method"})
    with pytest.raises(ConfigError, match=r"approach_distance=-1.0: must be in \[0, 10\]"):
        from_parameters(FilterConfig, {"approach_distance": -1.0})
    assert from_parameters(PlacementConfig, {"num_cameras": 3, "method": "celf"}).method == "celf"


def _set(node, name, value):
    from rclpy.parameter import Parameter

    return node.set_parameters([Parameter(name, value=value)])[0]


@pytest.mark.ros
def test_running_nodes_refuse_bad_values_with_a_reason_and_keep_the_old_one():
    from perch_common.ros.node_main import ros_context
    from perch_common.ros.testing import use_isolated_ros_env
    from perch_filtering.node import FilterNode
    from perch_operator.coordinator.node import OperatorNode
    from perch_placement.node import PlacementNode

    use_isolated_ros_env()
    with ros_context():
        placement, filtering, operator = PlacementNode(), FilterNode(), OperatorNode()
        try:
            descriptor = placement.describe_parameter("num_cameras")
            assert [(r.from_value, r.to_value) for r in descriptor.integer_range] == [(0, 100)]
            assert "one of: 'pso', 'celf'" in placement.describe_parameter("method").additional_constraints
            radius = filtering.describe_parameter("approach_distance").floating_point_range
            assert [(r.from_value, r.to_value) for r in radius] == [(0.0, 10.0)]

            bad_method = _set(placement, "method", "no_such_method")
            assert not bad_method.successful and "use one of 'pso', 'celf', 'random', 'grid', 'naive'" in bad_method.reason
            negative = _set(placement, "num_cameras", -3)
            assert not negative.successful and "out of range" in negative.reason
            # In range, but the whole configuration is unusable: the camera would see nothing.
            blind = _set(placement, "camera.min_range", 9.0)
            assert not blind.successful and "range [9.0, 3.247] m is empty" in blind.reason
            radius = _set(filtering, "approach_distance", -1.0)
            assert not radius.successful and "out of range" in radius.reason
            # standoff must stay >= drone_radius (0.35 m): a check across fields
            standoff = _set(filtering, "standoff", 0.1)
            assert not standoff.successful and "standoff=0.1 m must be at least drone_radius" in standoff.reason
            up = _set(operator, "up_axis", "sideways")
            assert not up.successful and "up axis 'sideways'" in up.reason

            assert placement.get_parameter("method").value == "pso"
            assert placement.get_parameter("num_cameras").value == 5
            assert filtering.get_parameter("approach_distance").value == 0.5
            assert _set(placement, "num_cameras", 3).successful
            assert placement.get_parameter("num_cameras").value == 3
        finally:
            for node in (placement, filtering, operator):
                node.destroy_node()


@pytest.mark.ros
@pytest.mark.parametrize("module, override, expected", [
    ("perch_placement.node", "num_cameras:=-3", "perch_placement: parameter num_cameras=-3: must be in [0, 100]"),
    ("perch_placement.node", "method:=no_such_method",
     "perch_placement: parameter method='no_such_method': use one of 'pso', 'celf', 'random', 'grid', 'naive'"),
    ("perch_filtering.node", "approach_distance:=-1.0",
     "perch_filtering: parameter approach_distance=-1.0: must be in [0, 10]"),
    ("perch_segmentation.node", "theta_max_deg:=90.0",
     "perch_segmentation: theta_max_deg=90.0 must be in (0, 90)"),
])
def test_a_bad_start_up_value_stops_the_node_with_one_line(module, override, expected):
    from perch_common.ros.testing import isolated_ros_env

    done = subprocess.run([sys.executable, "-m", module, "--ros-args", "-p", override], env=isolated_ros_env(),
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 2
    lines = [line for line in done.stderr.splitlines() if line.strip()]
    assert lines == [f"error: {expected}"], done.stderr


def test_node_only_parameters_extend_the_core_configs():
    """Each stage's node config adds its own parameters to the core config, never redefines them."""
    from perch_filtering.config import FilterConfig
    from perch_placement.config import PlacementConfig
    from perch_reconstruction.config import ReconstructionConfig
    from perch_segmentation.config import SegmentationConfig

    for node, core in (("perch_filtering", FilterConfig), ("perch_placement", PlacementConfig),
                       ("perch_reconstruction", ReconstructionConfig), ("perch_segmentation", SegmentationConfig)):
        cls = node_config(node)
        assert issubclass(cls, core)
        extra = {f.name for f in dataclasses.fields(cls)} - {f.name for f in dataclasses.fields(core)}
        assert "introspection" in extra or node == "perch_reconstruction"
