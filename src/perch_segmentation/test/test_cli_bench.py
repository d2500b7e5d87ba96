"""`perch segment` writes surfaces and a coloured mesh; the benchmark's helpers and JSON."""

import json

import numpy as np
import pytest
import yaml

from perch_common.cli import main
from perch_common.mesh import load_mesh, save_mesh
from perch_segmentation.bench import subdivide
from perch_segmentation.testing import box_room


def test_segment_command_writes_surfaces_and_coloured_mesh(tmp_path, capsys):
    mesh, plane = box_room(door=True)
    source = save_mesh(tmp_path / "room.ply", mesh)
    out = tmp_path / "result" / "room.yaml"
    assert main(["segment", str(source), "-o", str(out), "--png", str(tmp_path / "room.png")]) == 0
    document = yaml.safe_load(out.read_text())
    surfaces = document["surfaces"]
    assert len(surfaces) == 7 and [s["id"] for s in surfaces] == list(range(7))
    door = [s for s in surfaces if s["mean_color"][0] < 0.5]
    assert len(door) == 1 and door[0]["area"] == pytest.approx(1.8, rel=0.15)
    floor = max(surfaces, key=lambda s: s["frame"]["normal"][2])
    assert floor["area"] == pytest.approx(12.0, rel=0.01) and len(floor["face_indices"]) == 2400
    assert len(floor["boundary"][0][0]) >= 4  # polygon 0, outer ring, points [u, v]
    coloured = load_mesh(tmp_path / "result" / "room_segments.ply")
    assert coloured.num_faces == mesh.num_faces
    assert (tmp_path / "room.png").stat().st_size > 10000
    assert "7 surfaces" in capsys.readouterr().out


def test_segment_command_json_folder_and_overrides(tmp_path):
    mesh, _ = box_room(door=True)
    source = save_mesh(tmp_path / "room.ply", mesh)
    assert main(["segment", str(source), "-o", str(tmp_path / "out.json"), "-p", "use_color:=false"]) == 0
    assert len(json.loads((tmp_path / "out.json").read_text())["surfaces"]) == 6  # door merged into its wall
    assert main(["segment", str(source), "-o", str(tmp_path / "folder")]) == 0
    assert (tmp_path / "folder" / "surfaces.yaml").is_file() and (tmp_path / "folder" / "segments.ply").is_file()


def test_segment_command_rejects_unknown_parameters(tmp_path, capsys):
    source = save_mesh(tmp_path / "room.ply", box_room()[0])
    with pytest.raises(SystemExit):
        main(["segment", str(source), "-o", str(tmp_path / "x.yaml"), "-p", "theta:=3"])
    assert "has no parameter 'theta'" in capsys.readouterr().err


def test_subdivide_quadruples_faces_and_keeps_geometry():
    mesh, _ = box_room(size=(2.0, 1.0, 1.0), cell=0.5)
    fine = subdivide(mesh)
    assert fine.num_faces == 4 * mesh.num_faces
    assert fine.face_areas().sum() == pytest.approx(mesh.face_areas().sum())
    np.testing.assert_allclose(fine.bounds(), mesh.bounds())
    assert fine.vertex_colors.shape == (fine.num_vertices, 3)


@pytest.mark.parametrize("baseline", ["patches", "ransac"])
def test_bench_scene_prints_accuracy_and_baseline(tmp_path, capsys, baseline):
    assert main(["bench", "segment", "--scene", "0", "--kind", "room", "--repeats", "1",
                 "--baseline", baseline, "--out", str(tmp_path), "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    for key in ("faces", "seconds", "peak_rss_mb", "surfaces", "plane_recall", "plane_precision", "normal_error_deg"):
        assert key in result
    assert result["plane_recall"] >= 0.95
    assert result["baseline"]["seconds"] > 0 and "plane_recall" in result["baseline"]
    assert (tmp_path / "scene_room_0.png").is_file()


def test_bench_reports_a_failed_baseline_and_still_prints_its_own_figures(tmp_path, capsys):
    """Scene 11 is the one where Open3D's detect_planar_patches dies in Qhull (QH6154)."""
    assert main(["bench", "segment", "--scene", "11", "--repeats", "1", "--no-render", "--out", str(tmp_path),
                 "--json"]) == 0
    captured = capsys.readouterr()
    result = json.loads(captured.out)
    assert "Qhull" in result["baseline"]["error"] and "seconds" not in result["baseline"]
    assert result["surfaces"] > 10 and result["plane_recall"] >= 0.9
    assert "baseline patches failed" in captured.err


@pytest.mark.parametrize("suffix", [".yaml", ".json"])
def test_surfaces_file_round_trips(tmp_path, suffix):
    from perch_common.surfaces_file import read_surfaces, write_surfaces
    from perch_common.types import SurfaceClass
    from perch_segmentation.core import SegmentationConfig, segment_mesh

    surfaces = segment_mesh(box_room(door=True)[0], SegmentationConfig()).surfaces
    surfaces[0].surface_class = SurfaceClass.WALL
    back = read_surfaces(write_surfaces(tmp_path / f"s{suffix}", surfaces))
    assert [s.id for s in back] == [s.id for s in surfaces] and back[0].surface_class == SurfaceClass.WALL
    for a, b in zip(surfaces, back):
        np.testing.assert_array_equal(a.face_indices, b.face_indices)
        np.testing.assert_allclose(a.frame.normal, b.frame.normal)
        assert b.area == pytest.approx(a.area) and len(b.boundary) == len(a.boundary)
        np.testing.assert_allclose(b.boundary[0][0], a.boundary[0][0], atol=1e-5)


def test_read_surfaces_names_the_bad_file(tmp_path):
    from perch_common.surfaces_file import read_surfaces

    (tmp_path / "bad.yaml").write_text("surfaces: [{id: 0}]")
    with pytest.raises(ValueError, match="bad.yaml: malformed surface"):
        read_surfaces(tmp_path / "bad.yaml")
