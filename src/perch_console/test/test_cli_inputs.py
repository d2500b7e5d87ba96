"""`perch console` and `perch view` refuse bad input with one line before serving anything.

Each used to hang (a port out of range, an address not on this machine, a text file given to the
viewer), serve somewhere else than asked (a port in use), or start viser or chromium before failing
(a missing recording, a folder as the screenshot) or replace a user's file (an existing screenshot).
The commands run as `python -m perch_common.cli` processes: the timeout only bounds a hang (the old
behaviour) and is never reached by a refusal, which comes at once.
"""

from __future__ import annotations

import socket
import subprocess
import sys
from pathlib import Path

import pytest

HANG_LIMIT_S = 120   # a refusal takes a couple of seconds of imports; reaching this is the hang being tested


@pytest.fixture(scope="module", autouse=True)
def isolated_domain():
    from perch_common.ros import testing

    testing.use_isolated_ros_env()   # the console's rclpy client stays off other tests' graphs


def perch(*argv: str, cwd: Path | None = None) -> subprocess.CompletedProcess:
    """Run `perch ARGV...`; a hang fails the test with TimeoutExpired."""
    return subprocess.run([sys.executable, "-m", "perch_common.cli", *argv], capture_output=True, text=True,
                          timeout=HANG_LIMIT_S, cwd=cwd)


def assert_refused(done: subprocess.CompletedProcess, said: str, code: int = 1) -> None:
    """One line naming the problem, the exit code, no traceback and no server started."""
    assert done.returncode == code, (done.stdout, done.stderr)
    assert said in done.stderr, done.stderr
    assert "Traceback" not in done.stderr + done.stdout
    assert "viser" not in done.stdout + done.stderr   # viser's banner: a server was started


@pytest.fixture
def busy_port():
    """A port something on this machine listens on."""
    with socket.socket() as holder:
        holder.bind(("127.0.0.1", 0))
        holder.listen()
        yield holder.getsockname()[1]


@pytest.mark.parametrize("port", ["70000", "-1"])
def test_a_port_out_of_range_is_an_argument_error(port):
    assert_refused(perch("console", "--port", port), "argument --port", code=2)


@pytest.mark.parametrize("host", ["256.1.1.1", "nosuch.invalid", "192.0.2.1"])   # 192.0.2.1: RFC 5737, never local
def test_an_address_not_on_this_machine_is_refused(host):
    assert_refused(perch("console", "--host", host, "--port", "0"), f"--host {host}: cannot be served on here")


def test_a_port_in_use_is_refused_not_moved(busy_port):
    assert_refused(perch("console", "--port", str(busy_port)),
                   f"--port {busy_port}: cannot be used on 127.0.0.1 (Address already in use); give another port, "
                   "or --port 0")


def test_a_port_taken_after_the_check_is_refused_too(busy_port, monkeypatch):
    """The port is taken between the check and viser's start: viser moved to the next port; now refused."""
    from perch_common.errors import PerchError
    from perch_console import cli

    monkeypatch.setattr(cli, "check_can_serve", lambda host, port: None)
    with pytest.raises(PerchError, match=f"--port {busy_port}: cannot be used"):
        cli.start_console(None, "127.0.0.1", busy_port)


def test_a_missing_or_foreign_recording_is_refused_before_serving(tmp_path):
    text = tmp_path / "notes.mcap"
    text.write_text("hello\n")
    assert_refused(perch("console", "--recording", str(tmp_path / "missing.mcap"), "--port", "0"),
                   "missing.mcap: no such recording")
    assert_refused(perch("console", "--recording", str(text), "--port", "0"), "not an MCAP recording")
    # Hunt 6: a camera bag (an MCAP of images, no /perch/ topic) was served as an empty console.
    from perch_reconstruction.bag_write import write_bag
    from perch_reconstruction.synthetic import DEFAULT_INTRINSICS, synthetic_room_frames

    _, frames = synthetic_room_frames(seed=1, count=2)
    write_bag(tmp_path / "camera.mcap", frames, DEFAULT_INTRINSICS)
    assert_refused(perch("console", "--recording", str(tmp_path / "camera.mcap"), "--port", "0"),
                   "camera.mcap: not a Perch run recording (its topics: /camera/")


def test_a_screenshot_must_be_a_new_png_file(tmp_path):
    folder = tmp_path / "shots"
    folder.mkdir()
    mine = tmp_path / "mine.png"
    mine.write_bytes(b"the user's picture")
    for path, said in ((folder, f"--screenshot {folder} is an existing folder; give a file path"),
                       (tmp_path / "shot.jpg", "not a .png file"),
                       (mine, "the file exists; give a new path, or add --overwrite")):
        assert_refused(perch("console", "--port", "0", "--screenshot", str(path)), said)
    assert mine.read_bytes() == b"the user's picture"
    from perch_console.cli import check_screenshot

    check_screenshot(mine, overwrite=True)   # --overwrite: the user asked for it to be replaced
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mine.png", "shots"]


def test_perch_view_refuses_a_file_that_is_not_a_recording(tmp_path):
    text = tmp_path / "text.mcap"
    text.write_text("hello\n")
    empty = tmp_path / "empty.rrd"
    empty.write_bytes(b"")
    for path, kind in ((text, "neither .rrd nor MCAP"), (empty, "empty")):
        done = perch("view", str(path), "--web")
        assert done.returncode == 1 and f"not a recording ({kind})" in done.stderr, (done.stdout, done.stderr)
        assert "perch view: " not in done.stdout   # the viewer was never started


def test_perch_view_accepts_rrd_and_mcap_and_serves_on_loopback_by_default(tmp_path):
    from perch_operator.cli.commands import check_viewable, viewer_command

    for name, head in (("run.rrd", b"RRF2\x00\x29\x00\x00"), ("run.mcap", b"\x89MCAP0\r\n")):
        (tmp_path / name).write_bytes(head + b"\x00" * 16)
        check_viewable(tmp_path / name)
    cmd = viewer_command(tmp_path / "run.rrd", web=True)
    if cmd is None:
        pytest.skip("rerun is not installed")
    assert cmd[cmd.index("--bind") + 1] == "127.0.0.1"
    exposed = viewer_command(tmp_path / "run.rrd", web=True, host="0.0.0.0")
    assert exposed[exposed.index("--bind") + 1] == "0.0.0.0"
