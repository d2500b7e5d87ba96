"""perch batch: which scans a folder or manifest names, each scan's row, and whole batches run
locally and on a local multi-process Dask cluster (a failing scan never stops the batch)."""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import pytest

from perch_common.errors import PerchError
from perch_operator.cli import batch


def _touch(path: Path, text: str = "x") -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


def test_folder_lists_meshes_and_bags_and_takes_x_target_as_the_footprint_of_x(tmp_path):
    for name in ("apartment.ply", "apartment_target.ply", "office.obj", "walk.mcap", "notes.txt", "lone_target.ply"):
        _touch(tmp_path / name)
    _touch(tmp_path / "rosbag" / "metadata.yaml")
    scans = {s.name: s for s in batch.collect_scans([tmp_path])}
    assert sorted(scans) == ["apartment", "lone_target", "office", "rosbag", "walk"]
    assert scans["apartment"].options == {"--target": f"{tmp_path / 'apartment_target.ply'}:1.2"}
    assert scans["office"].kind == "mesh" and not scans["office"].options
    assert scans["walk"].kind == "bag" and scans["rosbag"].kind == "bag"


def test_manifest_rows_give_per_scan_options_and_bad_rows_become_failed_scans(tmp_path):
    _touch(tmp_path / "scans" / "a.obj")
    _touch(tmp_path / "scans" / "b.ply")
    _touch(tmp_path / "scans" / "floorplan.ply")
    _touch(tmp_path / "scans" / "readme.txt")
    manifest = _touch(tmp_path / "scans" / "list.tsv", "\n".join([
        "file\tup\tcameras\ttarget\tname\tnote\tscale\tshift",
        "a.obj\t+y\t3\t\t\tfirst\t\t",
        "b.ply\t0.03,0.99,-0.02\t\tfloorplan.ply:2\tb scan\t\t",
        "a.obj\t\t\tbox:0,0,1,1,1,1\t\tagain\t0.001\t-450120,-5201240,-310",
        "missing.ply\t\t\t\t\t\t\t",
        "readme.txt\t\t\t\t\t\t\t",
        "\t\t\t\t\tempty row is skipped\t\t"]))
    scans = batch.collect_scans([manifest])
    assert [s.name for s in scans] == ["a", "b_scan", "a_2", "missing", "readme"]
    assert scans[0].options == {"--up": "+y", "--cameras": "3"}
    assert scans[1].options == {"--up": "0.03,0.99,-0.02", "--target": f"{tmp_path / 'scans' / 'floorplan.ply'}:2"}
    assert scans[2].options == {"--target": "box:0,0,1,1,1,1", "--scale": "0.001", "--shift": "-450120,-5201240,-310"}
    # A georeferenced scan's shift starts with a minus: passed as --shift=..., which perch plan's parser takes.
    from perch_common.cli import build_parser

    cmd = batch.plan_command(scans[2], batch.PlanSettings(out=str(tmp_path)), "perch_batch_r_0")
    argv = cmd[cmd.index("--namespace"):]
    args = build_parser(argv).parse_args(argv)
    assert args.shift == (-450120.0, -5201240.0, -310.0) and args.scale == 0.001
    assert "line 5" in scans[3].problem and "does not exist" in scans[3].problem
    assert "neither a mesh" in scans[4].problem
    # A folder holding MANIFEST.tsv is read through it.
    (tmp_path / "scans" / "list.tsv").rename(tmp_path / "scans" / "MANIFEST.tsv")
    assert [s.name for s in batch.collect_scans([tmp_path / "scans"])] == ["a", "b_scan", "a_2", "missing", "readme"]


def test_manifest_without_a_file_column_and_empty_sources_are_refused(tmp_path):
    manifest = _touch(tmp_path / "m.csv", "scan_file,up\na.ply,+z\n")
    with pytest.raises(PerchError, match="column named one of file, path"):
        batch.collect_scans([manifest])
    (tmp_path / "empty").mkdir()
    with pytest.raises(PerchError, match="no scans in"):
        batch.collect_scans([tmp_path / "empty"])
    with pytest.raises(PerchError, match="no such folder or file"):
        batch.collect_scans([tmp_path / "nowhere"])


def test_plan_command_passes_values_that_start_with_a_minus(tmp_path):
    scan = batch.Scan("/data/x.ply", "mesh", "x", {"--up": "-0.03,0.99,-0.02", "--cameras": "2"})
    settings = batch.PlanSettings(out=str(tmp_path), options={"--cameras": "4", "--seed": "1"},
                                  params=["perch_placement:num_particles:=8"], overwrite=True)
    cmd = batch.plan_command(scan, settings, "perch_batch_r_0")
    assert cmd[cmd.index("--namespace") + 1] == "perch_batch_r_0"
    assert "--mesh=/data/x.ply" in cmd and f"--out={tmp_path / 'x'}" in cmd
    assert "--up=-0.03,0.99,-0.02" in cmd and "--cameras=2" in cmd and "--cameras=4" not in cmd
    assert "--seed=1" in cmd and "--param=perch_placement:num_particles:=8" in cmd and "--overwrite" in cmd
    from perch_common.cli import build_parser

    argv = cmd[cmd.index("--namespace"):]
    args = build_parser(argv).parse_args(argv)   # perch plan's own parser accepts every option
    assert args.up == "-0.03,0.99,-0.02" and args.cameras == 2 and args.auto_accept


def test_plan_output_numbers_follow_perch_plans_summary_table():
    from perch_operator.cli.runner import summary_table

    result = SimpleNamespace(placements=[1, 2, 3], coverage=0.9871, mean_uncertainty=0.000123, fitness=0.9512,
                             stage_names=["clean", "segment", "filter"], stage_seconds=[0.2, 1.25, 3.5])
    text = "progress...\n" + summary_table(result) + "\noutputs in out/x/: waypoints.yaml  (9.1 s in all, mission 6.4 s)\n"
    numbers = batch.parse_plan_output(text)
    assert numbers["cameras"] == 3
    assert numbers["coverage_pct"] == pytest.approx(98.7)
    assert numbers["mean_uncertainty_m2"] == pytest.approx(0.000123)
    assert numbers["fitness"] == pytest.approx(0.9512)
    assert numbers["stage_seconds"] == {"clean": 0.2, "segment": 1.25, "filter": 3.5}
    assert numbers["mission_s"] == pytest.approx(6.4)


def test_failure_reason_prefers_the_failed_file_then_perchs_error_line(tmp_path):
    assert batch.failure_reason(tmp_path, "a\nperch: error: x.ply: no faces\n", 1) == "x.ply: no faces"
    assert batch.failure_reason(tmp_path, "Traceback\nKeyError: 3\n", 1) == "perch plan exited with code 1: KeyError: 3"
    _touch(tmp_path / "FAILED", "stage filter failed: no perch surface\n\nfailed at ...")
    assert batch.failure_reason(tmp_path, "perch: error: mission failed", 1) == "stage filter failed: no perch surface"


def test_summary_files_hold_every_row_and_the_totals(tmp_path):
    rows = [batch.ScanRow("b", "/b.ply", "failed", reason="bad | file", wall_s=1.0),
            batch.ScanRow("a", "/a.ply", "ok", cameras=2, coverage_pct=97.5, mean_uncertainty_m2=0.002,
                          stage_seconds={"filter": 1.5}, mission_s=3.0, wall_s=5.0)]
    result = batch.BatchResult(rows, "local", 2, 4.0)
    json_path, md_path = batch.write_summary(tmp_path, result)
    data = json.loads(json_path.read_text())
    assert data["totals"] == {"scans": 2, "ok": 1, "failed": 1, "engine": "local", "workers": 2, "wall_s": 4.0,
                              "sum_of_scan_wall_s": 6.0, "speedup": 1.5}
    assert [r["name"] for r in data["scans"]] == ["a", "b"]
    md = md_path.read_text().splitlines()
    assert md[0].startswith("| scan | status | cameras | coverage % |") and "filter s" in md[0]
    assert md[2].startswith("| a | ok | 2 | 97.5 |") and "| 1.50 |" in md[2]
    assert md[3].startswith("| b | failed |") and md[3].endswith("bad \\| file |")
    assert "1 of 2 scans planned (1 failed) on 2 local worker(s)" in md_path.read_text()


# ---------------------------------------------------------------------------------------------
# Whole batches (each scan a real `perch plan` with its own graph)
# ---------------------------------------------------------------------------------------------

def _corpus(folder: Path) -> Path:
    """Two small generated rooms and a broken mesh, listed in a manifest with a missing file."""
    from perch_common.mesh import save_mesh
    from perch_common.scene_generator import generate_scene

    folder.mkdir(parents=True)
    for seed in (3, 4):
        save_mesh(folder / f"room{seed}.ply", generate_scene(seed, "room").mesh)
    _touch(folder / "broken.ply", "ply\nformat ascii 1.0\nelement vertex 2\nend_header\n0 0\n")
    return _touch(folder / "MANIFEST.tsv", "file\tcameras\nroom3.ply\t2\nbroken.ply\t\nroom4.ply\t1\ngone.obj\t\n")


def _check_rows(result: batch.BatchResult, out: Path) -> None:
    rows = {r.name: r for r in result.rows}
    assert sorted(rows) == ["broken", "gone", "room3", "room4"]
    for name, cameras in (("room3", 2), ("room4", 1)):
        row = rows[name]
        assert row.status == "ok", row.reason
        assert row.cameras == cameras and 0 < row.coverage_pct <= 100
        assert {"segment", "filter", "optimise"} <= set(row.stage_seconds)
        assert (out / name / "waypoints.yaml").is_file() and (out / name / "report.html").is_file()
        assert row.wall_s >= row.mission_s > 0
    assert rows["broken"].status == "failed" and "broken.ply" in rows["broken"].reason
    assert rows["gone"].status == "failed" and "does not exist" in rows["gone"].reason
    summary = json.loads((out / batch.SUMMARY_JSON).read_text())
    assert summary["totals"]["ok"] == 2 and summary["totals"]["failed"] == 2
    assert "| room3 | ok | 2 |" in (out / batch.SUMMARY_MD).read_text()


@pytest.mark.ros
@pytest.mark.slow
def test_local_batch_plans_every_scan_and_reports_each_failure(tmp_path):
    from perch_common.ros import testing

    testing.use_isolated_ros_env()
    manifest = _corpus(tmp_path / "scans")
    settings = batch.PlanSettings(out=str(tmp_path / "out"), options={"--seed": "1"})
    result = batch.run_batch(batch.collect_scans([manifest]), settings, workers=2)
    _check_rows(result, tmp_path / "out")
    assert result.totals["engine"] == "local" and result.totals["workers"] == 2


@pytest.mark.ros
@pytest.mark.slow
def test_batch_on_a_local_multi_process_dask_cluster(tmp_path):
    distributed = pytest.importorskip("distributed", reason="Dask distributed is not installed (requirements.in)")
    from perch_common.ros import testing

    testing.use_isolated_ros_env()   # the workers inherit this domain and profile
    manifest = _corpus(tmp_path / "scans")
    settings = batch.PlanSettings(out=str(tmp_path / "out"), options={"--seed": "1"})
    with distributed.LocalCluster(processes=True, n_workers=2, threads_per_worker=1, dashboard_address=None,
                                  host="127.0.0.1") as cluster:
        worker_pids = {w.pid for w in cluster.workers.values()}
        result = batch.run_batch(batch.collect_scans([manifest]), settings, cluster=cluster.scheduler_address)
    assert len(worker_pids) == 2
    _check_rows(result, tmp_path / "out")
    assert result.totals["engine"] == "dask" and result.totals["workers"] == 2
