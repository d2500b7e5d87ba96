"""Parameters declared from a config dataclass: defaults, descriptions, overrides."""

from dataclasses import dataclass, field

import pytest

pytestmark = pytest.mark.ros


@dataclass
class Camera:
    width: int = field(default=1280, metadata={"description": "image width", "unit": "px"})


@dataclass
class Config:
    num_cameras: int = field(default=5, metadata={"description": "cameras to place"})
    method: str = "pso"
    camera: Camera = field(default_factory=Camera)


def test_declare_config_defaults_overrides_and_descriptions():
    import rclpy
    from rclpy.parameter import Parameter

    from perch_common.ros.node_main import ros_context
    from perch_common.ros.params import declare_config, read_config
    from perch_common.ros.testing import use_isolated_ros_env

    use_isolated_ros_env()
    with ros_context():
        node = rclpy.create_node("params_test", parameter_overrides=[Parameter("camera.width", value=640)])
        cfg = declare_config(node, Config)
        assert cfg == Config(camera=Camera(width=640))
        descriptor = node.describe_parameter("camera.width")
        assert descriptor.description == "image width [px]"
        assert node.describe_parameter("num_cameras").description == "cameras to place"
        node.set_parameters([Parameter("num_cameras", value=3)])
        assert read_config(node, Config).num_cameras == 3
        node.destroy_node()
