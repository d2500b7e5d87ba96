"""Nothing the user had is lost: outputs with the user's umask, a re-run swaps in a complete new set
(a failed one keeps the last good waypoints and says so), readers never find waypoints.yaml missing,
only what Perch wrote is replaced or removed, and unusable output folders are refused before a mission."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from perch_common.errors import PerchError
from perch_common.outputs import (
    MANIFEST_NAME,
    check_writable_folder,
    publish_output,
    refuse_folder_holding_inputs,
    refuse_foreign_outputs,
    replace_outputs,
    staging_folder,
    written_by_perch,
)


@pytest.fixture
def umask_027():
    previous = os.umask(0o027)
    try:
        yield
    finally:
        os.umask(previous)


def _good_mission(out: Path, label: str) -> None:
    """What a successful `perch plan` leaves: waypoints first, then the rest swapped in together."""
    from perch_interfaces.action import PlanPerches
    from perch_operator.cli.runner import GOOD_SET, OUTPUT_NAMES, PlanOutputs, publish_waypoints

    staged = staging_folder(out)
    (staged / "run.mcap").write_text(f"recording {label}")
    outputs = PlanOutputs(PlanPerches.Result(success=True, message=label), out, staged / "run.mcap", staged=staged)
    publish_waypoints(outputs)
    (staged / "report.html").write_text(f"report {label}")
    (staged / "report_files").mkdir()
    (staged / "report_files" / "overview.png").write_text(label)
    (staged / "run.rrd").write_text(label)
    replace_outputs(staged, out, GOOD_SET, [n for n in OUTPUT_NAMES if n != "waypoints.yaml"])


def test_outputs_get_the_users_umask(tmp_path, umask_027):
    out = tmp_path / "run"
    _good_mission(out, "first")
    for name in ("waypoints.yaml", "run.mcap", "report.html", "run.rrd", "report_files/overview.png"):
        assert (out / name).stat().st_mode & 0o777 == 0o640, name
    assert (out / "report_files").stat().st_mode & 0o777 == 0o750
    os.umask(0o002)
    _good_mission(out, "second")
    assert (out / "waypoints.yaml").stat().st_mode & 0o777 == 0o664


def test_a_failed_rerun_keeps_the_last_good_waypoints_and_says_so(tmp_path):
    from perch_interfaces.action import PlanPerches
    from perch_operator.cli.runner import PlanOutputs, fail_outputs

    out = tmp_path / "run"
    _good_mission(out, "good")
    before = {n: (out / n).read_bytes() for n in ("waypoints.yaml", "run.mcap", "report.html")}
    staged = staging_folder(out)
    (staged / "run.mcap").write_text("recording of the failed mission")
    failed = PlanOutputs(PlanPerches.Result(success=False), out, staged / "run.mcap", staged=staged)
    fail_outputs(failed, "segment: no planar region")
    # The last good set is untouched; the failure and its recording sit beside it.
    assert {n: (out / n).read_bytes() for n in before} == before
    assert (out / "failed.mcap").read_text() == "recording of the failed mission"
    reason = (out / "FAILED").read_text()
    assert reason.startswith("segment: no planar region")
    assert "the last good waypoints.yaml (written" in reason and "the last good mission's" in reason
    assert failed.mcap == out / "failed.mcap"
    # The next good mission clears the failure.
    _good_mission(out, "again")
    assert not (out / "FAILED").exists() and not (out / "failed.mcap").exists()
    assert (out / "report.html").read_text() == "report again"
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


def test_a_first_failure_leaves_failed_and_its_recording(tmp_path):
    from perch_interfaces.action import PlanPerches
    from perch_operator.cli.runner import PlanOutputs, fail_outputs

    out = tmp_path / "run"
    staged = staging_folder(out)
    (staged / "run.mcap").write_text("rec")
    fail_outputs(PlanOutputs(PlanPerches.Result(), out, staged / "run.mcap", staged=staged), "bad target")
    assert sorted(p.name for p in out.iterdir()) == [MANIFEST_NAME, "FAILED", "run.mcap"]
    assert "no waypoints, report or rerun file were written" in (out / "FAILED").read_text()


def test_readers_polling_waypoints_never_find_it_missing(tmp_path):
    out = tmp_path / "run"
    _good_mission(out, "0")
    missing, reads = [], [0]
    done = threading.Event()

    def poll() -> None:
        while not done.is_set():
            try:
                text = (out / "waypoints.yaml").read_text()
                assert text.startswith("frame_id"), text[:40]
            except FileNotFoundError:
                missing.append(1)
            reads[0] += 1

    reader = threading.Thread(target=poll)
    reader.start()
    try:
        for i in range(40):
            _good_mission(out, str(i))
    finally:
        done.set()
        reader.join()
    assert reads[0] > 100 and not missing, f"waypoints.yaml missing {len(missing)} times in {reads[0]} reads"


def test_only_what_perch_wrote_is_replaced_or_removed(tmp_path):
    out = tmp_path / "run"
    mine = out / "report_files"
    mine.mkdir(parents=True)
    (mine / "holiday.jpg").write_text("the user's own")
    (out / "notes.txt").write_text("mine")
    with pytest.raises(PerchError, match=r"holds report_files/, not written by Perch"):
        refuse_foreign_outputs(out, ["waypoints.yaml", "report_files"])
    staged = staging_folder(out)
    (staged / "report_files").mkdir()
    with pytest.raises(PerchError, match="not written by Perch"):
        replace_outputs(staged, out, ["report_files"], [])
    shutil.rmtree(staged)
    assert (mine / "holiday.jpg").read_text() == "the user's own"
    # Stale names are removed only when the manifest lists them.
    publish_output(out, "waypoints.yaml", lambda p: p.write_text("frame_id: map\n"))
    staged = staging_folder(out)
    (staged / "FAILED").write_text("why")
    replace_outputs(staged, out, ["FAILED"], ["waypoints.yaml", "report_files", "notes.txt"])
    assert sorted(p.name for p in out.iterdir()) == [MANIFEST_NAME, "FAILED", "notes.txt", "report_files"]
    assert written_by_perch(out) == {"FAILED"}


def test_a_folder_from_before_manifests_counts_only_what_its_report_shows(tmp_path):
    out = tmp_path / "old"
    (out / "report_files").mkdir(parents=True)
    (out / "report.html").write_text("<img src='report_files/overview.png'>")
    (out / "report_files" / "overview.png").write_text("png")
    (out / "waypoints.yaml").write_text("frame_id: map\n")
    assert written_by_perch(out) == {"report.html", "report_files", "waypoints.yaml"}
    (out / "report_files" / "my_notes.txt").write_text("the user's")
    assert written_by_perch(out) == {"report.html", "waypoints.yaml"}


def test_an_output_folder_holding_an_input_is_refused(tmp_path):
    mesh = tmp_path / "scans" / "room.ply"
    mesh.parent.mkdir()
    mesh.write_text("ply")
    with pytest.raises(PerchError, match="holds the input"):
        refuse_folder_holding_inputs(tmp_path / "scans", [mesh])
    with pytest.raises(PerchError, match="holds the input"):
        refuse_folder_holding_inputs(tmp_path, [None, mesh])
    refuse_folder_holding_inputs(tmp_path / "out", [mesh, None])


def test_an_unwritable_output_folder_is_refused_before_the_mission(tmp_path):
    with pytest.raises(PerchError, match="is a file"):
        (tmp_path / "f").write_text("")
        check_writable_folder(tmp_path / "f")
    check_writable_folder(tmp_path / "new" / "deeper")   # created later: its existing ancestor is writable
    # Root may write into any folder of an ordinary file system; /proc takes no new folders from anyone.
    out = Path("/proc/perch-out") if os.getuid() == 0 else tmp_path / "locked" / "out"
    if os.getuid() != 0:
        out.mkdir(parents=True)
        out.chmod(0o555)
    try:
        with pytest.raises(PerchError, match="cannot write into"):
            check_writable_folder(out)
        # `perch plan --no-launch` (no graph needed to get this far) stops before any mission with one
        # line, no traceback and no .partial folder.
        done = subprocess.run([sys.executable, "-m", "perch_common.cli", "plan", "--scene", "1", "--no-launch",
                               "--auto-accept", "-o", str(out)], capture_output=True, text=True, timeout=120)
        assert done.returncode == 1, done.stderr
        assert "perch: error: -o" in done.stderr and "cannot write into" in done.stderr, done.stderr
        assert "Traceback" not in done.stderr
        if os.getuid() != 0:
            assert not list(out.iterdir()) and sorted(p.name for p in out.parent.iterdir()) == ["out"]
    finally:
        if os.getuid() != 0:
            out.chmod(0o755)


def test_the_dispatchers_waypoints_file_is_replaced_atomically_with_the_umask(tmp_path, umask_027):
    """`perch dispatch --output FILE` rewrites FILE on every waypoint set (write_waypoints_yaml)."""
    from unittest import mock

    from perch_operator.outputs.mission_data import write_waypoints_yaml

    path = tmp_path / "dispatch.yaml"
    write_waypoints_yaml(path, [])
    assert path.stat().st_mode & 0o777 == 0o640
    before = path.read_text()
    real_write = Path.write_text

    def half_then_fail(self, text, *args, **kwargs):   # the disk filled up halfway through
        real_write(self, text[: len(text) // 2])
        raise OSError(28, "No space left on device")

    with mock.patch.object(Path, "write_text", half_then_fail), pytest.raises(OSError):
        write_waypoints_yaml(path, [])
    assert path.read_text() == before and sorted(p.name for p in tmp_path.iterdir()) == ["dispatch.yaml"]


def test_a_users_file_put_inside_perchs_report_files_is_never_removed(tmp_path):
    """--overwrite replaces report_files/ only while it holds only what Perch wrote (issue 22 finding 2)."""
    from perch_operator.cli.plan import check_output_folder
    from perch_operator.cli.runner import OUTPUT_NAMES

    out = tmp_path / "run"
    _good_mission(out, "first")
    assert "report_files/overview.png" in (out / MANIFEST_NAME).read_text()
    (out / "report_files" / "my_annotations.txt").write_text("the user's")
    refused = r"report_files/ holds my_annotations.txt, not written by Perch; .* move it out of report_files/"
    for overwrite in (True, False):
        with pytest.raises(PerchError, match=refused):
            check_output_folder(out, overwrite, [])
    with pytest.raises(PerchError, match=refused):   # and at the swap, should it appear during the mission
        _good_mission(out, "second")
    staged = staging_folder(out)
    (staged / "FAILED").write_text("why")
    replace_outputs(staged, out, ["FAILED"], OUTPUT_NAMES)   # stale names: the folder is not removed either
    assert (out / "report_files" / "my_annotations.txt").read_text() == "the user's"
    (out / "report_files" / "my_annotations.txt").unlink()
    _good_mission(out, "third")   # once it is moved away, the folder is Perch's again
    assert (out / "report.html").read_text() == "report third"


def test_the_advice_for_a_users_own_report_files_matches_what_overwrite_does(tmp_path):
    """Without --overwrite the reply must not advise --overwrite when that would be refused (finding 8)."""
    from perch_operator.cli.plan import check_output_folder

    (tmp_path / "report_files").mkdir()
    for overwrite in (False, True):
        with pytest.raises(PerchError, match=r"holds report_files/, not written by Perch") as info:
            check_output_folder(tmp_path, overwrite, [])
        assert "--overwrite" not in str(info.value)


def test_a_link_to_the_input_inside_the_output_folder_is_refused(tmp_path):
    """The input reached through a symlink in -o counts as held by -o (finding 9)."""
    mesh = tmp_path / "scans" / "room.ply"
    mesh.parent.mkdir()
    mesh.write_text("ply")
    out = tmp_path / "out"
    out.mkdir()
    (out / "room.ply").symlink_to(mesh)
    with pytest.raises(PerchError, match="holds the input"):
        refuse_folder_holding_inputs(out, [out / "room.ply"])
    (tmp_path / "scans_link").symlink_to(mesh.parent, target_is_directory=True)
    with pytest.raises(PerchError, match="holds the input"):   # -o given through a link to the input's folder
        refuse_folder_holding_inputs(tmp_path / "scans_link", [mesh])


def _dispatch(*argv: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "perch_common.cli", "dispatch", *argv], capture_output=True,
                          text=True, timeout=60)


def test_perch_dispatch_checks_its_output_file_when_it_starts(tmp_path):
    """A folder, or a file in an unwritable folder, is refused with one line before any waypoint set
    arrives (no graph runs here: the command would otherwise wait for one) (issue 22 findings 1, 11)."""
    done = _dispatch("--output", str(tmp_path))
    assert done.returncode == 1, done.stderr
    assert done.stderr == (f"perch: error: --output {tmp_path} is an existing folder; give a file path "
                           f"(e.g. {tmp_path / 'waypoints.yaml'})\n")
    # Root may write into any folder of an ordinary file system; /proc takes no new files from anyone.
    locked = Path("/proc") if os.getuid() == 0 else tmp_path / "locked"
    if os.getuid() != 0:
        locked.mkdir()
        locked.chmod(0o555)
    try:
        done = _dispatch("--output", str(locked / "wp.yaml"))
    finally:
        if os.getuid() != 0:
            locked.chmod(0o755)
    assert done.returncode == 1, done.stderr
    line = done.stderr.strip()
    assert "\n" not in line and line.startswith(f"perch: error: --output {locked / 'wp.yaml'}: cannot write into "
                                                f"{locked} ("), line
    assert line.endswith("choose a file in a folder you can write, or fix the folder's permissions"), line


def test_a_one_thread_node_runs_on_the_single_threaded_executor():
    """`perch dispatch` (threads=1) printed rclpy's 'MultiThreadedExecutor is used with a single thread'."""
    import warnings

    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor

    from perch_common.ros import testing
    from perch_common.ros.node_main import make_executor

    testing.use_isolated_ros_env()
    context = Context()
    context.init()
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            for threads in (1, 2):
                executor = make_executor(threads, context)
                assert isinstance(executor, SingleThreadedExecutor) == (threads == 1)
                executor.shutdown()
    finally:
        context.try_shutdown()


def test_commands_never_replace_a_users_file_nor_read_a_non_recording(tmp_path, capsys):
    """`perch record` onto an existing file replaced it with an empty MCAP; `perch batch -o FILE` and
    `perch replay` of a file that is not an MCAP ended in tracebacks. Each is one line, and the file stays."""
    from perch_common.cli import main
    from perch_operator.outputs.runfile import stage_calls

    mesh = tmp_path / "room.obj"
    mesh.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    for argv, said in ((["record", str(mesh), "--duration", "1"], "the file exists; give a new path"),
                       (["record", str(tmp_path / "new.mcap"), "--duration", "-1"], "--duration must be >= 0"),
                       (["batch", str(mesh), "-o", str(mesh)], "is a file; give a folder for the outputs")):
        with pytest.raises(SystemExit) as stopped:
            main(argv)
        assert stopped.value.code == 1 and said in capsys.readouterr().err, argv
    assert mesh.read_text() == "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n"
    empty = tmp_path / "empty.mcap"
    empty.write_bytes(b"")
    for path, kind in ((empty, "empty"), (mesh, "another format")):
        with pytest.raises(PerchError, match=f"not an MCAP recording \\({kind}\\); give the run.mcap"):
            stage_calls(path)
