"""Crop stage core: keep-boxes and remove-boxes on a mesh, and the resolved target volume.

Pure numpy (plus OpenCV for the floor outline); never imports rclpy.
"""

from __future__ import annotations

from dataclasses import dataclass, field

# The floor outline (perch_common.polygons) uses OpenCV, whose first import costs ~0.4 s: better at node
# start than in a mission.
import cv2  # noqa: F401
import numpy as np

from perch_common.mesh import Mesh, MeshError
from perch_common.polygons import raster_outline
from perch_common.target import TargetVolume
from perch_operator.coordinator.config import CropConfig


@dataclass
class Box:
    """An oriented box: centre (3,), full edge lengths (3,), rotation (3,3) world-from-box."""

    center: np.ndarray
    size: np.ndarray
    rotation: np.ndarray = field(default_factory=lambda: np.eye(3))

    def __post_init__(self) -> None:
        self.center = np.asarray(self.center, np.float64).reshape(3)
        self.size = np.asarray(self.size, np.float64).reshape(3)
        self.rotation = np.asarray(self.rotation, np.float64).reshape(3, 3)
        if not np.all(np.isfinite(self.size)) or np.any(self.size <= 0):
            raise ValueError(f"crop box size must be positive in x, y and z, got {self.size.tolist()}")
        if not np.allclose(self.rotation @ self.rotation.T, np.eye(3), atol=1e-4):
            raise ValueError("crop box orientation is not a rotation (check the quaternion is normalised)")

    def contains(self, points: np.ndarray) -> np.ndarray:
        """(N,) whether each point lies inside the box."""
        local = (np.asarray(points, np.float64) - self.center) @ self.rotation
        return np.all(np.abs(local) <= self.size / 2, axis=1)


@dataclass
class CropResult:
    """The cropped mesh, which input faces it kept, and the target volume."""

    mesh: Mesh
    kept_faces: np.ndarray   # indices into the input mesh's faces
    target: TargetVolume     # never None: given, or the default floor-area target


def crop_mesh(mesh: Mesh, keep_boxes: list[Box] = (), remove_boxes: list[Box] = (),
              target: TargetVolume | None = None, config: CropConfig | None = None) -> CropResult:
    """Keep the faces whose centroid lies in any keep box (all when none) and in no remove box.

    `target` None means: the cropped mesh's floor area extruded by `config.target_height`.
    The input mesh is not modified.
    """
    config = config or CropConfig()
    if mesh.num_faces == 0:
        raise MeshError("crop: the input mesh has no faces")
    centroids = mesh.face_centroids()
    keep = np.ones(mesh.num_faces, bool)
    if len(keep_boxes):
        keep = np.zeros(mesh.num_faces, bool)
        for box in keep_boxes:
            keep |= box.contains(centroids)
    for box in remove_boxes:
        keep &= ~box.contains(centroids)
    kept_faces = np.flatnonzero(keep)
    if len(kept_faces) == 0:
        raise MeshError(f"crop: no faces left after {len(keep_boxes)} keep box(es) and {len(remove_boxes)} "
                        f"remove box(es); the mesh spans {np.round(mesh.bounds(), 2).tolist()} m")
    cropped = mesh.submesh(kept_faces)
    if target is None:
        target = floor_target(cropped, config)
    return CropResult(cropped, kept_faces, target)


def floor_level(mesh: Mesh, config: CropConfig) -> tuple[float, np.ndarray]:
    """Height of the floor and the mask of faces forming it (z-up mesh).

    The floor is the height band with the most upward-facing area near the lowest upward face,
    so stray low fragments (noise below the floor) do not win. A mesh wound inside out (its lowest
    horizontal faces mostly facing down, its highest up) has its normals taken the other way round.
    """
    normals, areas = mesh.face_normals(), mesh.face_areas()
    z = mesh.face_centroids()[:, 2]
    # A floor faces up into the room, unless every winding of the mesh is inverted (the up estimate
    # notices that too): then the lowest horizontal faces mostly face down and the highest mostly up.
    horizontal = np.abs(normals[:, 2]) >= np.cos(config.floor_angle)
    if horizontal.any():
        lowest = horizontal & (z <= z[horizontal].min() + config.floor_band)
        highest = horizontal & (z >= z[horizontal].max() - config.floor_band)
        up, down = normals[:, 2] > 0, normals[:, 2] < 0
        if areas[lowest & down].sum() > areas[lowest & up].sum() and \
                areas[highest & up].sum() > areas[highest & down].sum():
            normals = -normals
    upward = normals[:, 2] >= np.cos(config.floor_angle)
    if not upward.any():
        raise MeshError("crop: no upward-facing faces, so no floor to derive the default target from; "
                        "give a target box or footprint (is the mesh z-up?)")
    low = z[upward].min()
    band = upward & (z <= low + config.floor_band)
    step = config.floor_tolerance
    bins = np.floor((z[band] - low) / step).astype(np.int64)
    weight = np.bincount(bins, weights=areas[band])
    best = int(np.argmax(weight))
    level = float(np.average(z[band][bins == best], weights=areas[band][bins == best] + 1e-12))
    floor = upward & (np.abs(z - level) <= step)
    return level, floor


def floor_target(mesh: Mesh, config: CropConfig | None = None) -> TargetVolume:
    """The floor's outline (largest connected piece, holes ignored) extruded by the target height."""
    config = config or CropConfig()
    if config.target_height <= 0:
        raise ValueError(f"crop: target_height must be positive, got {config.target_height}")
    level, floor = floor_level(mesh, config)
    try:
        footprint, area = raster_outline(mesh.triangles(floor)[:, :, :2], config.grid_resolution,
                                         config.close_radius)
    except ValueError as exc:
        raise MeshError(f"crop: floor outline: {exc} (raise grid_resolution or give a target)") from None
    if len(footprint) < 3 or area < 0.05:
        raise MeshError("crop: the floor is too small to derive a default target; give a target")
    return TargetVolume(footprint=footprint, base=level, height=config.target_height)
