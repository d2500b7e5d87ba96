"""`perch dispatch --output FILE` replaces FILE only while it is a writable waypoints file it wrote:
a user's file, a read-only file, a link or a mission's output is refused when it starts and never replaced."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

from perch_common.ros import testing


def _dispatch(*argv: str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "perch_common.cli", "dispatch", *argv], capture_output=True,
                          text=True, timeout=30, cwd=cwd, env=testing.isolated_ros_env())


def _waypoints_file(path: Path) -> Path:
    from perch_interfaces.msg import PerchWaypoint
    from perch_operator.outputs.mission_data import waypoint_dict, write_waypoints_yaml

    return write_waypoints_yaml(path, [waypoint_dict(PerchWaypoint(drone_index=0, proposal_id=3))])


def test_a_users_file_and_a_read_only_file_are_refused_at_start_up(tmp_path):
    """Bug hunt: notes.txt, and a chmod 444 file, were silently replaced by waypoint YAML at the first
    accepted proposal. Now each is refused by name before the dispatcher waits for anything."""
    notes = tmp_path / "notes.txt"
    notes.write_text("my notes\n")
    read_only = _waypoints_file(tmp_path / "kept.yaml")   # a waypoints file, but the user locked it
    read_only.chmod(0o444)
    before = read_only.read_text()
    cases = ((notes, "exists and is not a waypoints file written by perch dispatch"),
             (read_only, "is read-only, and perch dispatch never replaces a read-only file"))
    for path, why in cases:
        done = _dispatch("--output", path.name, cwd=tmp_path)
        assert done.returncode == 1, done.stderr
        line = done.stderr.strip()
        assert "\n" not in line and line.startswith(f"perch: error: --output {path.name}: {why}"), line
        assert "Traceback" not in done.stderr
    assert notes.read_text() == "my notes\n" and read_only.read_text() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["kept.yaml", "notes.txt"]


def test_which_files_the_dispatcher_may_replace(tmp_path):
    from perch_common.outputs import MANIFEST_NAME
    from perch_operator.cli.dispatcher import replace_refusal

    assert replace_refusal(tmp_path / "new.yaml") == ""                      # absent: created
    assert replace_refusal(_waypoints_file(tmp_path / "own.yaml")) == ""    # its own earlier file
    for name, text in (("empty.yaml", ""), ("list.yaml", "- 1\n- 2\n"), ("binary.yaml", "\x00\xff"),
                       ("other.yaml", "frame_id: map\nunits: m\nwaypoints: []\nnotes: mine\n"),
                       ("bad.yaml", "frame_id: map\nunits: m\nwaypoints: [{a: 1}]\n"), ("broken.yaml", "a: [")):
        (tmp_path / name).write_text(text)
        assert "is not a waypoints file" in replace_refusal(tmp_path / name), name
    link = tmp_path / "link.yaml"
    link.symlink_to(tmp_path / "own.yaml")
    assert "symbolic link" in replace_refusal(link)
    mission = tmp_path / "m1"   # perch plan's output folder: its waypoints.yaml is a mission result
    mission.mkdir()
    _waypoints_file(mission / "waypoints.yaml")
    (mission / MANIFEST_NAME).write_text('{"written": ["waypoints.yaml"]}\n')
    assert "is a mission's output" in replace_refusal(mission / "waypoints.yaml")


@pytest.fixture
def ros_context():
    testing.use_isolated_ros_env()
    from perch_common.ros.node_main import ros_context

    with ros_context():
        yield


def test_a_file_that_changes_after_start_up_is_not_replaced(tmp_path, ros_context):
    """The file is checked again before each write: put there (or locked) while the dispatcher runs, it is
    left alone with a log line, and the dispatcher goes on."""
    from unique_identifier_msgs.msg import UUID

    from perch_interfaces.msg import PerchWaypoint, PerchWaypointSet
    from perch_operator.cli.dispatcher import Dispatcher

    path = tmp_path / "waypoints.yaml"
    dispatcher = Dispatcher(path, name="test_dispatch_output")
    try:
        mission = UUID(uuid=list(range(16)))
        waypoint_set = PerchWaypointSet(mission_id=mission, waypoints=[PerchWaypoint(mission_id=mission,
                                                                                      drone_index=1, proposal_id=4)])
        dispatcher._accept(waypoint_set)   # absent: written
        assert "proposal_id: 4" in path.read_text()
        path.chmod(0o444)
        waypoint_set.waypoints[0].proposal_id = 5
        dispatcher._accept(waypoint_set)
        assert "proposal_id: 4" in path.read_text() and dispatcher.received[0]["proposal_id"] == 5
        path.chmod(0o644)
        path.write_text("the user's notes\n")
        dispatcher._accept(waypoint_set)
        assert path.read_text() == "the user's notes\n"
        path.unlink()
        dispatcher._accept(waypoint_set)
        assert "proposal_id: 5" in path.read_text()
    finally:
        dispatcher.destroy_node()
    assert os.listdir(tmp_path) == ["waypoints.yaml"]


def test_it_says_at_start_up_what_it_waits_for(tmp_path):
    """Hunt 6: started before any mission it printed nothing: running or stuck looked the same."""
    import select
    import time

    path = tmp_path / "waypoints.yaml"
    started = subprocess.Popen([sys.executable, "-m", "perch_common.cli", "dispatch", "--output", str(path)],
                               stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, cwd=tmp_path,
                               env=testing.isolated_ros_env())
    try:
        deadline, said = time.monotonic() + 60, b""
        while b"before this start" not in said and time.monotonic() < deadline:   # the end of its first line
            if select.select([started.stderr], [], [], max(0.0, deadline - time.monotonic()))[0]:
                chunk = os.read(started.stderr.fileno(), 4096)
                if not chunk:   # it exited
                    break
                said += chunk
        text = said.decode()
        assert "waiting for the accepted perches on /perch/mission_waypoints" in text, text
        assert f"(kept in {path})" in text
    finally:
        started.terminate()
        started.wait(30)
