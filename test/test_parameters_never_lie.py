"""Parameters that never lie: -p checked before anything starts, start-up-only parameters read-only,
a node that refuses its parameters not restarted, parameter files read as rcl reads them."""

from __future__ import annotations

import subprocess
import sys
import time

import pytest

from perch_common.config import ConfigError, check_overrides, node_names, node_parameters
from perch_common.launch import parse_overrides

MISSION_NODES = ["perch_operator", "perch_reconstruction", "perch_segmentation", "perch_filtering", "perch_placement"]
PERCH = [sys.executable, "-m", "perch_common.cli"]


def _check(*overrides: str) -> dict:
    return check_overrides(parse_overrides(list(overrides)), MISSION_NODES)


@pytest.mark.parametrize("override, expected", [
    ("perch_placement:num_cameras:=-3", r"perch_placement:num_cameras=-3: must be in \[0, 100\]"),
    ("perch_placement:occlusion_epsilon:=abc", r"occlusion_epsilon:=abc: expects a float \(double\), got str 'abc'"),
    ("perch_placement:num_cameras:=2.5", r"num_cameras:=2.5: expects an integer, got float 2.5"),
    ("perch_reconstruction:gravity_align:=maybe", r"gravity_align:=maybe: expects a bool"),
    ("perch_nowhere:num_cameras:=3", r"no node 'perch_nowhere' in this graph; its nodes: perch_operator, "
                                     r"perch_reconstruction"),
    ("perch_placement:num_camera:=3", r"node perch_placement declares no parameter 'num_camera'; did you mean "
                                      r"num_cameras.*its parameters: .*method, num_cameras"),
    ("no_such_parameter:=3", r"no node declares a parameter 'no_such_parameter'"),
    ("perch_operator:up_axis:=sideways", r"perch_operator: up axis 'sideways'"),   # the node's own validation
    ("perch_reconstruction:depth_min:=9.0", r"need 0 <= depth_min < depth_max"),   # against the file's depth_max
])
def test_bad_overrides_are_refused_before_anything_starts(override, expected):
    with pytest.raises(ConfigError, match=expected):
        _check(override)


def test_an_integer_for_a_float_is_taken_as_that_float_and_good_overrides_pass_unchanged():
    assert _check("perch_operator:stage_timeout:=60") == {"perch_operator": ["stage_timeout:=60.0"]}
    assert _check("perch_placement:num_cameras:=3", "perch_placement:method:=celf") == {
        "perch_placement": ["num_cameras:=3", "method:=celf"]}
    assert _check("perch_reconstruction:gravity:=[0, 0, -9]") == {"perch_reconstruction": ["gravity:=[0.0, 0.0, -9.0]"]}
    assert _check("seed:=4") == {"*": ["seed:=4"]}   # every node declaring `seed`


PARAMS_FILE = """\
/**:
  ros__parameters:
    seed: 5
perch_placement:
  ros__parameters:
    num_cameras: 4
/site_a/perch_placement:
  ros__parameters:
    num_cameras: 7
    camera:
      width: 320
/**/perch_segmentation:
  ros__parameters:
    seed: 9
/site_a/*:
  ros__parameters:
    introspection: false
"""


def test_namespaced_and_wildcard_keys_resolve_as_rcl_resolves_them(tmp_path):
    """What node_parameters reads equals what a real node gets from rcl for the same file."""
    import rclpy
    from rclpy.context import Context

    path = tmp_path / "site.yaml"
    path.write_text(PARAMS_FILE)
    assert node_names(path) == ["perch_placement", "perch_segmentation"]
    ours = {(ns, name): node_parameters(name, path, namespace=ns)
            for ns in ("", "/site_a") for name in ("perch_placement", "perch_segmentation")}
    assert ours[("/site_a", "perch_placement")] == {"seed": 5, "num_cameras": 7, "camera.width": 320,
                                                    "introspection": False}
    assert ours[("", "perch_placement")] == {"seed": 5, "num_cameras": 4}
    assert ours[("/site_a", "perch_segmentation")] == {"seed": 9, "introspection": False}
    assert ours[("", "perch_segmentation")] == {"seed": 9}
    for (ns, name), expected in ours.items():
        context = Context()
        args = ["--ros-args", "--params-file", str(path)] + (["-r", f"__ns:={ns}"] if ns else [])
        rclpy.init(args=args, context=context)
        try:
            node = rclpy.create_node(name, context=context, start_parameter_services=False,
                                     automatically_declare_parameters_from_overrides=True)
            given = {p: node.get_parameter(p).value for p in node._parameter_overrides}
            node.destroy_node()
        finally:
            rclpy.try_shutdown(context=context)
        assert given == expected, (ns, name)


def test_an_integer_in_a_parameter_file_is_taken_for_a_float(tmp_path):
    import rclpy
    from rclpy.context import Context

    from perch_common.ros.params import declare_config
    from perch_operator.coordinator.config import OperatorConfig

    path = tmp_path / "op.yaml"
    path.write_text("perch_operator:\n  ros__parameters:\n    stage_timeout: 60\n    confirm_timeout: 30\n")
    context = Context()
    rclpy.init(args=["--ros-args", "--params-file", str(path)], context=context)
    try:
        node = rclpy.create_node("perch_operator", context=context, start_parameter_services=False)
        config = declare_config(node, OperatorConfig, check=OperatorConfig.validate)
        assert config.stage_timeout == 60.0 and isinstance(config.stage_timeout, float)
        assert config.confirm_timeout == 30.0
        node.destroy_node()
    finally:
        rclpy.try_shutdown(context=context)


@pytest.mark.parametrize("module, cls, read_only, live", [
    ("perch_operator.coordinator.config", "OperatorConfig", ["stage_timeout", "service_wait", "gone_grace", "introspection"],
     ("exclusion_radius", 0.5)),
    ("perch_reconstruction.config", "ReconstructionNodeConfig",
     ["color_topic", "depth_topic", "camera_info_topic", "pose_topic", "pose_type", "compressed_images",
      "lossless_replay", "progress_period", "introspection"], ("voxel_size", 0.03)),
    ("perch_placement.config", "PlacementNodeConfig", ["scene_cache_faces", "introspection"], ("num_cameras", 3)),
])
def test_start_up_only_parameters_are_read_only_and_a_change_to_them_is_refused(module, cls, read_only, live):
    """`ros2 param set` of a start-up-only parameter fails ("read-only") instead of succeeding and
    changing nothing; the parameters the node reads per call still change."""
    import importlib

    import rclpy
    from rclpy.context import Context
    from rclpy.parameter import Parameter

    from perch_common.ros.params import declare_config

    config_class = getattr(importlib.import_module(module), cls)
    context = Context()
    rclpy.init(args=[], context=context)
    try:
        node = rclpy.create_node("params_probe", context=context, start_parameter_services=False)
        declare_config(node, config_class)
        flagged = [d.name for d in node.describe_parameters(list(node._parameters)) if d.read_only]
        assert set(read_only) <= set(flagged), flagged
        for name in read_only:
            current = node.get_parameter(name).value
            [result] = node.set_parameters([Parameter(name, value=current)])
            assert not result.successful and "read-only" in result.reason, (name, result)
        [changed] = node.set_parameters([Parameter(live[0], value=live[1])])
        assert changed.successful and node.get_parameter(live[0]).value == live[1]
        node.destroy_node()
    finally:
        rclpy.try_shutdown(context=context)


def _isolated_env():
    from perch_common.ros.testing import isolated_ros_env

    return isolated_ros_env()


def test_perch_plan_refuses_a_bad_override_and_an_override_with_no_launch(tmp_path):
    env = _isolated_env()
    plan = PERCH + ["plan", "--scene", "3", "--kind", "room", "--auto-accept", "--quiet"]
    bad = subprocess.run(plan + ["-o", str(tmp_path / "a"), "-p", "perch_placement:occlusion_epsilon:=abc"],
                         env=env, capture_output=True, text=True, timeout=120)
    assert bad.returncode == 1 and "occlusion_epsilon:=abc: expects a float" in bad.stderr, bad.stderr[-2000:]
    assert not (tmp_path / "a" / "logs").exists()   # refused before any node started
    refused = subprocess.run(plan + ["-o", str(tmp_path / "b"), "--no-launch", "-p", "perch_placement:num_cameras:=3"],
                             env=env, capture_output=True, text=True, timeout=120)
    assert refused.returncode == 1 and "-p with --no-launch" in refused.stderr, refused.stderr[-2000:]
    print("perch plan -p perch_placement:occlusion_epsilon:=abc ->", bad.stderr.strip().splitlines()[-1])
    print("perch plan --no-launch -p ... ->", refused.stderr.strip().splitlines()[-1])


@pytest.mark.ros
def test_perch_launch_refuses_a_bad_override_and_stops_when_a_node_refuses_its_file(tmp_path):
    env = _isolated_env()
    bad = subprocess.run(PERCH + ["launch", "--nodes", "perch_placement", "-p", "perch_placement:num_cameras:=-3"],
                         env=env, capture_output=True, text=True, timeout=120)
    assert bad.returncode == 1 and "num_cameras=-3: must be in [0, 100]" in bad.stderr, bad.stderr[-2000:]
    assert "starting" not in bad.stdout
    # A bad value in the parameter file itself: the node exits (code 2) and is not restarted.
    config = tmp_path / "bad.yaml"
    config.write_text("perch_placement:\n  ros__parameters:\n    num_cameras: -3\n")
    started = time.monotonic()
    proc = subprocess.run(PERCH + ["launch", "--config", str(config), "--nodes", "perch_placement",
                                   "--log-dir", str(tmp_path / "logs")],
                          env=env, capture_output=True, text=True, timeout=180)
    assert proc.returncode == 1, proc.stderr[-2000:]
    assert "perch_placement refused its parameters (exit code 2: perch_placement: parameter num_cameras=-3: " \
           "must be in [0, 100]); not restarting it" in proc.stderr, proc.stderr[-2000:]
    assert "restarting it in" not in proc.stderr
    print(f"perch launch with num_cameras: -3 in its file stopped after {time.monotonic() - started:.1f} s:",
          proc.stderr.strip().splitlines()[-1])
