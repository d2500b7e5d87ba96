"""The same room turned by far less than a scan's noise is segmented into the same surfaces.

Turns of 0.02 deg are what two up estimates of one scan differ by; an answer that changes on such
a turn (the apartment lost a 0.6 m^2 patch to the floor, and a perch with it) is not one to trust.
"""

from __future__ import annotations

import numpy as np
import pytest

from perch_common.data import shared_file
from perch_common.mesh import Mesh
from perch_common.scene_generator import generate_scene
from perch_segmentation import stats as st
from perch_segmentation.core import SegmentationConfig, reliable_face_normals, segment_mesh

TURNS_DEG = (0.02, -0.02, 0.1, -0.1)


def turned(mesh: Mesh, degrees: float, axis) -> Mesh:
    """`mesh` turned by `degrees` about the horizontal `axis` through its box centre (Rodrigues)."""
    k = np.asarray(axis, float) / np.linalg.norm(axis)
    cross = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    a = np.radians(degrees)
    matrix = np.eye(4)
    matrix[:3, :3] = np.eye(3) + np.sin(a) * cross + (1.0 - np.cos(a)) * cross @ cross
    centre = 0.5 * (mesh.vertices.min(axis=0) + mesh.vertices.max(axis=0))
    matrix[:3, 3] = centre - matrix[:3, :3] @ centre
    return mesh.transformed(matrix)


def with_double_sided_faces(mesh: Mesh, share: float, seed: int) -> Mesh:
    """`mesh` plus a reversed copy of a seeded share of its faces (two-sided geometry, as exported
    scans have): those faces' windings cancel exactly in one frame and to float residue in another."""
    rng = np.random.default_rng(seed)
    chosen = rng.choice(mesh.num_faces, int(share * mesh.num_faces), replace=False)
    faces = np.concatenate([mesh.faces, mesh.faces[chosen][:, ::-1]])
    return Mesh(vertices=mesh.vertices, faces=faces, vertex_colors=mesh.vertex_colors)


def surfaces_of(mesh: Mesh) -> tuple[list[float], list[int], np.ndarray]:
    """Areas, classes (normal's main axis and sign, in the mesh's own frame) and face labels."""
    result = segment_mesh(mesh, SegmentationConfig())
    areas = [s.area for s in result.surfaces]
    kinds = [int(np.argmax(np.abs(s.frame.normal))) * 2 + int(s.frame.normal[np.argmax(np.abs(s.frame.normal))] > 0)
             for s in result.surfaces]
    return areas, kinds, result.face_labels


def assert_same_surfaces(mesh: Mesh, axes=((1.0, 0.0, 0.0), (0.0, 1.0, 0.0))) -> None:
    """Count, classes and areas (1 cm^2) equal at 0 and at every small turn about each axis."""
    areas, kinds, _ = surfaces_of(mesh)
    for axis in axes:
        for degrees in TURNS_DEG:
            t_areas, t_kinds, _ = surfaces_of(turned(mesh, degrees, axis))
            where = f"turned {degrees:+} deg about {axis}"
            assert len(t_areas) == len(areas), f"{where}: {len(t_areas)} surfaces, {len(areas)} unturned"
            assert t_kinds == kinds, where
            np.testing.assert_allclose(t_areas, areas, atol=1e-4, err_msg=where)


def test_cancelled_winding_is_zero_in_every_frame():
    # One triangle both ways round: the summed winding is exactly 0 or ~1e-17, never a direction.
    table = np.zeros((2, st.NORMAL.stop))
    table[:, st.AREA] = 0.5
    table[0, st.NORMAL] = (0.0, 0.0, 0.0)
    table[1, st.NORMAL] = (3e-17, -1e-17, 2e-17)
    np.testing.assert_array_equal(st.winding_normals(table), np.zeros((2, 3)))
    table[1, st.NORMAL] = (0.0, 0.0, 1e-3)  # a real, if lopsided, winding keeps its direction
    np.testing.assert_allclose(st.winding_normals(table)[1], (0.0, 0.0, 1.0))


def test_sliver_faces_have_no_normal():
    # A 10 cm triangle 1 um high (float rounding made it a triangle), and a 2 um high triangle of 1 cm.
    triangles = np.array([[[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [0.05, 1e-6, 0.0]],
                          [[0.0, 0.0, 0.0], [0.01, 0.0, 0.0], [0.005, 0.0, 2e-6]],
                          [[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [0.0, 0.1, 0.0]]])
    normals = np.array([[0.0, 0.0, 1.0], [0.0, -1.0, 0.0], [0.0, 0.0, 1.0]])
    np.testing.assert_array_equal(reliable_face_normals(triangles, normals),
                                  [[0.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, 1.0]])


def test_generated_room_with_double_sided_faces_keeps_its_surfaces_when_turned():
    scene = generate_scene(3, "room", noise=0.005, holes=4)
    assert_same_surfaces(with_double_sided_faces(scene.mesh, 0.3, seed=7))


def test_generated_room_keeps_its_surfaces_when_turned():
    assert_same_surfaces(generate_scene(3, "room", noise=0.005, holes=4).mesh, axes=((1.0, 0.0, 0.0),))


@pytest.mark.data
def test_real_apartment_keeps_its_surfaces_when_turned():
    path = shared_file("meshes", "apartment.ply")
    if path is None:
        pytest.skip("../shared/data not found: meshes/apartment.ply")
    from perch_common.mesh import load_mesh

    mesh = load_mesh(path)
    areas, _, labels = surfaces_of(mesh)
    assert len(areas) >= 10
    assert_same_surfaces(mesh, axes=((1.0, 0.0, 0.0),))
    # and face for face: the 0.6 m^2 low patch stays apart from the floor at +0.02 deg
    np.testing.assert_array_equal(surfaces_of(turned(mesh, 0.02, (1.0, 0.0, 0.0)))[2], labels)


@pytest.mark.data
def test_real_hololens_room_keeps_its_surfaces_when_turned():
    # Its slivers (zero-area faces and the line-like clusters step 1 leaves of them) had normals of
    # float residue: 8-73 faces and up to 0.05 m^2 moved between surfaces on these turns.
    path = shared_file("meshes", "scans", "holo1_room_window.obj")
    if path is None:
        pytest.skip("../shared/data not found: meshes/scans/holo1_room_window.obj")
    from perch_common.mesh import load_mesh

    mesh = load_mesh(path)
    _, _, labels = surfaces_of(mesh)
    for degrees in TURNS_DEG:
        np.testing.assert_array_equal(surfaces_of(turned(mesh, degrees, (1.0, 0.0, 0.0)))[2], labels,
                                      err_msg=f"turned {degrees:+} deg")
