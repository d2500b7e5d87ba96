"""`perch bench scans` pieces that need no graph: the corpus list from the manifest, the up error and
the calibration table."""

import numpy as np
import pytest

from perch_common.scan_corpus import calibration, up_error
from perch_common.scan_orientations import corpus_scans


def test_up_error_is_the_angle_between_axes_and_the_sign_separately():
    assert up_error(np.array([0.0, 0.0, 2.0]), np.array([0.0, 0.0, 1.0])) == (0.0, True)
    angle, sign = up_error(np.array([0.0, np.sin(np.radians(2)), -np.cos(np.radians(2))]), np.array([0.0, 0.0, 1.0]))
    assert angle == pytest.approx(2.0, abs=1e-3) and not sign


def test_calibration_bins_share_right_and_the_confident_label():
    rows = [{"confidence": c, "confident": c >= 0.5, "right": r}
            for c, r in [(0.1, False), (0.2, True), (0.6, True), (0.95, True), (1.0, True), (0.8, False)]]
    table = calibration(rows)
    by_bin = {b["confidence"]: b for b in table["bins"]}
    assert by_bin["[0.00, 0.25)"] == {"confidence": "[0.00, 0.25)", "cases": 2, "right": 1, "share_right": 0.5}
    assert by_bin["[0.25, 0.50)"]["share_right"] is None
    assert by_bin["[0.90, 1.00]"]["cases"] == 2          # 1.0 falls in the last, closed bin
    assert table["confident"] == {"cases": 4, "right": 3, "share_right": 0.75}
    assert table["not_confident"] == {"cases": 2, "right": 1}


def test_the_corpus_reads_every_manifest_row_with_its_true_up():
    from perch_common.data import shared_file

    manifest = shared_file("meshes", "scans", "MANIFEST.tsv")
    if manifest is None:
        pytest.skip("../shared/data/meshes/scans/MANIFEST.tsv is absent (real scans are optional)")
    rows = manifest.read_text().splitlines()[1:]
    scans = {name: up for name, _, up in corpus_scans()}
    for row in rows:
        name, up = row.split("\t")[:2]
        assert name in scans
        np.testing.assert_allclose(np.linalg.norm(scans[name]), 1.0)
        if up in ("+y", "+z"):
            assert scans[name]["xyz".index(up[1])] == 1.0
    assert scans["realsense_corner.ply"] @ [0, 1, 0] > 0.99   # 'x,y,z' components, normalised


def test_an_extra_manifest_adds_its_scans_and_a_bad_one_is_refused_naming_the_row(tmp_path):
    from perch_common.mesh import Mesh, save_mesh
    from perch_common.scan_corpus import cases, manifest_scans

    vertices = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], np.float64)
    save_mesh(tmp_path / "tet.ply", Mesh(vertices, np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])))
    manifest = tmp_path / "MANIFEST.tsv"
    manifest.write_text("file\tup\tnote\ntet.ply\t0,2,0\tfour faces\n")
    assert [(name, path.name, up.tolist()) for name, path, up in manifest_scans(manifest)] == [
        ("tet.ply", "tet.ply", [0.0, 1.0, 0.0])]
    added = [c for c in cases(only=["tet.ply"], rotations=True, manifests=[manifest])]
    assert [c[1] for c in added] == ["own", "y-up", "y-down", "tilt-25", "tilt-35"]
    assert np.allclose(added[0][3], [0.0, 1.0, 0.0]) and added[1][4] is None  # a rotated copy has no file
    for text, says in (("file\tup\ntet.ply\tsideways\n", "line 2: up 'sideways'"),
                       ("file\tup\nmissing.ply\t+z\n", "line 2: file 'missing.ply' not found"),
                       ("name\taxis\ntet.ply\t+z\n", "must name the columns 'file' and 'up'")):
        manifest.write_text(text)
        with pytest.raises(ValueError, match=says):
            manifest_scans(manifest)
    with pytest.raises(ValueError, match="not a file"):
        manifest_scans(tmp_path / "nowhere.tsv")
