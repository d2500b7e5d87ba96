"""The clean stage repairs pathological real-world meshes instead of planning slowly on them: a jittered
triangle soup is welded, duplicates and needle slivers go, flipped windings are made consistent; an
ordinary mesh is left as it was; each repair is said in the report."""

from __future__ import annotations

import numpy as np
import pytest

from perch_common.mesh import Mesh
from perch_common.mesh_health import inspect_health, winding_flips
from perch_reconstruction.cleaning import clean_mesh_with_report
from perch_reconstruction.config import ReconstructionConfig

CONFIG = ReconstructionConfig(target_faces=0, gravity_align=False)


@pytest.fixture(scope="module")
def room():
    from perch_common.scene_generator import generate_scene

    return generate_scene(4, "room").mesh


def _pathological(room: Mesh, seed: int = 3) -> tuple[Mesh, int]:
    """The issue's mesh in small: a triangle soup (corners jittered by 50 um), 30 % of faces flipped,
    duplicates, and needles across the room. Returns it and its needle count."""
    rng = np.random.default_rng(seed)
    faces = room.faces.copy()
    flipped = rng.random(len(faces)) < 0.3
    faces[flipped] = faces[flipped][:, ::-1]
    faces = np.vstack([faces, faces[rng.choice(len(faces), len(faces) // 6, replace=False)][:, [1, 2, 0]]])
    corners = room.vertices[faces].reshape(-1, 3) + 5e-5 * rng.standard_normal((3 * len(faces), 3))
    lo, hi = room.bounds()
    span, count = hi - lo, 50
    a, b = rng.uniform(lo, lo + 0.3 * span, (count, 3)), rng.uniform(hi - 0.3 * span, hi, (count, 3))
    needles = np.concatenate([a, b, (a + b) / 2 + 1e-6])
    soup = np.arange(3 * len(faces)).reshape(-1, 3)
    extra = 3 * len(faces) + np.arange(count)[:, None] + np.array([0, count, 2 * count])
    order = rng.permutation(len(soup) + count)
    return Mesh(np.vstack([corners, needles]), np.vstack([soup, extra])[order]), count


def test_an_ordinary_mesh_is_not_changed_by_the_repairs(room):
    cleaned, report = clean_mesh_with_report(room, None, CONFIG)
    assert cleaned.num_faces == room.num_faces and report.warnings == []
    np.testing.assert_array_equal(cleaned.faces, room.faces)


def test_a_jittered_soup_with_flips_duplicates_and_needles_is_repaired(room):
    mesh, needles = _pathological(room)
    cleaned, report = clean_mesh_with_report(mesh, None, CONFIG)
    text = "; ".join(report.warnings)
    assert "repaired a triangle soup: corners welded at" in text
    assert "duplicate or degenerate faces" in text
    assert f"removed {needles} needle slivers" in text
    assert "re-wound" in text and "inconsistent windings" in text
    # What is left is the room again: its face count, one consistent winding, nothing pathological.
    assert cleaned.num_faces == pytest.approx(room.num_faces, rel=0.01)
    assert winding_flips(cleaned.faces)[1] == 0
    assert inspect_health(cleaned).lines() == []
    assert cleaned.face_areas().sum() == pytest.approx(room.face_areas().sum(), rel=0.01)


def test_the_clean_stage_says_when_the_mesh_falls_apart(room):
    """Pieces too small to keep are said, not dropped silently (a soup that could not be welded)."""
    rng = np.random.default_rng(8)
    corners = room.vertices[room.faces].reshape(-1, 3)
    corners += 0.05 * rng.standard_normal(corners.shape)   # corners 5 cm apart: no weld joins them
    mesh = Mesh(corners, np.arange(len(corners)).reshape(-1, 3))
    try:
        _, report = clean_mesh_with_report(mesh, None, CONFIG)
    except ValueError as exc:   # nothing left at all: MeshError naming min_piece_diameter
        assert "min_piece_diameter" in str(exc)
        return
    assert any("falls apart into fragments" in w for w in report.warnings), report.warnings


def test_the_clean_stage_says_when_most_vertices_lost_their_faces(room):
    """A mesh that lost faces (a file cut short) keeps vertices no face uses: the clean report says so."""
    kept = room.faces[: room.num_faces // 5]
    unused = room.num_vertices - len(np.unique(kept))
    _, report = clean_mesh_with_report(Mesh(room.vertices, kept), None, CONFIG)
    assert any(w.startswith(f"{unused:,} of {room.num_vertices:,} vertices") and "used by no face" in w
               for w in report.warnings), report.warnings
