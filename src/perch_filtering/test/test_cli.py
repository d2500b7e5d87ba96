"""`perch filter` and `perch bench filter` end to end (in-process)."""

import json

import pytest
from filtering_scenes import Builder, structure

from perch_common.cli import main
from perch_common.mesh import load_mesh, save_mesh
from perch_common.surfaces_file import read_surfaces, write_surfaces


def test_perch_filter_writes_regions_and_removals(tmp_path, capsys):
    b = Builder()
    b.room("room", [[0, 0], [6, 0], [6, 5], [0, 5]], 2.8)
    b.box("table", [2.0, 0.05, 0.0], [3.2, 0.85, 0.75])
    save_mesh(tmp_path / "room.ply", b.mesh())
    surfaces = b.surfaces(structure(b))
    write_surfaces(tmp_path / "surfaces.yaml", surfaces)  # the default of `perch segment -o FOLDER`
    out = tmp_path / "out"
    code = main(["filter", str(tmp_path / "room.ply"), "--surfaces", str(tmp_path / "surfaces.yaml"),
                 "--target-box", "3", "2.5", "1", "2", "1.5", "1.2", "-p", "allow_ceiling=false", "-o", str(out)])
    assert code == 0
    summary = json.loads((out / "regions.json").read_text())
    assert summary["regions"] and all(r["surface_class"] == "wall" for r in summary["regions"])
    assert [r["surface_id"] for r in summary["removals"]] == [s.id for s in surfaces]
    ceiling = summary["removals"][1]
    assert ceiling["orientation"] == pytest.approx(ceiling["area_total"])
    assert summary["removed_m2"]["recovery_height"] > 0
    oriented = read_surfaces(out / "surfaces.json")
    assert [s.surface_class.name for s in oriented] == ["FLOOR", "CEILING", "WALL", "WALL", "WALL", "WALL"]
    regions_mesh = load_mesh(out / "regions.ply")
    total = sum(r["area"] for r in summary["regions"])
    assert regions_mesh.face_areas().sum() == pytest.approx(total, rel=1e-3)
    assert "perch regions" in capsys.readouterr().out


def test_perch_filter_reports_bad_input(tmp_path, capsys):
    b = Builder()
    b.room("room", [[0, 0], [6, 0], [6, 5], [0, 5]], 2.8)
    save_mesh(tmp_path / "room.ply", b.mesh())
    (tmp_path / "bad.json").write_text("{\"surfaces\": [{\"id\": 0}]}")
    with pytest.raises(SystemExit) as info:
        main(["filter", str(tmp_path / "room.ply"), "--surfaces", str(tmp_path / "bad.json"),
              "--target-box", "3", "2.5", "1", "2", "1.5", "1.2", "-o", str(tmp_path / "out")])
    assert info.value.code == 1
    assert "bad.json: malformed surface" in capsys.readouterr().err


def test_bench_filter_scene_prints_scores(capsys):
    code = main(["bench", "filter", "--scene", "1", "--kind", "room", "--repeats", "1", "--json"])
    assert code == 0
    result = json.loads(capsys.readouterr().out)
    assert result["regions"] > 0 and result["seconds"] > 0
    assert set(result["removed_m2"]) == {"orientation", "recovery_height", "perch_window", "obstacle_clearance",
                                         "support", "line_of_sight", "reachability"}
    assert result["precision"] >= 0.99 and result["recall"] >= 0.9
