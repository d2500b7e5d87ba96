"""config/perch.yaml names only parameters its nodes declare: a renamed or removed parameter left in the file
would otherwise be ignored without a word (ROS accepts undeclared keys in a parameter file)."""

import pytest

from perch_common.config import WILDCARD, ConfigError, default_config_path, flatten, from_parameters, load_yaml
from perch_common.mesh_node import MeshToolsConfig
from perch_filtering.config import FilterNodeConfig
from perch_operator.coordinator.config import OperatorConfig
from perch_placement.config import PlacementNodeConfig
from perch_reconstruction.config import ReconstructionNodeConfig
from perch_segmentation.config import SegmentationNodeConfig

NODE_CONFIGS = {
    "perch_reconstruction": ReconstructionNodeConfig,
    "perch_operator": OperatorConfig,
    "perch_segmentation": SegmentationNodeConfig,
    "perch_filtering": FilterNodeConfig,
    "perch_placement": PlacementNodeConfig,
    "perch_mesh_tools": MeshToolsConfig,
}


def _section(data: dict, name: str) -> dict:
    return flatten((data.get(name) or {}).get("ros__parameters") or {})


def test_every_node_section_names_only_declared_parameters():
    data = load_yaml(default_config_path())
    assert sorted(k.lstrip("/") for k in data if k != WILDCARD) == sorted(NODE_CONFIGS)
    for name, cls in NODE_CONFIGS.items():
        from_parameters(cls, _section(data, name), strict=True)  # raises ConfigError naming the stray key


def test_every_wildcard_parameter_is_declared_by_some_node():
    data = load_yaml(default_config_path())
    for key, value in _section(data, WILDCARD).items():
        users = []
        for name, cls in NODE_CONFIGS.items():
            try:
                from_parameters(cls, {key: value}, strict=True)
                users.append(name)
            except ConfigError:
                pass
        assert users, f"/** parameter {key} is declared by no node"


def test_a_stray_key_is_named():
    with pytest.raises(ConfigError, match="clearance_radius"):
        from_parameters(FilterNodeConfig, {"clearance_radius": 0.5}, strict=True)
