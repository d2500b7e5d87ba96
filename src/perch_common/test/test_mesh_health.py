"""Mesh health counts what makes real-world meshes slow or wrong: soups, duplicates, flipped windings,
needle slivers; `perch mesh info` prints them."""

from __future__ import annotations

import numpy as np
import pytest

from perch_common.mesh import Mesh
from perch_common.mesh_health import inspect_health, needle_mask, winding_flips


@pytest.fixture(scope="module")
def room():
    from perch_common.scene_generator import generate_scene

    return generate_scene(4, "room").mesh


def test_a_generated_room_is_healthy(room):
    health = inspect_health(room)
    assert health.lines() == [] and health.flipped_faces == 0 and health.duplicate_faces == 0


def test_flipped_faces_are_found_and_only_the_minority_turns(room):
    rng = np.random.default_rng(5)
    flipped = rng.random(room.num_faces) < 0.2
    faces = room.faces.copy()
    faces[flipped] = faces[flipped][:, ::-1]
    flips, inconsistent = winding_flips(faces)
    assert inconsistent > 0
    # Turning the chosen faces over restores the original winding exactly (the majority kept it).
    np.testing.assert_array_equal(flips, flipped)
    health = inspect_health(Mesh(room.vertices, faces))
    assert health.flipped_faces == int(flipped.sum())
    assert f"inconsistent windings: {int(flipped.sum()):,} faces face the other way" in health.lines()[0]


def test_a_soup_with_duplicates_and_needles(room):
    rng = np.random.default_rng(6)
    corners = room.vertices[room.faces].reshape(-1, 3)
    faces = np.arange(len(corners)).reshape(-1, 3)
    duplicates = faces[rng.choice(len(faces), 500, replace=False)][:, [1, 2, 0]]
    lo, hi = room.bounds()
    span = hi - lo
    ends = np.stack([rng.uniform(lo, lo + 0.3 * span, (40, 3)), rng.uniform(hi - 0.3 * span, hi, (40, 3))])
    needle_corners = np.concatenate([ends[0], ends[1], (ends[0] + ends[1]) / 2 + 1e-6])
    needles = len(corners) + np.arange(40)[:, None] + np.array([0, 40, 80])
    mesh = Mesh(np.vstack([corners, needle_corners]), np.vstack([faces, duplicates, needles]))
    health = inspect_health(mesh)
    assert health.soup and health.duplicate_faces == 500 and health.needle_slivers == 40
    assert needle_mask(mesh)[-40:].all() and not needle_mask(mesh)[:-40].any()
    lines = health.lines()
    assert lines[0].startswith(f"triangle soup: most of the {mesh.num_faces:,} faces share no vertex")
    assert "500 duplicate faces" in lines[1] and lines[2].startswith("40 needle slivers")


def test_mesh_info_prints_the_health(room, tmp_path, capsys):
    from perch_common.cli import main
    from perch_common.mesh import save_mesh

    faces = room.faces.copy()
    faces[::4] = faces[::4][:, ::-1]
    path = save_mesh(tmp_path / "flipped.ply", Mesh(room.vertices, np.vstack([faces, faces[:30]])))
    assert main(["mesh", "info", str(path)]) == 0
    problems = [line for line in capsys.readouterr().out.splitlines() if "problems:" in line][0]
    assert "30 duplicate faces" in problems and "inconsistent windings" in problems


def _obj_text(vertices: np.ndarray, faces: np.ndarray) -> str:
    return "".join(f"v {x:.6f} {y:.6f} {z:.6f}\n" for x, y, z in vertices) + "".join(
        f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in faces)


def test_an_obj_cut_at_a_line_break_shows_its_unused_vertices(room, tmp_path, capsys):
    """All `v` lines kept, part of the `f` lines lost: the OBJ loader keeps only the vertices faces use,
    so only the file tells (issue 22 finding 10)."""
    from perch_common.cli import main
    from perch_common.mesh import load_mesh

    whole = tmp_path / "whole.obj"
    whole.write_text(_obj_text(room.vertices, room.faces))
    cut = tmp_path / "cut.obj"
    kept = room.faces[: room.num_faces // 5]
    cut.write_text(_obj_text(room.vertices, kept))
    unused = room.num_vertices - len(np.unique(kept))
    assert unused > 0.2 * room.num_vertices
    assert inspect_health(load_mesh(whole), path=whole).lines() == []
    health = inspect_health(load_mesh(cut), path=cut)
    assert (health.unreferenced_vertices, health.vertices) == (unused, room.num_vertices)
    share = round(100 * unused / room.num_vertices)
    expected = (f"{unused:,} of {room.num_vertices:,} vertices ({share} %) are used by no face: the file may be "
                "cut short or faces lost")
    assert expected in health.lines()
    assert main(["mesh", "info", str(cut)]) == 0
    assert expected in capsys.readouterr().out
    # A mesh (a PLY, a stage request) that kept its unused vertices shows them without a file.
    assert expected in inspect_health(Mesh(room.vertices, kept)).lines()
    # A few unused vertices, as real scans have (up to 7.8 %), are not a problem.
    extra = room.vertices[: room.num_vertices // 10]
    assert inspect_health(Mesh(np.vstack([room.vertices, extra]), room.faces)).lines() == []
