"""The perch CLI and the launcher, as a user runs them."""

import subprocess
import sys
from pathlib import Path

import pytest

from perch_common.config import ConfigError
from perch_common.launch import GraphProcesses, available_nodes, parse_overrides

PERCH = [sys.executable, "-m", "perch_common.cli"]


def run(*args, **kw):
    return subprocess.run(PERCH + list(args), capture_output=True, text=True, timeout=120, **kw)


def test_help_lists_core_commands():
    out = run("--help")
    assert out.returncode == 0
    for command in ("mesh", "scene", "launch", "bench"):
        assert command in out.stdout


def _commands(parser) -> set[str]:
    import argparse

    action = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return set(action.choices)


def test_a_named_command_loads_only_its_own_plugin():
    from perch_common.cli import build_parser, command_words

    assert command_words(["--namespace", "site_a", "bench", "up", "--json"]) == ["bench", "up"]
    assert command_words(["--namespace=site_a", "plan", "--mesh", "m.ply"]) == ["plan"]
    assert command_words(["--help", "plan"]) == []
    assert _commands(build_parser(["plan", "--mesh", "m.ply"])) == {"plan"}
    bench = build_parser(["bench", "up", "--json"])
    assert _commands(bench) == {"bench"}
    assert _commands(bench._subparsers._group_actions[0].choices["bench"]) == {"up"}
    # No command, or an unknown one: every command, so that help and the error list them all.
    everything = _commands(build_parser())
    assert {"plan", "mesh", "bench", "launch", "operator"} <= everything
    assert _commands(build_parser(["plam"])) == everything
    out = run("plam")
    assert out.returncode == 2 and "'plan'" in out.stderr and "'mesh'" in out.stderr


def test_scene_generate_writes_mesh_and_labels(tmp_path):
    import numpy as np

    from perch_common.mesh import load_mesh
    out = run("scene", "generate", "--seed", "1", "--kind", "apartment", "-o", str(tmp_path / "room.ply"))
    assert out.returncode == 0, out.stderr
    mesh = load_mesh(tmp_path / "room.ply")
    labels = np.load(tmp_path / "room.labels.npz")
    assert len(labels["face_plane"]) == mesh.num_faces and mesh.vertex_colors is not None


def test_mesh_info_reports_and_fails_clearly(tmp_path):
    from perch_common.mesh import Mesh, save_mesh
    save_mesh(tmp_path / "tri.ply", Mesh([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]]))
    out = run("mesh", "info", str(tmp_path / "tri.ply"))
    assert out.returncode == 0 and "1 faces" in out.stdout
    out = run("mesh", "info", str(tmp_path / "nope.ply"))
    assert out.returncode == 1 and "perch: error:" in out.stderr and "no such file" in out.stderr
    assert "Traceback" not in out.stderr


def test_overrides_parse():
    assert parse_overrides(["perch_placement:num_cameras:=3", "up_axis:=+y"]) == {
        "perch_placement": ["num_cameras:=3"], "*": ["up_axis:=+y"]}
    with pytest.raises(ConfigError, match="node:param:=value"):
        parse_overrides(["num_cameras=3"])


def test_launch_lists_installed_listed_nodes(tmp_path):
    config = tmp_path / "p.yaml"
    config.write_text("/**:\n  ros__parameters:\n    up_axis: '+z'\n"
                      "perch_mesh_tools:\n  ros__parameters: {}\nnot_installed_node:\n  ros__parameters: {}\n")
    assert "perch_mesh_tools" in available_nodes()
    graph = GraphProcesses(config, overrides=["perch_mesh_tools:service_name:=/x"])
    assert graph.nodes == ["perch_mesh_tools"]
    assert graph.command("perch_mesh_tools")[-2:] == ["-p", "perch_mesh_tools:service_name:=/x"]
    with pytest.raises(ConfigError, match="unknown node"):
        GraphProcesses(config, nodes=["nope"])


def test_launch_nodes_that_name_no_node_are_refused(capsys):
    """Hunt 6: `--nodes ",,"` said `unknown node(s) , , `."""
    from perch_common.cli import main

    with pytest.raises(SystemExit) as exited:
        main(["launch", "--nodes", ",,"])
    assert exited.value.code == 1
    assert "--nodes ',,' names no node; give them comma-separated" in capsys.readouterr().err


def test_the_coordinator_runs_on_glibc_malloc_unless_the_user_chose_an_allocator():
    import os

    base = {k: v for k, v in os.environ.items() if k != "PYTHONMALLOC"}
    graph = GraphProcesses(nodes=["perch_operator", "perch_segmentation"], env=base)
    assert graph.node_environment("perch_operator")["PYTHONMALLOC"] == "malloc"
    assert "PYTHONMALLOC" not in graph.node_environment("perch_segmentation")
    chosen = GraphProcesses(nodes=["perch_operator"], env={**base, "PYTHONMALLOC": "pymalloc"})
    assert chosen.node_environment("perch_operator")["PYTHONMALLOC"] == "pymalloc"


@pytest.mark.ros
def test_launch_starts_and_stops_cleanly_on_ctrl_c(tmp_path):
    import signal

    from perch_common.ros.testing import isolated_ros_env, poll_until
    config = tmp_path / "p.yaml"
    config.write_text("perch_mesh_tools:\n  ros__parameters:\n    service_name: /perch/inspect_mesh\n")
    proc = subprocess.Popen(PERCH + ["launch", "--config", str(config), "--log-dir", str(tmp_path / "logs")],
                            env=isolated_ros_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    log = tmp_path / "logs" / "perch_mesh_tools.log"
    try:   # Ctrl-C once the node serves (a loaded machine starts it later than a fixed wait would allow)
        poll_until(lambda: proc.poll() is not None or (log.is_file() and "serving" in log.read_text(errors="replace")),
                   120, "perch_mesh_tools serving (or perch launch ending)")
    except AssertionError:
        proc.kill()
        raise
    assert proc.poll() is None, proc.communicate()[1][-2000:]
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=20)
    assert proc.returncode == 0, err
    assert "starting perch_mesh_tools" in out and "stopped" in out
    assert "serving /perch/inspect_mesh" in (Path(tmp_path / "logs" / "perch_mesh_tools.log").read_text())


def test_a_negative_up_axis_is_taken_as_written():
    """`--up -y` (as Perch's own hints write it) is the axis, not an unknown option."""
    from perch_common.cli import build_parser, glued_axis_values

    argv = glued_axis_values(["plan", "--mesh", "room.ply", "--up", "-y", "--cameras", "2", "-o", "out"])
    assert argv == ["plan", "--mesh", "room.ply", "--up=-y", "--cameras", "2", "-o", "out"]
    assert build_parser(argv).parse_args(argv).up == "-y"
    # Anything else after --up is left to argparse as before.
    assert glued_axis_values(["plan", "--up", "+z", "--up", "-0.1 0 1"]) == ["plan", "--up", "+z", "--up", "-0.1 0 1"]
    out = run("plan", "--up", "-y")   # argparse's complaint is about the missing mesh now, not about --up
    assert out.returncode == 2 and "--up" not in out.stderr.splitlines()[-1], out.stderr
