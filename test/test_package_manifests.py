"""Every package.xml declares what its Python code imports, with rosdep keys that exist (or a PyPI note)."""

from __future__ import annotations

import ast
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PYTHON_PACKAGES = ("perch_common", "perch_reconstruction", "perch_segmentation", "perch_filtering",
                   "perch_placement", "perch_operator", "perch_console")
# Third-party module -> its rosdep key, each found in ros/rosdistro's rosdep/python.yaml (the -pip
# keys install from PyPI); None: no key exists, the module comes from requirements.in only.
ROSDEP_KEYS = {"numpy": "python3-numpy", "scipy": "python3-scipy", "shapely": "python3-shapely",
               "yaml": "python3-yaml", "psutil": "python3-psutil", "cv2": "python3-opencv",
               "trimesh": "python3-trimesh-pip", "open3d": "python3-open3d-pip",
               "mapbox_earcut": "python3-mapbox-earcut-pip", "rosbags": "python3-rosbags-pip",
               "mcap": "mcap-ros2-support", "mcap_ros2": "mcap-ros2-support", "fast_simplification": None, "rerun": None,
               "embreex": None,
               "threadpoolctl": None, "viser": None, "playwright": None}
PYPI_NAMES = {"fast_simplification": "fast-simplification", "rerun": "rerun-sdk", "threadpoolctl": "threadpoolctl",
              "embreex": "embreex", "viser": "viser", "playwright": "playwright"}
# ROS packages imported under their own name (resolved by rosdep from the Jazzy distribution).
ROS_PACKAGES = {"rclpy", "rcl_interfaces", "std_msgs", "std_srvs", "geometry_msgs", "sensor_msgs", "nav_msgs",
                "visualization_msgs", "tf2_msgs", "service_msgs", "action_msgs", "unique_identifier_msgs",
                "builtin_interfaces", "ament_index_python", "launch", "launch_ros"}


def declared(package: str) -> set[str]:
    """The exec_depend / depend keys of a package.xml."""
    root = ET.parse(ROOT / "src" / package / "package.xml").getroot()
    return {e.text.strip() for e in root if e.tag in ("exec_depend", "depend") and e.text}


def imported(package: str) -> set[str]:
    """Top-level modules imported anywhere in the package's code (tests excluded) and its launch files."""
    files = list((ROOT / "src" / package / package).rglob("*.py")) + list((ROOT / "src" / package).glob("launch/*.py"))
    names: set[str] = set()
    for path in files:
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                names.update(alias.name.split(".")[0] for alias in node.names)
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                names.add(node.module.split(".")[0])
    return names


@pytest.mark.parametrize("package", PYTHON_PACKAGES)
def test_package_xml_declares_every_import(package):
    deps = declared(package)
    missing = []
    for module in sorted(imported(package)):
        if module in ROS_PACKAGES or (module.startswith("perch_") and module != package):
            if module not in deps:
                missing.append(module)
        elif module in ROSDEP_KEYS and ROSDEP_KEYS[module] is not None and ROSDEP_KEYS[module] not in deps:
            missing.append(f"{ROSDEP_KEYS[module]} (for {module})")
    assert not missing, f"src/{package}/package.xml lacks <exec_depend> for: {', '.join(missing)}"


def test_modules_without_a_rosdep_key_come_from_requirements():
    requirements = {line.split("#")[0].strip().lower() for line in (ROOT / "requirements.in").read_text().splitlines()}
    for module, key in ROSDEP_KEYS.items():
        if key is None:
            assert PYPI_NAMES[module] in requirements, module
    keys = {k for p in PYTHON_PACKAGES for k in declared(p)}
    # keys rosdep cannot resolve (the findings) are gone
    assert not keys & {"python3-mcap-pip", "python3-pymeshlab-pip", "python3-open3d"}


def test_interfaces_declare_what_their_definitions_use():
    deps = declared("perch_interfaces")
    assert {"std_msgs", "geometry_msgs", "unique_identifier_msgs", "action_msgs", "service_msgs"} <= deps
