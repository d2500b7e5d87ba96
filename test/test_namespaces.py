"""Two whole graphs side by side on one domain, each in its own namespace, each running its own mission."""

from __future__ import annotations

import pytest

pytestmark = pytest.mark.ros

NAMESPACES = {"/site_a": 1, "/site_b": 2}  # namespace -> cameras (tells the two missions apart)


def test_launch_command_puts_every_node_in_the_namespace():
    from perch_common.launch import GraphProcesses

    graph = GraphProcesses(nodes=["perch_segmentation"], namespace="site_a")
    command = graph.command("perch_segmentation")
    assert command[command.index("-r") + 1] == "__ns:=/site_a"
    assert "-r" not in GraphProcesses(nodes=["perch_segmentation"], namespace="").command("perch_segmentation")
    with pytest.raises(ValueError, match="namespace '1bad'"):
        GraphProcesses(nodes=["perch_segmentation"], namespace="1bad")


def test_two_namespaced_graphs_run_missions_side_by_side(tmp_path, graph_parts):
    missing = graph_parts.missing
    if missing:
        pytest.skip(f"stage node(s) not installed yet: {', '.join(missing)}")
    from perch_common.ros import testing

    testing.use_isolated_ros_env()
    import rclpy

    from perch_common.launch import GraphProcesses
    from perch_common.ros.conversions import mesh_to_msg, target_to_msg
    from perch_common.scene_generator import generate_scene
    from perch_interfaces.action import PlanPerches
    from perch_operator.cli.runner import offered_services, run_recorded_mission
    from perch_operator.outputs.runfile import channel_counts, iter_messages

    scene = generate_scene(3, "room")
    config = graph_parts.write_config(tmp_path / "perch.yaml")
    rclpy.init()
    graphs = [GraphProcesses(config, list(graph_parts.stage_nodes), log_dir=tmp_path / ns.strip("/"), namespace=ns)
              for ns in NAMESPACES]
    clients = {ns: rclpy.create_node("ns_client", namespace=ns) for ns in NAMESPACES}
    try:
        for graph in graphs:
            graph.start()
        for ns, node in clients.items():
            wanted = [f"{ns}/perch/{name}" for name in ("crop", "clean_mesh", "segment", "filter", "optimise")]
            assert not graphs[0].wait_for_services(node, wanted, timeout=180), f"logs in {tmp_path}"
        # servers only: a client another test of this process left behind names /perch/... too
        offered = offered_services(clients["/site_a"])
        ignored = [n for n in offered if n.startswith("/perch/")]
        assert not ignored, f"a node ignored the namespace: {ignored}"
        for ns, cameras in NAMESPACES.items():
            goal = PlanPerches.Goal(mesh=mesh_to_msg(scene.mesh), target=target_to_msg(scene.target),
                                    num_cameras=cameras, auto_accept=True, seed=-1)
            outputs = run_recorded_mission(clients[ns], goal, tmp_path / f"out{ns}", progress=False, timeout=300)
            assert outputs.result.success, outputs.result.message
            assert len(outputs.result.waypoints) == cameras
            counts = channel_counts(outputs.mcap)
            # Only this graph's topics were recorded, under its namespace, and nothing of the other.
            assert counts[f"{ns}/perch/waypoints"] == cameras
            assert all(topic.startswith(ns + "/") for topic in counts), sorted(counts)
            waypoints = [m for _, m, _ in iter_messages(outputs.mcap, ["/perch/waypoints"])]
            assert len(waypoints) == cameras
    finally:
        for graph in graphs:
            graph.stop()
        for node in clients.values():
            node.destroy_node()
        rclpy.try_shutdown()


def test_launch_file_starts_what_perch_launch_starts():
    import ast
    from importlib.metadata import entry_points
    from pathlib import Path

    import perch_operator
    from perch_common.config import default_config_path, node_names
    from perch_common.launch import graph_nodes

    nodes = graph_nodes(default_config_path())
    assert [n.name for n in nodes] == node_names(default_config_path())
    scripts = {ep.name: ep.value.split(":")[0] for ep in entry_points(group="console_scripts")}
    nodes_by_name = {ep.name: ep.value.split(":")[0] for ep in entry_points(group="perch.nodes")}
    for node in nodes:  # `ros2 launch` runs lib/<package>/<executable>: the same module as `perch launch`
        assert scripts[node.executable] == nodes_by_name[node.name], node
        assert nodes_by_name[node.name].split(".")[0] == node.package
    launch_file = Path(perch_operator.__file__).parents[1] / "launch" / "perch.launch.py"
    tree = ast.parse(launch_file.read_text())
    assert "generate_launch_description" in {f.name for f in tree.body if isinstance(f, ast.FunctionDef)}
    # installed to share/perch_operator/{launch,config} by the package's data_files (setup.cfg)
    import configparser

    setup_cfg = configparser.ConfigParser()
    setup_cfg.read(launch_file.parents[1] / "setup.cfg")
    data_files = setup_cfg["options.data_files"]
    assert "launch/perch.launch.py" in data_files["share/perch_operator/launch"]
    assert "config/perch.yaml" in data_files["share/perch_operator/config"]
    assert (launch_file.parents[1] / "config" / "perch.yaml").resolve() == default_config_path().resolve()


def test_cli_namespace_option_reaches_the_launcher():
    import subprocess
    import sys

    out = subprocess.run([sys.executable, "-m", "perch_common.cli", "--namespace", "site_a", "launch", "--list",
                          "--nodes", "perch_segmentation"], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert "-r __ns:=/site_a" in out.stdout
    bad = subprocess.run([sys.executable, "-m", "perch_common.cli", "--namespace", "9x", "launch", "--list"],
                         capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2 and "namespace '9x'" in bad.stderr
