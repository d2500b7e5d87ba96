"""Installed the ROS way: interfaces listed explicitly, the stand-in tf2_msgs invisible to a workspace
build, a `ros2 run` executable per node, config found in the install space's share directory."""

from __future__ import annotations

import configparser
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def test_perch_interfaces_lists_exactly_its_interface_files():
    text = (ROOT / "src" / "perch_interfaces" / "CMakeLists.txt").read_text()
    assert "GLOB" not in text
    listed = set(re.findall(r"^\s+((?:msg|srv|action)/\w+\.(?:msg|srv|action))\s*$", text, re.M))
    present = {f"{kind}/{p.name}" for kind in ("msg", "srv", "action")
               for p in (ROOT / "src" / "perch_interfaces" / kind).glob(f"*.{kind}")}
    assert listed == present, (f"add to src/perch_interfaces/CMakeLists.txt: {sorted(present - listed)}; "
                               f"listed but missing: {sorted(listed - present)}")


def test_a_workspace_build_never_sees_the_stand_in_tf2_msgs():
    """`colcon build` in a ROS workspace would build src/tf2_msgs over the real tf2_msgs: COLCON_IGNORE
    hides it (make setup builds it from a copy, only when the installation has no tf2_msgs)."""
    assert (ROOT / "src" / "tf2_msgs" / "COLCON_IGNORE").is_file()
    colcon = Path(sys.executable).with_name("colcon")
    if not colcon.is_file():
        pytest.skip("colcon is not installed in this environment")
    # --log-base: colcon would write its log into ./log of the working directory (the project root).
    listed = subprocess.run([str(colcon), "--log-base", os.devnull, "list", "--names-only", "--base-paths",
                             str(ROOT / "src")], capture_output=True, text=True, timeout=120, check=True).stdout.split()
    assert "tf2_msgs" not in listed and "perch_interfaces" in listed and "perch_operator" in listed


def test_every_node_has_a_ros2_run_executable():
    """`ros2 run <package> <node>_node`: a console script per registered node, installed into lib/<package>."""
    for setup in sorted((ROOT / "src").glob("perch_*/setup.cfg")):
        config = configparser.ConfigParser()
        config.read(setup)
        package = setup.parent.name
        points = config["options.entry_points"] if config.has_section("options.entry_points") else {}
        nodes = [line.split("=")[0].strip() for line in points.get("perch.nodes", "").splitlines() if line.strip()]
        scripts = {line.split("=")[0].strip(): line.split("=")[1].strip()
                   for line in points.get("console_scripts", "").splitlines() if "=" in line}
        for node in nodes:
            assert f"{node}_node" in scripts, f"{setup}: no console script {node}_node"
        if nodes:
            assert config["install"]["install_scripts"] == f"$base/lib/{package}", setup


def test_config_is_found_in_the_install_spaces_share_directory(tmp_path, monkeypatch):
    from perch_common.config import installed_config_file

    share = tmp_path / "install" / "share" / "perch_operator" / "config"
    share.mkdir(parents=True)
    (share / "perch.yaml").write_text("perch_placement:\n  ros__parameters:\n    num_cameras: 3\n")
    assert installed_config_file("perch.yaml", [str(tmp_path / "elsewhere"), str(tmp_path / "install")]) == \
        share / "perch.yaml"
    monkeypatch.setenv("AMENT_PREFIX_PATH", str(tmp_path / "install"))
    assert installed_config_file("perch.yaml") == share / "perch.yaml"
    assert installed_config_file("fastdds.xml") is None
    # What the package installs there (its setup.cfg data_files) is the source tree's config.
    config = configparser.ConfigParser()
    config.read(ROOT / "src" / "perch_operator" / "setup.cfg")
    installed = config["options.data_files"]["share/perch_operator/config"]
    assert {"config/perch.yaml", "config/fastdds.xml", "config/fastdds_network.xml"} <= {
        name.strip() for name in installed.split(",")}


def test_the_colcon_install_space_runs_perch_with_its_own_config(tmp_path):
    """`colcon build` of the Python packages into an install space (perch_interfaces from the
    environment): the installed `perch` runs from elsewhere and takes the share directory's config."""
    import os

    colcon = Path(sys.executable).with_name("colcon")
    if not colcon.is_file():
        pytest.skip("colcon is not installed in this environment")
    env = dict(os.environ, AMENT_PREFIX_PATH=sys.prefix, PATH=f"{Path(sys.executable).parent}{os.pathsep}"
               f"{os.environ.get('PATH', '')}")
    env.pop("PERCH_CONFIG", None)
    built = subprocess.run([str(colcon), "--log-base", str(tmp_path / "log"), "build", "--base-paths",
                            str(ROOT / "src"), "--packages-up-to", "perch_operator", "--packages-skip", "perch_interfaces",
                            "--build-base", str(tmp_path / "build"), "--install-base", str(tmp_path / "install"),
                            "--merge-install"], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600)
    assert built.returncode == 0, built.stdout[-3000:] + built.stderr[-3000:]
    install = tmp_path / "install"
    site = next(install.glob("lib/python3*/site-packages"))
    env.update(PYTHONPATH=str(site), AMENT_PREFIX_PATH=f"{install}{os.pathsep}{sys.prefix}")
    listed = subprocess.run([str(install / "lib" / "perch_common" / "perch"), "launch", "--list"], cwd=tmp_path,
                            env=env, capture_output=True, text=True, timeout=120)
    assert listed.returncode == 0, listed.stderr[-2000:]
    config = install / "share" / "perch_operator" / "config" / "perch.yaml"
    assert f"--params-file {config}" in listed.stdout and "perch_placement" in listed.stdout, listed.stdout
    assert (install / "lib" / "perch_operator" / "perch_operator_node").is_file()   # `ros2 run perch_operator ...`
