"""`perch filter` runs under the stage nodes' work budget: over it, one line naming the budget and the fix."""

import pytest
from filtering_scenes import Builder, structure

from perch_common.cli import main
from perch_common.mesh import save_mesh
from perch_common.surfaces_file import write_surfaces


def test_perch_filter_over_its_work_budget_stops_with_the_reason(tmp_path, capsys, monkeypatch):
    b = Builder()
    b.room("room", [[0, 0], [6, 0], [6, 5], [0, 5]], 2.8)
    mesh = b.mesh()
    save_mesh(tmp_path / "room.ply", mesh)
    write_surfaces(tmp_path / "surfaces.yaml", b.surfaces(structure(b)))
    monkeypatch.setenv("PERCH_WORK_BUDGET", "0.001")   # s: over at the filter's first checkpoint
    with pytest.raises(SystemExit) as info:
        main(["filter", str(tmp_path / "room.ply"), "--surfaces", str(tmp_path / "surfaces.yaml"),
              "--target-box", "3", "2.5", "1", "2", "1.5", "1.2", "-o", str(tmp_path / "out")])
    assert info.value.code == 1
    err = capsys.readouterr().err
    assert f"perch filter exceeded its work budget of 0.001 s for {mesh.num_faces:,} faces: the mesh is likely " \
           "a triangle soup; run `perch mesh info`; if the input is sound, run again with PERCH_WORK_BUDGET=60" in err
    assert "Traceback" not in err
    assert not (tmp_path / "out" / "regions.json").exists()
