"""Configuration of the segmentation stage (ROS parameters of node perch_segmentation)."""

from __future__ import annotations

import math
from dataclasses import dataclass

from perch_common.config import StageNodeConfig, param
from perch_common.transforms import parse_up_axis


@dataclass
class SegmentationConfig:
    """Parameters of the segmentation stage (defaults from the original system)."""

    target_clusters: int = param(2000, "step 1 stops merging at this many clusters", low=1)
    energy_bound: float = param(4e-4, "step 1 merges only while the union's mean squared distance to its "
                                       "best-fit plane stays at or below this (4e-4 = 2 cm RMS)", "m^2", low=0.0)
    theta_max_deg: float = param(15.0, "step 2 merges clusters whose normals differ by less than this", "deg", low=0.0, high=90.0)
    theta_min_deg: float = param(70.0, "step 2: the line joining two centroids must make at least this angle "
                                        "with both normals (no stacking of parallel planes)", "deg", low=0.0, high=90.0)
    d_max: float = param(0.2, "step 2: each centroid within this distance of the other's plane", "m", low=0.0)
    use_color: bool = param(True, "keep differently coloured regions apart (ignored without vertex colours)")
    color_threshold: float = param(20.0, "largest CIELAB distance (Delta E 1976) between mean colours "
                                          "of clusters that merge", "Delta E", low=0.0)
    min_area: float = param(0.2, "smallest surface reported", "m^2", low=0.0)
    normal_guard_area: float = param(0.01, "step 1: clusters at least this large merge only if their "
                                            "normals differ by less than theta_max", "m^2", low=0.0)
    fragment_rms: float = param(0.1, "pieces smaller than min_area join the adjacent surface whose plane "
                                       "they fit within this RMS distance (rough scans)", "m", low=0.0)
    merge_floor_ceiling: bool = param(True, "unite the disconnected coplanar pieces of the floor and ceiling")
    up_axis: str = param("+z", "world up: +x, -x, +y, -y, +z, -z or three numbers")
    boundary_cell: float = param(0.02, "grid cell the outlines are traced on (their accuracy)", "m", low=0.0, high=1.0)
    boundary_simplify: float = param(0.02, "tolerance of the outline simplification", "m", low=0.0, high=1.0)
    threads: int = param(2, "worker threads for independent work (face adjacency, outlines)", low=1, high=64)

    def validate(self) -> "SegmentationConfig":
        """Raise ValueError naming the first absurd parameter."""
        checks = [
            (self.target_clusters >= 1, f"target_clusters={self.target_clusters} must be at least 1"),
            (math.isfinite(self.energy_bound) and self.energy_bound > 0,
             f"energy_bound={self.energy_bound} must be a positive number of m^2"),
            (0 < self.theta_max_deg < 90, f"theta_max_deg={self.theta_max_deg} must be in (0, 90)"),
            (0 <= self.theta_min_deg <= 90, f"theta_min_deg={self.theta_min_deg} must be in [0, 90]"),
            (math.isfinite(self.d_max) and self.d_max > 0, f"d_max={self.d_max} must be a positive distance (m)"),
            (math.isfinite(self.color_threshold) and self.color_threshold > 0,
             f"color_threshold={self.color_threshold} must be a positive CIELAB distance"),
            (math.isfinite(self.min_area) and self.min_area >= 0, f"min_area={self.min_area} must be >= 0 m^2"),
            (math.isfinite(self.normal_guard_area) and self.normal_guard_area >= 0,
             f"normal_guard_area={self.normal_guard_area} must be >= 0 m^2"),
            (math.isfinite(self.fragment_rms) and self.fragment_rms >= 0,
             f"fragment_rms={self.fragment_rms} must be >= 0 m"),
            (math.isfinite(self.boundary_cell) and self.boundary_cell > 0,
             f"boundary_cell={self.boundary_cell} must be a positive distance (m)"),
            (math.isfinite(self.boundary_simplify) and self.boundary_simplify >= 0,
             f"boundary_simplify={self.boundary_simplify} must be >= 0 m"),
            (1 <= self.threads <= 64, f"threads={self.threads} must be in 1..64"),
        ]
        for ok, message in checks:
            if not ok:
                raise ValueError(message)
        parse_up_axis(self.up_axis)
        return self


@dataclass
class SegmentationNodeConfig(SegmentationConfig, StageNodeConfig[SegmentationConfig]):
    """The perch_segmentation node's parameters: the segmentation settings plus the node's own."""
