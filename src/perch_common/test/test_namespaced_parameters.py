"""Parameters reach nodes in a namespace: rcl matches a bare `NAME:` file key and `-p NAME:p:=v` to /NAME only."""

from __future__ import annotations

import rclpy
from rclpy.context import Context

from perch_common.launch import ros_arguments


def _value(args: list[str], default: int) -> int:
    context = Context()
    rclpy.init(args=["test", *args], context=context)
    try:
        node = rclpy.create_node("perch_placement", context=context)
        value = node.declare_parameter("num_cameras", default).value
        node.destroy_node()
        return value
    finally:
        rclpy.shutdown(context=context)


def test_file_and_overrides_apply_in_a_namespace_and_at_the_root(tmp_path):
    config = tmp_path / "p.yaml"
    config.write_text("perch_placement:\n  ros__parameters:\n    num_cameras: 7\n")
    assert _value(ros_arguments(config, ["perch_placement"], {}, "/site_a"), 1) == 7
    assert _value(ros_arguments(config, ["perch_placement"], {"perch_placement": ["num_cameras:=3"]}, "/site_a"), 1) == 3
    assert _value(ros_arguments(config, ["perch_placement"], {"*": ["num_cameras:=4"]}, "/a/b"), 1) == 4
    assert _value(ros_arguments(config, ["perch_placement"], {"perch_placement": ["num_cameras:=3"]}, ""), 1) == 3
    assert _value(ros_arguments(config, ["perch_placement"], {}, ""), 1) == 7


def test_what_rcl_does_without_the_rewrite(tmp_path):
    """Why the rewrite exists: the same file and -p, given as they are, do not reach /site_a/perch_placement."""
    config = tmp_path / "p.yaml"
    config.write_text("perch_placement:\n  ros__parameters:\n    num_cameras: 7\n")
    plain = ["--ros-args", "--params-file", str(config), "-r", "__ns:=/site_a", "-p", "perch_placement:num_cameras:=3"]
    assert _value(plain, 1) == 1
