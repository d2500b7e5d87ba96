"""`perch operator`: bad values are refused by argparse, `list` shows only the current mission's
proposals (what `accept` acts on), prints received text safely, and says when no coordinator is there."""

import subprocess
import sys
import time

import pytest

from perch_common.ros import testing


def _perch(*argv: str, timeout: float = 60) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "perch_common.cli", *argv], capture_output=True, text=True,
                          timeout=timeout, env=testing.isolated_ros_env())


@pytest.mark.parametrize("argv, why", [
    (["list", "--wait", "inf"], "--wait: inf must be a finite number > 0"),   # hung for ever
    (["list", "--wait", "-5"], "--wait: -5 must be a finite number > 0"),
    (["list", "--wait", "nan"], "--wait: nan must be a finite number > 0"),
    (["list", "--wait", "0"], "--wait: 0 must be a finite number > 0"),
    (["cancel", "--timeout", "-1"], "--timeout: -1 must be a finite number > 0"),
    (["cancel", "--timeout", "inf"], "--timeout: inf must be a finite number > 0"),
    (["reject", "2", "--reason", "multi\nline \x1b[31mred\x1b[0m"], "--reason: holds the control character '\\n'"),
    (["accept", "2", "--reason", "\x1b[31mred"], "--reason: holds the control character '\\x1b'"),
    (["failed", "2", "--reason", "abc\u202edcba"], "--reason: holds the control character '\\u202e'"),
    (["reject", "2", "--reason", "x" * 100_000], "--reason: is 100000 characters long; give at most 500"),
    (["review", "1", "--reason", "a\tb"], "--reason: holds the control character '\\t'"),
    (["accept", "-1"], "id: -1 is out of range"),
    (["accept", str(2 ** 32)], f"id: {2 ** 32} is out of range"),
    (["accept", "four"], "id: 'four' is not a whole number"),
])
def test_bad_values_are_refused_before_anything_runs(argv, why, capsys):
    from perch_common.cli import build_parser

    argv = ["operator", *argv]
    with pytest.raises(SystemExit) as exit_info:   # parsed only: the old code ran `list --wait inf` for ever
        build_parser(argv).parse_args(argv)
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and f"error: argument {why}" in err.splitlines()[-1], err   # after the usage


def test_a_sensible_reason_is_taken():
    from perch_operator.cli.commands import MAX_REASON, reason_text

    for reason in ("", "blocks the door", "ü-Bahn: n\u00e4he Tür", "x" * MAX_REASON):
        assert reason_text(reason) == reason


def test_received_text_is_printed_safely():
    """Another client may send any reason: `list` shows it on one line, escapes and all, cut to length."""
    from perch_interfaces.msg import Proposal
    from perch_operator.cli.commands import MAX_REASON, _proposal_line

    line = _proposal_line(Proposal(id=3, reason="multi\nline \x1b[31mred\x1b[0m \u202eevil\r"))
    assert "\n" not in line and "\x1b" not in line and "\u202e" not in line and "\r" not in line
    assert "(multi\\nline \\x1b[31mred\\x1b[0m \\u202eevil\\r)" in line
    line = _proposal_line(Proposal(id=3, reason="y" * 100_000))
    assert "y" * MAX_REASON + "... (99500 more characters)" in line and len(line) < MAX_REASON + 300


def test_list_without_a_graph_says_so_and_fails_in_bounded_time():
    """It printed "no proposals (is a mission running?)" and exited 0."""
    started = time.monotonic()
    done = _perch("operator", "list", "--wait", "1")
    assert done.returncode == 1, (done.stdout, done.stderr)
    assert done.stderr.startswith("perch: error: no mission coordinator in the graph within 1 s"), done.stderr
    assert "is the graph running (`perch launch`)?" in done.stderr and len(done.stderr.splitlines()) == 1
    assert done.stdout == "" and time.monotonic() - started < 30


class FakeCoordinator:
    """What `perch operator list` reads of a coordinator: its proposal history, its action's goal status
    list and its latched waypoint set, published with the coordinator's QoS."""

    def __init__(self, node):
        from action_msgs.msg import GoalStatusArray
        from rclpy.qos import qos_profile_action_status_default

        from perch_common.conventions import MISSION_STATUS_TOPIC
        from perch_interfaces.msg import PerchWaypointSet, Proposal
        from perch_operator.coordinator.node import LATCHED, LATCHED_LAST

        self.node = node
        self.proposals = node.create_publisher(Proposal, "perch/proposals", LATCHED)
        self.status = node.create_publisher(GoalStatusArray, MISSION_STATUS_TOPIC, qos_profile_action_status_default)
        self.sets = node.create_publisher(PerchWaypointSet, "perch/mission_waypoints", LATCHED_LAST)
        self.goals = []   # GoalStatus of every mission so far

    def propose(self, proposal_id: int, status: int = 0, reason: str = "") -> None:
        """A proposal of the latest mission, tagged with its goal id as the coordinator does."""
        from perch_interfaces.msg import Proposal

        self.proposals.publish(Proposal(id=proposal_id, mission_id=self.goals[-1].goal_info.goal_id, status=status,
                                        reason=reason))

    def start(self, goal: int) -> None:
        """Mission `goal` accepted now (after everything published so far) and running."""
        from action_msgs.msg import GoalInfo, GoalStatus
        from unique_identifier_msgs.msg import UUID

        from perch_interfaces.msg import PerchWaypointSet

        uuid = UUID(uuid=[goal] * 16)
        info = GoalInfo(goal_id=uuid, stamp=self.node.get_clock().now().to_msg())
        self.goals.append(GoalStatus(goal_info=info, status=GoalStatus.STATUS_EXECUTING))
        self._publish_status()
        self.sets.publish(PerchWaypointSet(mission_id=uuid))

    def end(self, status: int) -> None:
        self.goals[-1].status = status
        self._publish_status()

    def _publish_status(self) -> None:
        from action_msgs.msg import GoalStatusArray

        self.status.publish(GoalStatusArray(status_list=list(self.goals)))

    def destroy(self) -> None:
        for publisher in (self.proposals, self.status, self.sets):
            self.node.destroy_publisher(publisher)


@pytest.fixture
def coordinator(ros_node):
    fake = FakeCoordinator(ros_node)
    try:
        yield fake
    finally:
        fake.destroy()


def _listed(stdout: str) -> list[int]:
    return [int(line.split()[1]) for line in stdout.splitlines() if line.startswith("proposal ")]


def test_list_shows_only_the_current_missions_proposals(coordinator):
    """Bug hunt: `list` showed every earlier mission's proposals (some still pending, from the depth-100
    transient-local history of perch/proposals) while `accept 4` said proposal 4 was unknown. Each
    proposal now names its mission."""
    from action_msgs.msg import GoalStatus

    coordinator.start(1)                       # a finished mission: three proposals, two left pending
    for pid in (1, 2, 3):
        coordinator.propose(pid)
    coordinator.propose(3, status=1)
    coordinator.end(GoalStatus.STATUS_SUCCEEDED)
    coordinator.start(2)                       # a cancelled one
    coordinator.propose(4)
    coordinator.end(GoalStatus.STATUS_CANCELED)
    coordinator.start(3)                       # the mission in review now
    coordinator.propose(5, reason="multi\nline \x1b[31mred\x1b[0m")
    coordinator.propose(6)
    coordinator.propose(6, status=2, reason="blocks the door")
    coordinator.propose(7)
    done = _perch("operator", "list", "--wait", "5")
    assert done.returncode == 0, done.stderr
    assert _listed(done.stdout) == [5, 6, 7], done.stdout
    assert done.stdout.startswith(f"mission {'03' * 16} (running): 3 proposal(s)\n"), done.stdout
    assert "\x1b" not in done.stdout and "(multi\\nline \\x1b[31mred\\x1b[0m)" in done.stdout
    assert " rejected " in done.stdout.splitlines()[2] and "(blocks the door)" in done.stdout

    coordinator.end(GoalStatus.STATUS_SUCCEEDED)   # ended: its accepted perches can still fail in flight
    done = _perch("operator", "list", "--wait", "5")
    assert done.returncode == 0 and _listed(done.stdout) == [5, 6, 7], (done.stdout, done.stderr)
    assert "(succeeded)" in done.stdout and "perch operator failed ID" in done.stdout

    coordinator.start(4)                       # a new mission that has not proposed yet
    done = _perch("operator", "list", "--wait", "5")
    assert done.returncode == 0 and _listed(done.stdout) == [], (done.stdout, done.stderr)
    assert done.stdout == f"no proposals yet: mission {'04' * 16} is running (it proposes perches once its " \
                          "optimise stage has run)\n"

    coordinator.propose(8)
    coordinator.end(GoalStatus.STATUS_CANCELED)   # cancelled: accept refuses every proposal of it
    done = _perch("operator", "list", "--wait", "5")
    assert done.returncode == 0 and _listed(done.stdout) == [], (done.stdout, done.stderr)
    assert done.stdout.startswith(f"no proposals to decide: mission {'04' * 16} cancelled; decisions"), done.stdout

    coordinator.start(5)                       # it proposes; then the action server forgets its goal (expired)
    coordinator.propose(9)
    coordinator.goals.clear()
    coordinator._publish_status()
    done = _perch("operator", "list", "--wait", "5")   # the latched waypoint set still names the mission
    assert done.returncode == 0 and _listed(done.stdout) == [9], (done.stdout, done.stderr)
    assert done.stdout.startswith(f"mission {'05' * 16} (ended): 1 proposal(s); it has ended"), done.stdout


def test_plan_no_launch_without_a_graph_fails_within_its_timeout_and_leaves_nothing(tmp_path):
    """Hunt 6: it took 41 s whatever --timeout, advised `perch plan` (the command in use), and left FAILED and a
    run.mcap that made the retry with the same -o need --overwrite; --config was silently ignored."""
    out = tmp_path / "mission"
    started = time.monotonic()
    done = _perch("plan", "--scene", "1", "--no-launch", "-o", str(out), "--auto-accept", "--quiet", "--timeout", "2")
    assert done.returncode == 1, (done.stdout, done.stderr)
    assert done.stderr.startswith("perch: error: no mission coordinator: action perch/plan_perches did not appear "
                                  "within 2 s; start the graph with `perch launch` (`perch plan` without "
                                  "--no-launch starts its own)"), done.stderr
    assert time.monotonic() - started < 30 and not out.exists()
    done = _perch("plan", "--scene", "1", "--no-launch", "--config", str(tmp_path / "mine.yaml"), "-o", str(out))
    assert done.returncode == 1 and done.stderr.startswith("perch: error: --config with --no-launch: "), done.stderr


def test_plan_refuses_options_that_do_not_apply_to_its_source(tmp_path):
    """Hunt 6: --scale with --scene and --kind with --mesh were silently ignored."""
    done = _perch("plan", "--scene", "1", "--scale", "2", "-o", str(tmp_path / "a"), "--auto-accept")
    assert done.returncode == 1 and done.stderr.startswith("perch: error: --scale and --shift apply to --mesh"), \
        done.stderr
    done = _perch("plan", "--mesh", str(tmp_path / "room.ply"), "--kind", "room", "-o", str(tmp_path / "b"))
    assert done.returncode == 1 and done.stderr.startswith("perch: error: --kind applies to --scene"), done.stderr
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()
