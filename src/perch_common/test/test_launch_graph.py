"""The launcher: respawn with back-off, graph modes, local-only sockets, free domains."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from perch_common.config import ConfigError
from perch_common.launch import (
    CONTAINER,
    GraphProcesses,
    Respawn,
    dds_profile,
    domain_ports,
    use_perch_dds,
)

PERCH = [sys.executable, "-m", "perch_common.cli"]
MESH_TOOLS_CONFIG = "perch_mesh_tools:\n  ros__parameters:\n    service_name: /perch/inspect_mesh\n"


def test_respawn_backs_off_and_resets_after_a_stable_run():
    policy = Respawn(first=1.0, longest=8.0, stable=60.0)
    delays = [policy.next_delay("seg", ran_for=2.0) for _ in range(6)]
    assert delays == [1.0, 2.0, 4.0, 8.0, 8.0, 8.0]
    assert policy.next_delay("seg", ran_for=120.0) == 1.0   # it ran long enough: start over
    assert policy.next_delay("other", ran_for=0.5) == 1.0   # per node


def test_domain_ports_follow_the_rtps_port_mapping():
    assert domain_ports(0)[0] == 7400 and domain_ports(1)[0] == 7650 and len(domain_ports(5)) == 250


@pytest.mark.ros
def test_a_running_participant_marks_its_domain_in_use_and_a_free_one_is_found(tmp_path):
    from perch_common.launch import domains_in_use, free_domain
    from perch_common.ros.testing import isolated_ros_env

    config = tmp_path / "p.yaml"
    config.write_text(MESH_TOOLS_CONFIG)
    env = isolated_ros_env()
    domain = int(env["ROS_DOMAIN_ID"])
    graph = GraphProcesses(config, ["perch_mesh_tools"], log_dir=tmp_path / "logs", env=env)
    with graph:
        _wait_for_log(tmp_path / "logs" / "perch_mesh_tools.log", "serving /perch/inspect_mesh")
        assert domain in domains_in_use()
        other = free_domain()
        assert other is not None and other != domain and other not in domains_in_use()


def test_local_profile_whitelists_loopback_and_network_opens_it(tmp_path):
    local = use_perch_dds({}, network=False)
    assert local["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "SYSTEM_DEFAULT"   # LOCALHOST would replace the transports
    assert local["FASTRTPS_DEFAULT_PROFILES_FILE"] == str(dds_profile(False))
    text = dds_profile(False).read_text()
    assert "<interfaceWhiteList>" in text and "<address>127.0.0.1</address>" in text
    assert "<useBuiltinTransports>false</useBuiltinTransports>" in text
    # Sample buffers are freed with their samples: rmw_fastrtps applies the profile's memory policy.
    assert local["RMW_FASTRTPS_USE_QOS_FROM_XML"] == "1" and "<historyMemoryPolicy>DYNAMIC<" in text
    opened = use_perch_dds({"PERCH_NETWORK": "1", "PERCH_KEY_FILE": str(tmp_path / "network.key")})
    assert opened["FASTRTPS_DEFAULT_PROFILES_FILE"] == str(dds_profile(True))
    assert "ROS_AUTOMATIC_DISCOVERY_RANGE" not in opened
    assert "interfaceWhiteList" not in dds_profile(True).read_text()
    assert opened["RMW_FASTRTPS_USE_QOS_FROM_XML"] == "1" and "<historyMemoryPolicy>DYNAMIC<" in dds_profile(True).read_text()
    # A networked graph signs its commands: a key it cannot use is refused before anything starts (hunt 6:
    # the graph started and every mission failed with an empty reason).
    shared = tmp_path / "shared.key"
    shared.write_bytes(bytes(32))
    shared.chmod(0o644)
    with pytest.raises(ConfigError, match=r"^--network needs the graph's key: .*shared\.key: the network key is "
                                          r"readable by other users \(mode 644\); `chmod 600 "):
        use_perch_dds({"PERCH_NETWORK": "1", "PERCH_KEY_FILE": str(shared)})
    kept = use_perch_dds({"FASTRTPS_DEFAULT_PROFILES_FILE": "/mine.xml"})
    assert kept["FASTRTPS_DEFAULT_PROFILES_FILE"] == "/mine.xml" and kept["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "LOCALHOST"
    assert "RMW_FASTRTPS_USE_QOS_FROM_XML" not in kept   # a user's own profile: rmw_fastrtps's defaults stay


def test_one_process_mode_runs_one_container_with_every_node(tmp_path):
    config = tmp_path / "p.yaml"
    config.write_text(MESH_TOOLS_CONFIG)
    graph = GraphProcesses(config, overrides=["perch_mesh_tools:service_name:=/x"], mode="one-process")
    assert graph.units == [CONTAINER]
    command = graph.command(CONTAINER)
    assert command[1:5] == ["-m", "perch_common.ros.container", "--nodes", "perch_mesh_tools"]
    assert command[-2:] == ["-p", "perch_mesh_tools:service_name:=/x"]


def _udp_addresses(pid: int) -> set[str]:
    import psutil

    proc = psutil.Process(pid)
    return {c.laddr.ip for c in proc.net_connections(kind="udp") if c.laddr}


def _shared_memory_ports(pid: int) -> set[str]:
    """The Fast DDS shared-memory transport's port segments the process maps (/dev/shm/fastrtps_port*)."""
    maps = Path(f"/proc/{pid}/maps").read_text()
    return {line.split()[-1] for line in maps.splitlines() if "/dev/shm/fastrtps_port" in line}


def _wait_for_log(path: Path, text: str, timeout: float = 60.0) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if path.is_file() and text in path.read_text(errors="replace"):
            return
        time.sleep(0.2)
    raise TimeoutError(f"'{text}' not in {path} within {timeout:.0f} s")


@pytest.mark.ros
@pytest.mark.parametrize("network", [False, True])
def test_nodes_bind_loopback_only_unless_the_network_is_opened(tmp_path, network):
    from perch_common.ros.testing import isolated_ros_env

    config = tmp_path / "p.yaml"
    config.write_text(MESH_TOOLS_CONFIG)
    env = isolated_ros_env()
    env.pop("FASTRTPS_DEFAULT_PROFILES_FILE", None)
    env.pop("ROS_AUTOMATIC_DISCOVERY_RANGE", None)
    graph = GraphProcesses(config, ["perch_mesh_tools"], log_dir=tmp_path / "logs", env=env, network=network)
    with graph:
        _wait_for_log(tmp_path / "logs" / "perch_mesh_tools.log", "serving /perch/inspect_mesh")
        time.sleep(1.0)
        addresses = _udp_addresses(graph.processes["perch_mesh_tools"].pid)
        ports = _shared_memory_ports(graph.processes["perch_mesh_tools"].pid)
    assert addresses, "the node bound no UDP socket at all"
    # No shared-memory transport in either profile (config/fastdds.xml says why): no port segment mapped.
    assert not ports, f"the node mapped Fast DDS shared-memory ports {ports}"
    # 239.255.0.1 is the SPDP multicast group; the whitelist joins it on loopback only.
    external = {a for a in addresses if not a.startswith("127.") and not a.startswith("239.")}
    if network:
        assert external, f"--network: expected sockets on every interface, got {addresses}"
    else:
        assert not external, f"local graph bound non-loopback addresses {external} (all: {addresses})"


@pytest.mark.ros
@pytest.mark.parametrize("respawn", [True, False])
def test_launch_restarts_a_killed_node_unless_no_respawn(tmp_path, respawn):
    import psutil

    from perch_common.ros.testing import isolated_ros_env

    config = tmp_path / "p.yaml"
    config.write_text(MESH_TOOLS_CONFIG)
    logs = tmp_path / "logs"
    command = PERCH + ["launch", "--config", str(config), "--log-dir", str(logs)] + ([] if respawn else ["--no-respawn"])
    proc = subprocess.Popen(command, env=isolated_ros_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        _wait_for_log(logs / "perch_mesh_tools.log", "serving /perch/inspect_mesh")
        (child,) = psutil.Process(proc.pid).children()
        child.kill()
        if respawn:
            deadline = time.monotonic() + 30
            while time.monotonic() < deadline:
                children = [c for c in psutil.Process(proc.pid).children() if c.pid != child.pid]
                if children:
                    break
                time.sleep(0.2)
            assert children, "the killed node was not restarted"
            assert proc.poll() is None
            proc.send_signal(signal.SIGTERM)   # SIGTERM stops the graph like Ctrl-C
            out, err = proc.communicate(timeout=30)
            assert proc.returncode == 0, err
            assert "restarting it in 1 s" in err and "restarted" in err
            assert not children[0].is_running() or children[0].status() == psutil.STATUS_ZOMBIE
        else:
            out, err = proc.communicate(timeout=30)
            assert proc.returncode == 1
            assert "exited" in err and "stopping the graph" in err
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
