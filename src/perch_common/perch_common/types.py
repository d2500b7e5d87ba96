"""Data passed between stages, in their pure-Python form (messages: perch_common.ros)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import IntEnum

import numpy as np

from perch_common.mesh import Mesh


class SurfaceClass(IntEnum):
    """Same codes as perch_interfaces/msg/Surface CLASS_*."""

    UNKNOWN = 0
    FLOOR = 1
    WALL = 2
    CEILING = 3
    INTERMEDIATE = 4


# A polygon with holes: list of rings, each (K,2) in plane coordinates; ring 0 is the outer boundary.
Polygon2D = list


@dataclass
class PlaneFrame:
    """Origin on the plane, in-plane unit axes u, v and unit normal with u x v = normal."""

    origin: np.ndarray
    axis_u: np.ndarray
    axis_v: np.ndarray
    normal: np.ndarray

    def to_plane(self, points: np.ndarray) -> np.ndarray:
        """(N,3) world points to (N,2) plane coordinates."""
        d = np.asarray(points, np.float64) - self.origin
        return np.stack([d @ self.axis_u, d @ self.axis_v], axis=-1)

    def to_world(self, uv: np.ndarray, height: float | np.ndarray = 0.0) -> np.ndarray:
        """(N,2) plane coordinates (plus height along the normal) to (N,3) world points."""
        uv = np.asarray(uv, np.float64)
        return (self.origin + uv[..., :1] * self.axis_u + uv[..., 1:2] * self.axis_v
                + np.asarray(height)[..., None] * self.normal)

    def flipped(self) -> "PlaneFrame":
        """The same plane seen from the other side (normal reversed, right-handed)."""
        return PlaneFrame(self.origin.copy(), self.axis_v.copy(), self.axis_u.copy(), -self.normal)

    @staticmethod
    def from_normal(origin: np.ndarray, normal: np.ndarray, up: np.ndarray | None = None) -> "PlaneFrame":
        """A frame whose v axis is the projection of `up` (walls: v points up), else arbitrary."""
        normal = np.asarray(normal, np.float64)
        normal = normal / np.linalg.norm(normal)
        ref = np.array([0.0, 0.0, 1.0]) if up is None else np.asarray(up, np.float64)
        v = ref - (ref @ normal) * normal
        if np.linalg.norm(v) < 1e-6:  # horizontal plane: pick any in-plane v
            ref = np.array([0.0, 1.0, 0.0]) if abs(normal[1]) < 0.9 else np.array([1.0, 0.0, 0.0])
            v = ref - (ref @ normal) * normal
        v /= np.linalg.norm(v)
        u = np.cross(v, normal)
        return PlaneFrame(np.asarray(origin, np.float64), u, v, normal)


@dataclass
class Surface:
    """A planar surface of the environment mesh."""

    id: int
    frame: PlaneFrame
    area: float
    face_indices: np.ndarray
    surface_class: SurfaceClass = SurfaceClass.UNKNOWN
    rms_distance: float = 0.0
    mean_color: np.ndarray = field(default_factory=lambda: np.zeros(3))
    boundary: list[Polygon2D] = field(default_factory=list)


NOT_MEASURED = -1.0  # evidence value of a perch nobody measured (messages carry finite numbers only)


@dataclass
class PerchEvidence:
    """Why a perch is safe, measured on the scan (m, share); for a region, its worst cell's values.

    approach_clearance: free depth of the approach prism; free_fall: free fall below the window;
    both saturate at the filter's lookahead. support_share: share of the window on scanned surface
    within tolerance of the perch plane; flatness_rms: RMS distance of that surface to the plane;
    approach_observed / fall_observed: share of the approach prism / fall corridor lying in space the
    scan observed (perch_filtering.observed). NOT_MEASURED (-1) where unknown.
    """

    approach_clearance: float = NOT_MEASURED
    free_fall: float = NOT_MEASURED
    support_share: float = NOT_MEASURED
    flatness_rms: float = NOT_MEASURED
    approach_observed: float = NOT_MEASURED  # share of the approach prism in space the scan observed
    fall_observed: float = NOT_MEASURED      # share of the fall corridor (column) in observed space


@dataclass
class PerchRegion:
    """Part of a surface where a drone can perch."""

    id: int
    source_surface: int
    surface_class: SurfaceClass
    frame: PlaneFrame
    polygons: list[Polygon2D]
    mesh: Mesh
    area: float
    evidence: PerchEvidence = field(default_factory=PerchEvidence)




@dataclass
class FilterRemoval:
    """Area (m^2) of one surface removed by each filter, in the order they run (conventions.FILTER_NAMES)."""

    surface_id: int
    area_total: float
    orientation: float = 0.0
    recovery_height: float = 0.0
    perch_window: float = 0.0
    obstacle_clearance: float = 0.0  # the approach prism
    support: float = 0.0
    line_of_sight: float = 0.0       # target visibility share
    reachability: float = 0.0
    area_kept: float = 0.0


@dataclass
class ExclusionZone:
    """No perch within `radius` of `center` (a rejected or failed perch)."""

    center: np.ndarray
    radius: float


@dataclass
class CameraPlacement:
    """One perched drone and its camera; poses are 4x4 world-from-body matrices.

    drone_pose: z along the surface normal, x forward. camera_pose: optical frame
    (z forward, x right, y down).
    """

    drone_index: int
    region_id: int
    drone_pose: np.ndarray
    camera_pose: np.ndarray
    pan: float
    tilt: float
    zoom: float = 1.0
    marginal_gain: float = 0.0
    fitness: float = 0.0
    coverage: float = 0.0
    mean_uncertainty: float = 0.0
    # Robustness of the whole arrangement with respect to this camera (perch_placement.robustness; NaN: not assessed)
    contribution: float = math.nan           # fitness lost when this camera is removed
    expected_contribution: float = math.nan  # its mean under the landing error
    p5_contribution: float = math.nan        # its 5th percentile under the landing error
    coverage_without: float = math.nan       # coverage with this camera removed
    kview_coverage_without: float = math.nan  # k-view coverage with this camera removed
