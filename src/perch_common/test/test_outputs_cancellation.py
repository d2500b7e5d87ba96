"""Outputs that never harm inputs (atomic writes, refused overwrites) and cancellable stage work."""

from __future__ import annotations

import pytest

from perch_common.cancellation import Cancelled, CancelToken, cancellable, checkpoint
from perch_common.errors import PerchError
from perch_common.outputs import atomic_path, refuse_overwriting_inputs, replace_outputs, staging_folder


def test_a_failed_atomic_write_keeps_the_old_file_and_leaves_no_partial(tmp_path):
    target = tmp_path / "scan.mcap"
    target.write_bytes(b"good bag")
    with pytest.raises(RuntimeError):
        with atomic_path(target) as partial:
            partial.write_bytes(b"half")
            raise RuntimeError("bad frame")
    assert target.read_bytes() == b"good bag"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scan.mcap"]
    with atomic_path(target) as partial:
        assert partial.suffix == ".mcap" and partial.parent == tmp_path
        partial.write_bytes(b"new bag")
    assert target.read_bytes() == b"new bag"


def test_an_existing_folder_is_not_a_file_output(tmp_path):
    with pytest.raises(PerchError, match="is an existing folder; give a file path"):
        with atomic_path(tmp_path):
            pass


def test_outputs_equal_to_inputs_are_refused(tmp_path):
    mesh = tmp_path / "room.ply"
    mesh.write_text("ply")
    with pytest.raises(PerchError, match="is the input"):
        refuse_overwriting_inputs([tmp_path / "." / "room.ply"], [mesh])
    refuse_overwriting_inputs([tmp_path / "clean.ply"], [mesh, None])


def test_replacing_outputs_removes_stale_ones(tmp_path):
    out = tmp_path / "run"
    out.mkdir()
    for name in ("waypoints.yaml", "report.html", "notes.txt"):
        (out / name).write_text("old")
    (out / ".perch-outputs.json").write_text('{"written": ["waypoints.yaml", "report.html"]}')  # Perch wrote these
    staged = staging_folder(out)
    assert staged.parent == tmp_path and staged.name.startswith(".run.partial-")
    abandoned = tmp_path / ".other.partial-999999999-x"   # no such process
    abandoned.mkdir()
    staging_folder(out).rmdir()
    assert not abandoned.exists() and staged.exists()
    (staged / "FAILED").write_text("why")
    (staged / "run.mcap").write_text("new")
    replace_outputs(staged, out, ["FAILED", "run.mcap"], ["waypoints.yaml", "report.html", "run.mcap", "FAILED"])
    # The user's own file stays; the earlier mission's outputs are gone.
    assert sorted(p.name for p in out.iterdir()) == [".perch-outputs.json", "FAILED", "notes.txt", "run.mcap"]
    assert not staged.exists()


def test_checkpoint_raises_only_inside_a_cancelled_block():
    checkpoint("anything")  # no token: a no-op
    token = CancelToken()
    with cancellable(token):
        checkpoint("step 1")
        token.cancel("/perch/segment: cancelled by the mission coordinator")
        with pytest.raises(Cancelled, match="cancelled by the mission coordinator.*before step 2"):
            checkpoint("step 2")
    checkpoint("after the block")
