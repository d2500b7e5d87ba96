"""numpy <-> message conversions: exact round trips and error detection."""

import array

import numpy as np
import pytest

from perch_common.mesh import Mesh, MeshError
from perch_common.ros import conversions as conv
from perch_common.target import TargetVolume
from perch_common.types import CameraPlacement, ExclusionZone, FilterRemoval, PerchRegion, PlaneFrame, Surface, SurfaceClass


def random_mesh(seed=0, faces=1000) -> Mesh:
    rng = np.random.default_rng(seed)
    v = rng.normal(size=(600, 3)).astype(np.float32).astype(np.float64)  # float32-exact values
    return Mesh(v, rng.integers(0, 600, (faces, 3)), rng.integers(0, 256, (600, 3)),
                rng.normal(size=(600, 3)).astype(np.float32), frame_id="odom")


def test_mesh_round_trip_is_exact():
    m = random_mesh()
    msg = conv.mesh_to_msg(m)
    assert isinstance(msg.vertices, array.array) and len(msg.triangles) == 3000
    back = conv.mesh_from_msg(msg)
    assert np.array_equal(back.vertices, m.vertices) and np.array_equal(back.faces, m.faces)
    assert np.array_equal(back.vertex_colors, m.vertex_colors)
    assert np.array_equal(back.vertex_normals, m.vertex_normals.astype(np.float32))
    assert back.frame_id == "odom"


def test_mesh_message_inconsistencies_are_reported():
    msg = conv.mesh_to_msg(random_mesh())
    msg.vertices = msg.vertices[:-1]
    with pytest.raises(MeshError, match="multiples of 3"):
        conv.mesh_from_msg(msg)
    msg = conv.mesh_to_msg(random_mesh())
    msg.vertex_colors = msg.vertex_colors[:-3]
    with pytest.raises(MeshError, match="vertex_colors has 599 entries for 600 vertices"):
        conv.mesh_from_msg(msg)


def test_pose_round_trip():
    from scipy.spatial.transform import Rotation
    pose = np.eye(4)
    pose[:3, :3] = Rotation.from_euler("xyz", [0.3, -1.1, 2.0]).as_matrix()
    pose[:3, 3] = [1.5, -2.0, 0.25]
    assert np.allclose(conv.pose_matrix(conv.pose_msg(pose)), pose, atol=1e-12)


def frame() -> PlaneFrame:
    return PlaneFrame.from_normal(np.array([1.0, 2.0, 1.5]), np.array([1.0, 0, 0]))


def test_surface_and_polygons_round_trip():
    rings = [[np.array([[0, 0], [2, 0], [2, 1], [0, 1.0]]), np.array([[0.5, 0.25], [1, 0.25], [1, 0.5]])],
             [np.array([[3, 0], [4, 0], [4, 1.0]])]]
    s = Surface(4, frame(), 2.5, np.array([3, 9, 27]), SurfaceClass.WALL, 0.004, np.array([0.25, 0.5, 0.75]), rings)
    back = conv.surface_from_msg(conv.surface_to_msg(s))
    assert back.id == 4 and back.surface_class == SurfaceClass.WALL and back.area == pytest.approx(2.5)
    assert np.array_equal(back.face_indices, [3, 9, 27])
    assert np.allclose(back.frame.normal, s.frame.normal) and np.allclose(back.mean_color, s.mean_color)
    assert [len(p) for p in back.boundary] == [2, 1]
    for poly, poly_back in zip(rings, back.boundary):
        for ring, ring_back in zip(poly, poly_back):
            assert np.allclose(ring, ring_back)


def test_region_removal_placement_exclusion_round_trip():
    region = PerchRegion(2, 4, SurfaceClass.CEILING, frame(), [[np.array([[0, 0], [1, 0], [0, 1.0]])]],
                         random_mesh(1, 10), 0.5)
    back = conv.region_from_msg(conv.region_to_msg(region))
    assert (back.id, back.source_surface, back.surface_class) == (2, 4, SurfaceClass.CEILING)
    assert np.array_equal(back.mesh.faces, region.mesh.faces)
    removal = FilterRemoval(4, 10.0, 1.0, 2.0, 0.5, 0.25, 0.125, 0.0625, 6.0625)
    assert conv.removal_from_msg(conv.removal_to_msg(removal)) == removal
    placement = CameraPlacement(1, 2, np.eye(4), np.eye(4), 0.5, -0.25, 1.0, 0.1, 0.6, 0.8, 0.002)
    back_p = conv.placement_from_msg(conv.placement_to_msg(placement))
    assert back_p.pan == 0.5 and back_p.mean_uncertainty == 0.002 and np.allclose(back_p.drone_pose, np.eye(4))
    zone = conv.exclusion_from_msg(conv.exclusion_to_msg(ExclusionZone(np.array([1.0, 2, 3]), 0.3)))
    assert np.allclose(zone.center, [1, 2, 3]) and zone.radius == 0.3


def test_target_round_trip():
    box = TargetVolume(center=[1, 2, 0.7], size=[2, 1, 1.2])
    back = conv.target_from_msg(conv.target_to_msg(box))
    assert np.allclose(back.center, box.center) and np.allclose(back.size, box.size)
    foot = TargetVolume(footprint=np.array([[0, 0], [2, 0], [2, 1], [0, 1.0]]), base=0.1, height=1.2)
    back = conv.target_from_msg(conv.target_to_msg(foot))
    assert back.volume() == pytest.approx(2.4) and back.base == pytest.approx(0.1)
    from perch_interfaces.msg import TargetVolume as TargetMsg
    assert conv.target_from_msg(TargetMsg()) is None


@pytest.mark.parametrize("start", range(6))
def test_concave_footprint_keeps_its_shape(start):
    ell = np.roll(np.array([[3, 1], [1, 1], [1, 3], [0, 3.0], [0, 0], [3, 0]]), start, axis=0)
    back = conv.target_from_msg(conv.target_to_msg(TargetVolume(footprint=ell, base=0.0, height=1.0)))
    assert back.volume() == pytest.approx(5.0)
    assert not back.contains(np.array([[2.0, 2.0, 0.5]]))[0]  # the L's missing corner
