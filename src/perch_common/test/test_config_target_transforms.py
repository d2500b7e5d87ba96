"""Config loading, target volumes and rotations."""

from dataclasses import dataclass, field

import numpy as np
import pytest

from perch_common.config import (
    ConfigError,
    StageNodeConfig,
    from_parameters,
    node_names,
    node_parameters,
    to_parameters,
)
from perch_common.target import TargetVolume
from perch_common.transforms import (
    matrix_from_quaternion,
    parse_up_axis,
    quaternion_from_matrix,
    rotation_between,
)


@dataclass
class Inner:
    width: int = 1280
    fov_deg: float = 87.0


@dataclass
class Outer:
    enabled: bool = True
    name: str = "d435"
    camera: Inner = field(default_factory=Inner)


def test_yaml_sections_merge_wildcard_and_flatten(tmp_path):
    path = tmp_path / "p.yaml"
    path.write_text("/**:\n  ros__parameters:\n    up_axis: '+y'\n    enabled: false\n"
                    "my_node:\n  ros__parameters:\n    enabled: true\n    camera:\n      width: 640\n")
    assert node_names(path) == ["my_node"]
    params = node_parameters("my_node", path)
    assert params == {"up_axis": "+y", "enabled": True, "camera.width": 640}
    cfg = from_parameters(Outer, params)
    assert cfg.enabled is True and cfg.camera.width == 640 and cfg.camera.fov_deg == 87.0
    assert to_parameters(cfg)["camera.width"] == 640


def test_bad_values_and_unknown_keys_are_named():
    with pytest.raises(ConfigError, match=r"camera.width=2.5"):
        from_parameters(Outer, {"camera.width": 2.5})
    with pytest.raises(ConfigError, match="unknown parameter.*camera.height"):
        from_parameters(Outer, {"camera.height": 3}, strict=True)


@dataclass
class OuterNode(Outer, StageNodeConfig[Outer]):
    queue: int = 4


def test_a_stage_node_config_hands_its_stage_the_settings_alone():
    node = from_parameters(OuterNode, {"name": "zed2", "camera.width": 640, "introspection": False, "queue": 9})
    assert (node.introspection, node.queue) == (False, 9)
    stage = node.stage_config()
    assert type(stage) is Outer and stage == Outer(name="zed2", camera=Inner(width=640))
    node_only = {"introspection", "action_server_result_timeout", "work_budget_base", "work_budget_rate",
                 "queue"}   # StageNodeConfig's + its own
    assert set(to_parameters(node)) == set(to_parameters(stage)) | node_only


def test_project_config_parses():
    from perch_common.config import default_config_path, load_yaml
    assert "/**" in load_yaml(default_config_path())


def test_box_target_sampling_is_stratified_and_seeded():
    rot = rotation_between(np.array([1.0, 0, 0]), np.array([1.0, 1.0, 0]))
    box = TargetVolume(center=[1, 1, 1], size=[2, 1, 0.5], rotation=rot)
    pts = box.sample(100, seed=3)
    assert len(pts) == 100 and box.contains(pts).all()
    assert np.array_equal(pts, box.sample(100, seed=3)) and not np.array_equal(pts, box.sample(100, seed=4))
    local = (pts - box.center) @ rot
    # Stratified: each half of the long axis holds half the points (+-10%).
    assert abs((local[:, 0] > 0).mean() - 0.5) < 0.1
    assert box.volume() == pytest.approx(1.0)
    assert len(box.sample(density=1000)) == pytest.approx(1000, rel=0.15)


def test_footprint_target_from_mesh():
    from perch_common.mesh import Mesh
    footprint = Mesh([[0, 0, 0.2], [2, 0, 0.2], [2, 1, 0.2], [0, 1, 0.2]], [[0, 1, 2], [0, 2, 3]])
    target = TargetVolume.from_footprint_mesh(footprint, 1.2)
    assert target.volume() == pytest.approx(2.4) and target.base == pytest.approx(0.2)
    assert np.allclose(target.centroid(), [1, 0.5, 0.8])
    assert target.contains(np.array([[1, 0.5, 1.0], [1, 0.5, 1.5], [3, 0.5, 1.0]])).tolist() == [True, False, False]
    assert len(target.edges()) == 12


def test_rotations():
    r = rotation_between(np.array([0, 0, 1.0]), np.array([0, 0, -1.0]))
    assert np.allclose(r @ [0, 0, 1], [0, 0, -1]) and np.isclose(np.linalg.det(r), 1)
    q = quaternion_from_matrix(rotation_between(np.array([1.0, 0, 0]), np.array([0, 1.0, 0])))
    assert np.allclose(matrix_from_quaternion(q) @ [1, 0, 0], [0, 1, 0])
    assert np.allclose(matrix_from_quaternion(np.zeros(4)), np.eye(3))


def test_up_axis_parsing():
    assert parse_up_axis("+y").tolist() == [0, 1, 0] and parse_up_axis("-z").tolist() == [0, 0, -1]
    assert np.allclose(parse_up_axis("0 0 2"), [0, 0, 1])
    with pytest.raises(ValueError, match="up axis 'sideways'"):
        parse_up_axis("sideways")


def test_optical_pose_looks_at_the_target_level_with_up():
    from perch_common.transforms import optical_pose_looking_at

    pose = optical_pose_looking_at([0.0, 0.0, 1.0], [2.0, 0.0, 1.0])
    np.testing.assert_allclose(pose[:3, 2], [1, 0, 0], atol=1e-12)    # z forward, at the target
    np.testing.assert_allclose(pose[:3, 0], [0, -1, 0], atol=1e-12)   # x right of the view
    np.testing.assert_allclose(pose[:3, 1], [0, 0, -1], atol=1e-12)   # y down
    np.testing.assert_allclose(pose[:3, 3], [0, 0, 1])
    assert np.linalg.det(pose[:3, :3]) == pytest.approx(1.0)
    with pytest.raises(ValueError, match="straight above or below"):
        optical_pose_looking_at([0.0, 0.0, 0.0], [0.0, 0.0, 3.0])


def test_command_overrides_take_ros_and_plain_forms_and_booleans_are_strict():
    """`-p NAME:=VALUE` (ROS's form) and NAME=VALUE both work, values read as YAML; a boolean that is neither
    true nor false is an error (segment took -p use_color:=banana as false)."""
    from perch_common.config import ConfigError, apply_overrides, from_parameters
    from perch_filtering.config import FilterConfig

    params = apply_overrides({}, ["allow_floor:=true", "min_support=0.8"], FilterConfig.__dataclass_fields__,
                             "perch_filtering")
    assert params == {"allow_floor": True, "min_support": 0.8}
    assert from_parameters(FilterConfig, {"allow_floor": "Yes"}).allow_floor is True
    with pytest.raises(ConfigError, match=r"allow_floor='banana': give true or false"):
        from_parameters(FilterConfig, apply_overrides({}, ["allow_floor:=banana"], ["allow_floor"], "perch_filtering"))
    with pytest.raises(ConfigError, match=r"perch_filtering has no parameter 'allow_flor' \(known: allow_floor\)"):
        apply_overrides({}, ["allow_flor:=true"], ["allow_floor"], "perch_filtering")


def test_mesh_outputs_are_checked_before_the_work(tmp_path, capsys):
    """An output named .png or without a suffix ended, after the work, in trimesh's raw exception tuple
    ('%s exporter not available!', 'partial') naming Perch's temporary file."""
    from perch_common.cli import main
    from perch_common.mesh import MeshError, mesh_output

    assert mesh_output(tmp_path / "room.PLY") == tmp_path / "room.PLY" and mesh_output(None) is None
    for name in ("room.png", "room"):
        with pytest.raises(MeshError, match=f"-o {tmp_path / name}: not a mesh format Perch writes; end the name"):
            mesh_output(tmp_path / name)
    with pytest.raises(MeshError, match="is a folder; give a mesh file name"):
        mesh_output(tmp_path)
    for argv, said in ((["-o", str(tmp_path / "scene.png")], "not a mesh format Perch writes"),
                       (["--holes", "-3", "-o", str(tmp_path / "s.ply")], "--holes -3: give 0 or more"),
                       (["--noise", "nan", "-o", str(tmp_path / "s.ply")], "--noise nan: give 0.0 or more")):
        with pytest.raises(SystemExit) as stopped:
            main(["scene", "generate", "--seed", "3", *argv])
        assert stopped.value.code == 1 and said in capsys.readouterr().err, argv
    assert not list(tmp_path.iterdir())
