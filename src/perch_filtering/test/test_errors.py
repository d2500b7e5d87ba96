"""Malformed input raises precise errors (the node turns them into success=false replies)."""

from __future__ import annotations

import copy

import numpy as np
import pytest
from filtering_scenes import Builder, structure

from perch_common.mesh import Mesh, MeshError
from perch_common.target import TargetVolume
from perch_filtering.core import FilterConfig, filter_surfaces

UP = np.array([0.0, 0.0, 1.0])
TARGET = TargetVolume(center=[3.0, 2.5, 1.0], size=[2.0, 1.5, 1.2])


@pytest.fixture(scope="module")
def room():
    b = Builder()
    b.room("room", [[0, 0], [6, 0], [6, 5], [0, 5]], 2.8)
    return b.mesh(), b.surfaces(structure(b))


def check(room, message, mesh=None, surfaces=None, target=TARGET, up=UP, config=None, error=ValueError):
    mesh = room[0] if mesh is None else mesh
    surfaces = copy.deepcopy(room[1]) if surfaces is None else surfaces
    with pytest.raises(error) as info:
        filter_surfaces(mesh, surfaces, target, up, config)
    assert message in str(info.value)


def test_bad_meshes(room):
    check(room, "environment mesh: mesh is empty", mesh=Mesh(np.zeros((0, 3)), np.zeros((0, 3))), error=MeshError)
    bad = Mesh(room[0].vertices.copy(), room[0].faces.copy())
    bad.vertices[3] = np.nan
    check(room, "vertices are NaN or infinite", mesh=bad, error=MeshError)


def test_bad_surfaces(room):
    surfaces = copy.deepcopy(room[1])
    surfaces[2].face_indices = np.array([0, 10_000])
    check(room, f"surface {surfaces[2].id} (input #2): face indices 0..10000 outside the mesh's 0..", surfaces=surfaces)
    surfaces = copy.deepcopy(room[1])
    surfaces[1].frame.normal = np.array([np.nan, 0, 1])
    check(room, "surface 1 (input #1): frame has NaN", surfaces=surfaces)
    surfaces = copy.deepcopy(room[1])
    surfaces[3].id = surfaces[0].id
    check(room, "duplicate surface id", surfaces=surfaces)
    surfaces = copy.deepcopy(room[1])
    surfaces[0].boundary, surfaces[0].face_indices = [], np.zeros(0, np.int64)
    check(room, "has neither a boundary nor faces", surfaces=surfaces)
    surfaces = copy.deepcopy(room[1])
    surfaces[0].frame.normal = np.array([0, 0, 2.0])
    check(room, "frame normal has length 2.0000", surfaces=surfaces)
    # Indices in range but of another mesh (or another surface): its faces lie away from its plane.
    surfaces = copy.deepcopy(room[1])
    floor = next(k for k, s in enumerate(surfaces) if abs(s.frame.normal @ UP) > 0.9 and s.frame.origin @ UP < 0.5)
    ceiling = next(k for k, s in enumerate(surfaces) if abs(s.frame.normal @ UP) > 0.9 and s.frame.origin @ UP > 2.0)
    surfaces[floor].face_indices = surfaces[ceiling].face_indices.copy()
    check(room, f"surface {surfaces[floor].id} (input #{floor}): its faces lie 2.80 m (median) from its plane",
          surfaces=surfaces)


def test_bad_target_and_up(room):
    check(room, "target volume: none given", target=None)
    far = TargetVolume(center=[30.0, 0, 1], size=[1, 1, 1])
    check(room, "target volume: its centre [30.0, 0.0, 1.0] lies outside the mesh bounds", target=far)
    check(room, "up axis [0.0, 0.0, 0.0] must be a finite, non-zero 3-vector", up=np.zeros(3))


def test_absurd_parameters(room):
    check(room, "raster_density=0.0 must be > 0", config=FilterConfig(raster_density=0.0))
    check(room, "raster_density=5000.0 px/m is absurd", config=FilterConfig(raster_density=5000.0))
    check(room, "class_angle_deg=60.0 must be in (0, 45)", config=FilterConfig(class_angle_deg=60.0))
    check(room, "standoff=0.0 m must be at least drone_radius=0.35 m", config=FilterConfig(standoff=0.0))
    check(room, "exceeds max_voxels=1000", config=FilterConfig(max_voxels=1000))
    check(room, "exceeds max_cells_per_surface=100", config=FilterConfig(max_cells_per_surface=100))


def test_no_surfaces_is_a_valid_empty_answer(room):
    result = filter_surfaces(room[0], [], TARGET, UP)
    assert result.regions == [] and result.removals == []
    assert result.message == "no surfaces given: nothing to filter"
