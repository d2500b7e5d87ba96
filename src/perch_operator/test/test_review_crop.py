"""Surface review crops: a reviewed surface trimmed to the operator's box (faces, outline, area, origin)."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from perch_common.mesh import Mesh
from perch_common.polygons import faces_outline, to_shapely
from perch_common.types import PlaneFrame, Surface
from perch_operator.coordinator.crop import Box
from perch_operator.coordinator.review import (
    ReviewDesk,
    ReviewError,
    box_section,
    crop_surface,
    cropped_surfaces,
    review_crops,
)


def wall(width: float = 4.0, height: float = 2.0, cell: float = 0.25) -> tuple[Mesh, Surface]:
    """A wall in the plane y = 0 facing -y, x in [0, width], z in [0, height], split in square cells,
    and the surface segmentation would give it (all its faces; outline from the faces)."""
    xs, zs = np.arange(0, width + 1e-9, cell), np.arange(0, height + 1e-9, cell)
    grid = np.array([[x, 0.0, z] for z in zs for x in xs])
    nx = len(xs)
    faces = []
    for j in range(len(zs) - 1):
        for i in range(nx - 1):
            a, b, c, d = j * nx + i, j * nx + i + 1, (j + 1) * nx + i + 1, (j + 1) * nx + i
            faces += [[a, b, c], [a, c, d]]
    mesh = Mesh(grid, np.array(faces, np.int64))
    frame = PlaneFrame(np.array([width / 2, 0.0, height / 2]), np.array([1.0, 0, 0]), np.array([0, 0, 1.0]),
                       np.array([0, -1.0, 0]))
    surface = Surface(id=3, frame=frame, area=width * height, face_indices=np.arange(len(faces)),
                      rms_distance=0.002, mean_color=np.array([0.5, 0.4, 0.3]),
                      boundary=faces_outline(frame, mesh.triangles()))
    return mesh, surface


def test_a_crop_keeps_the_faces_inside_the_box_and_cuts_the_outline():
    mesh, surface = wall()
    # the left half of the wall is good (x < 2 m); the box is thick across the wall, as an operator draws it
    box = Box(center=[1.0, 0.0, 1.0], size=[2.0, 0.4, 3.0])
    cropped = crop_surface(surface, mesh, box)
    centroids = mesh.face_centroids()[cropped.face_indices]
    assert len(cropped.face_indices) == len(surface.face_indices) // 2
    assert (centroids[:, 0] < 2.0).all()
    assert cropped.area == pytest.approx(4.0, abs=1e-9)
    np.testing.assert_allclose(cropped.frame.origin, [1.0, 0.0, 1.0], atol=1e-9)   # the kept part's centroid
    np.testing.assert_allclose(cropped.frame.normal, surface.frame.normal)
    outline = to_shapely(cropped.boundary)
    assert outline.area == pytest.approx(4.0, abs=1e-6)
    np.testing.assert_allclose(outline.bounds, [-1.0, -1.0, 1.0, 1.0], atol=1e-9)   # around the new origin
    assert cropped.id == surface.id and cropped.rms_distance == surface.rms_distance
    assert len(surface.face_indices) == 256   # the input surface is untouched


def test_a_turned_box_crops_along_its_own_axes():
    mesh, surface = wall()
    # a box turned 45 deg about y (across the wall): on the wall it keeps a diamond around (2, 1)
    turned = Rotation.from_euler("y", 45, degrees=True).as_matrix()
    box = Box(center=[2.0, 0.0, 1.0], size=[np.sqrt(2), 0.3, np.sqrt(2)], rotation=turned)
    section = box_section(surface.frame, box)
    import shapely

    assert shapely.Polygon(section).area == pytest.approx(2.0, abs=1e-9)   # the diamond, 2 m^2
    cropped = crop_surface(surface, mesh, box)
    local = (mesh.face_centroids()[cropped.face_indices] - box.center) @ box.rotation
    assert (np.abs(local[:, [0, 2]]) <= np.sqrt(2) / 2 + 1e-9).all()
    assert to_shapely(cropped.boundary).area == pytest.approx(2.0, abs=1e-6)


def test_a_box_beside_the_surface_is_refused_naming_it():
    mesh, surface = wall()
    with pytest.raises(ValueError, match="surface 3: none of its 256 faces lies inside the crop box"):
        crop_surface(surface, mesh, Box(center=[1.0, 2.0, 1.0], size=[1.0, 0.4, 1.0]))
    assert len(box_section(surface.frame, Box(center=[1.0, 2.0, 1.0], size=[1.0, 0.4, 1.0]))) == 0


def test_cropped_surfaces_take_boxes_in_the_input_frame():
    from perch_common.ros.conversions import surface_from_msg, surface_to_msg

    mesh, surface = wall()   # the gravity-aligned frame
    other = surface_to_msg(Surface(id=4, frame=surface.frame, area=1.0, face_indices=np.array([0, 1])))
    to_aligned = np.eye(4)
    to_aligned[:3, :3] = Rotation.from_euler("x", 90, degrees=True).as_matrix()   # input y-up -> aligned z-up
    # the operator's box in the input frame: aligned (1, 0, 1) is input (1, 1, 0), sizes along input x, z, y
    box = Box(center=to_aligned[:3, :3].T @ [1.0, 0.0, 1.0], size=[2.0, 3.0, 0.4])
    out = cropped_surfaces([surface_to_msg(surface), other], {3: box}, mesh, to_aligned)
    assert out[1] is other
    cropped = surface_from_msg(out[0])
    assert cropped.area == pytest.approx(4.0, abs=1e-5)
    assert (mesh.face_centroids()[cropped.face_indices][:, 0] < 2.0).all()


def test_the_review_desk_checks_crops():
    from perch_interfaces import msg as pm
    from perch_interfaces import srv

    _, surface = wall()
    desk = ReviewDesk()
    review = desk.open([3, 5], {3: (surface.frame, surface.boundary)})
    left = Box(center=[1.0, 0.0, 1.0], size=[2.0, 0.4, 3.0])
    with pytest.raises(ReviewError, match=r"surface\(s\) \[9\] are not part of review 1"):
        desk.decide(review, [], {9: left})
    with pytest.raises(ReviewError, match=r"surface\(s\) \[3\] are both rejected and cropped"):
        desk.decide(review, [3], {3: left})
    with pytest.raises(ReviewError, match="the crop box for surface 3 .* does not overlap it"):
        desk.decide(review, [], {3: Box(center=[9.0, 0.0, 1.0], size=[1.0, 0.4, 1.0])})
    assert desk.crops(review) == {}
    assert desk.decide(review, [5], {3: left}) == {5}
    assert list(desk.crops(review)) == [3]
    np.testing.assert_allclose(desk.crops(review)[3].center, [1.0, 0.0, 1.0])
    # the service request: one box per cropped id, each a real box
    request = srv.ReviewSurfaces.Request(review_id=1, cropped_surface_ids=[3, 5])
    request.crop_boxes = [pm.OrientedBox()]
    with pytest.raises(ValueError, match="2 cropped surface id.* but 1 crop box"):
        review_crops(request)
    request.cropped_surface_ids = [3]
    request.crop_boxes[0].pose.orientation.w = 1.0
    with pytest.raises(ValueError, match="crop box for surface 3: crop box size must be positive"):
        review_crops(request)


def test_the_command_line_crop_spec():
    from perch_common.errors import PerchError
    from perch_common.ros.conversions import box_from_msg
    from perch_operator.cli.commands import parse_crop

    surface_id, box = parse_crop("3:1.0,0.5,1.2,2.0,0.3,1.5,90")
    center, size, rotation = box_from_msg(box)
    assert surface_id == 3
    np.testing.assert_allclose(center, [1.0, 0.5, 1.2], atol=1e-6)
    np.testing.assert_allclose(size, [2.0, 0.3, 1.5], atol=1e-6)
    np.testing.assert_allclose(rotation @ [1.0, 0, 0], [0, 1.0, 0], atol=1e-6)   # yaw 90 deg: box x = world y
    for bad in ("x:1,2,3,4,5,6", "3:1,2,3", "3:1,2,3,4,0,6", "3:1,2,3,4,nan,6"):
        with pytest.raises(PerchError, match="--crop"):
            parse_crop(bad)
