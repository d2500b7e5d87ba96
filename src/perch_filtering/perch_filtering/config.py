"""What makes a perch safe: the filter's configuration (PerchSpec fields plus raster/grid settings)."""

from __future__ import annotations

import math
from dataclasses import dataclass

from perch_common.config import StageNodeConfig, param
from perch_common.transforms import parse_up_axis


@dataclass
class FilterConfig:
    """Defaults follow the original system (thesis) unless the description says otherwise."""

    allow_walls: bool = param(True, "perch on walls")
    allow_ceiling: bool = param(True, "perch on ceilings")
    allow_floor: bool = param(False, "land on floors (and other upward-facing surfaces)")
    allow_intermediate: bool = param(False, "perch on surfaces between the class angles")
    class_angle_deg: float = param(15.0, "tolerance of the floor / wall / ceiling classes", "deg", low=0.0, high=45.0)
    min_recovery_height: float = param(0.5, "free fall needed below a perch to recover", "m", low=0.0, high=10.0)
    approach_distance: float = param(0.5, "approach prism depth: the window swept this far along the normal "
                                     "(the waypoint's approach point) must be free of geometry", "m", low=0.0, high=10.0)
    approach_margin: float = param(0.1, "lateral margin added around the window for the approach prism and the "
                                   "fall corridor", "m", low=0.0, high=10.0)
    window_width: float = param(0.5, "perch window, horizontal side on walls", "m", low=0.0, high=10.0)
    window_height: float = param(0.5, "perch window, vertical side on walls (along gravity)", "m", low=0.0, high=10.0)
    window_ellipse: bool = param(False, "elliptic perch window instead of a rectangle")
    raster_density: float = param(50.0, "raster resolution of each surface", "px/m", low=0.0, high=1000.0)
    drone_radius: float = param(0.35, "drone radius for flight clearance; a wall's fall corridor is 2 radii deep",
                                "m", low=0.0, high=5.0)
    standoff: float = param(0.5, "point in front of a perch (along its normal) that must be reachable", "m", low=0.0, high=10.0)
    voxel_size: float = param(0.05, "voxel size of the flight-reachability occupancy grid", "m", low=0.0, high=1.0)
    min_support: float = param(0.9, "share of the window that must have scanned surface within plane_tolerance "
                               "of the perch plane", low=0.0, high=1.0)
    max_support_rms: float = param(0.02, "largest RMS distance of the scanned surface under the window to the "
                                   "perch plane", "m", low=0.0, high=1.0)
    min_visible_share: float = param(0.2, "share of the target's sample points a perch must see", low=0.0, high=1.0)
    visibility_per_volume: bool = param(True, "with a target of several volumes, min_visible_share is asked of "
                                        "the volume a perch sees best (a building's volumes lie in different "
                                        "rooms and storeys), not of all the target's points")
    visibility_points: int = param(64, "target sample points for the visibility share (seeded by seed)", low=1, high=100000)
    visibility_spacing: float = param(0.06, "grid on which visibility shares are ray cast and then "
                                      "interpolated bilinearly", "m", low=0.001, high=10.0)
    los_offset: float = param(0.02, "line-of-sight rays start this far in front of the surface", "m", low=0.0, high=1.0)
    plane_tolerance: float = param(0.03, "scanned surface within this of a window's perch plane supports it", "m",
                                   low=0.0, high=1.0)
    surface_depth: float = param(0.04, "most depth in front of a surface's plane that counts as the scanned surface "
                                 "itself (plane_tolerance plus 3 sigma of the surface's scan noise, capped here; support "
                                 "judges it under the window); farther geometry is an obstacle to the approach "
                                 "prism and the fall corridor", "m", low=0.0, high=1.0)
    max_unobserved_share: float = param(0.2, "largest share of a perch's approach prism or fall corridor (column) "
                                        "that may lie outside the space the scan observed", low=0.0, high=1.0)
    enclosed_escape_share: float = param(0.5, "a point counts as observed (enclosed by the scan) when at most this "
                                         "share of the rays cast from it leaves the model without a hit",
                                         low=0.0, high=1.0)
    floor_merge_tolerance: float = param(0.1, "floor pieces within this height of the lowest are one floor", "m",
                                         low=0.0, high=10.0)
    min_floor_area: float = param(1.0, "smallest horizontal surface that may be the floor", "m^2", low=0.0)
    min_region_area: float = param(0.005, "regions smaller than this are dropped", "m^2", low=0.0)
    max_cells_per_surface: int = param(4_000_000, "refuse rasters larger than this (absurd density)", low=1)
    max_voxels: int = param(60_000_000, "refuse occupancy grids larger than this (absurd voxel size)", low=1)
    seed: int = param(0, "seed of the random samples used to orient surfaces and of the target points", low=0)
    processes: int = param(2, "processes that judge a large scene's surfaces: 2 forks a second process for "
                           "half of them (the same answer, ~2x faster on 2 cores); 1 keeps them in this one",
                           low=1, high=2)

    @property
    def cell(self) -> float:
        """Raster cell size (m)."""
        return 1.0 / self.raster_density

    @property
    def lookahead(self) -> float:
        """How far in front of and below a perch geometry is measured (evidence saturates here)."""
        return max(2.0 * self.approach_distance, 2.0 * self.min_recovery_height, 2.0 * self.drone_radius)

    def validate(self) -> "FilterConfig":
        """Raise ValueError naming every absurd value."""
        problems = []
        positive = ("raster_density", "voxel_size", "window_width", "window_height", "drone_radius",
                    "visibility_spacing")
        for name in positive:
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                problems.append(f"{name}={value} must be > 0")
        for name in ("min_recovery_height", "approach_distance", "approach_margin", "standoff", "los_offset",
                     "plane_tolerance", "surface_depth", "max_support_rms", "floor_merge_tolerance", "min_floor_area",
                     "min_region_area"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                problems.append(f"{name}={value} must be >= 0")
        for name in ("min_support", "min_visible_share", "max_unobserved_share", "enclosed_escape_share"):
            value = getattr(self, name)
            if not (math.isfinite(value) and 0 <= value <= 1):
                problems.append(f"{name}={value} must be a share in [0, 1]")
        if not (1 <= self.visibility_points <= 4096):
            problems.append(f"visibility_points={self.visibility_points} must be in [1, 4096]")
        if not (0 < self.class_angle_deg < 45):
            problems.append(f"class_angle_deg={self.class_angle_deg} must be in (0, 45)")
        if self.raster_density > 1000:
            problems.append(f"raster_density={self.raster_density} px/m is absurd (max 1000)")
        if self.voxel_size > 1.0:
            problems.append(f"voxel_size={self.voxel_size} m is absurd (max 1.0)")
        if self.voxel_size > self.drone_radius:
            problems.append(f"voxel_size={self.voxel_size} m must not exceed drone_radius={self.drone_radius} m")
        if self.surface_depth < self.plane_tolerance:
            problems.append(f"surface_depth={self.surface_depth} m must be at least plane_tolerance="
                            f"{self.plane_tolerance} m (support looks that far in front of the plane)")
        if self.standoff < self.drone_radius:
            problems.append(f"standoff={self.standoff} m must be at least drone_radius={self.drone_radius} m "
                            "(the drone's centre hovers there)")
        if problems:
            raise ValueError("filter configuration: " + "; ".join(problems))
        return self


@dataclass
class FilterNodeConfig(FilterConfig, StageNodeConfig[FilterConfig]):
    """The perch_filtering node's parameters: the filter settings plus the node's own."""

    up_axis: str = param("+z", "up axis when a request leaves `up` zero")
    prepare_meshes: bool = param(True, "build the ray scene and surface samples of a mesh another stage of this "
                                 "process replies with (one-process graph) while the stages before the filter run",
                                 read_only=True)

    def validate(self) -> "FilterNodeConfig":
        """Raise ValueError naming every absurd value, the up axis included."""
        self.stage_config().validate()
        parse_up_axis(self.up_axis)
        return self
