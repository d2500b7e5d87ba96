"""Segmentation core: a room mesh in, its planar surfaces out (no ROS here).

Step 1 (agglomerate.py) grows flat clusters bottom-up by plane-fit energy, step 2
(merge_pass.py) merges adjacent coplanar clusters and the floor's and ceiling's pieces, step 3
(surfaces.py) outputs every cluster of at least min_area with its PCA frame and outline.
"""

from __future__ import annotations

import math
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from perch_common.errors import PerchError
from perch_common.mesh import Mesh, validate_mesh
from perch_common.timing import Laps
from perch_common.transforms import parse_up_axis
from perch_common.types import Surface
from perch_segmentation import stats as st
from perch_segmentation.adjacency import face_adjacency
from perch_segmentation.agglomerate import MergeRules, grow_clusters
from perch_segmentation.color import rgb_to_lab
from perch_segmentation.fragments import absorb_fragments
from perch_segmentation.merge_pass import PlaneRules, boundary_plane_groups, merge_coplanar
from perch_segmentation.surfaces import build_surfaces


def _field(default, description: str, unit: str | None = None):
    meta = {"description": description}
    if unit:
        meta["unit"] = unit
    return field(default=default, metadata=meta)


@dataclass
class SegmentationConfig:
    """Parameters of the segmentation stage (defaults from the original system)."""

    target_clusters: int = _field(2000, "step 1 stops merging at this many clusters")
    energy_bound: float = _field(4e-4, "step 1 merges only while the union's mean squared distance to its "
                                       "best-fit plane stays at or below this (4e-4 = 2 cm RMS)", "m^2")
    theta_max_deg: float = _field(15.0, "step 2 merges clusters whose normals differ by less than this", "deg")
    theta_min_deg: float = _field(70.0, "step 2: the line joining two centroids must make at least this angle "
                                        "with both normals (no stacking of parallel planes)", "deg")
    d_max: float = _field(0.2, "step 2: each centroid within this distance of the other's plane", "m")
    use_color: bool = _field(True, "keep differently coloured regions apart (ignored without vertex colours)")
    color_threshold: float = _field(20.0, "largest CIELAB distance (Delta E 1976) between mean colours "
                                          "of clusters that merge", "Delta E")
    min_area: float = _field(0.2, "smallest surface reported", "m^2")
    normal_guard_area: float = _field(0.01, "step 1: clusters at least this large merge only if their "
                                            "normals differ by less than theta_max", "m^2")
    fragment_rms: float = _field(0.1, "pieces smaller than min_area join the adjacent surface whose plane "
                                       "they fit within this RMS distance (rough scans)", "m")
    merge_floor_ceiling: bool = _field(True, "unite the disconnected coplanar pieces of the floor and ceiling")
    up_axis: str = _field("+z", "world up: +x, -x, +y, -y, +z, -z or three numbers")
    boundary_cell: float = _field(0.02, "grid cell the outlines are traced on (their accuracy)", "m")
    boundary_simplify: float = _field(0.02, "tolerance of the outline simplification", "m")
    threads: int = _field(2, "worker threads for independent work (face adjacency, outlines)")

    def validate(self) -> None:
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


@dataclass
class SegmentationResult:
    surfaces: list[Surface]       # largest first; id = index in this list
    face_labels: np.ndarray       # (F,) int64 index into surfaces, -1 for faces on none
    clusters_step1: int = 0       # clusters after step 1 (diagnostics)
    clusters_step2: int = 0       # clusters after step 2, before the min_area cut
    timings: dict = field(default_factory=dict)  # seconds per phase (diagnostics)


def segment_mesh(mesh: Mesh, config: SegmentationConfig | None = None) -> SegmentationResult:
    """Planar surfaces of `mesh`; raises ValueError/MeshError/PerchError on unusable input."""
    config = config or SegmentationConfig()
    config.validate()
    clock = Laps()
    validate_mesh(mesh, "mesh to segment")
    up = parse_up_axis(config.up_axis)
    colors = mesh.face_colors()  # mean colours are reported even when not used for merging
    color_threshold = config.color_threshold if (config.use_color and colors is not None) else None

    # Centring keeps the raw second moments well conditioned far from the origin.
    centre = 0.5 * (mesh.vertices.min(axis=0) + mesh.vertices.max(axis=0))
    triangles = mesh.vertices[mesh.faces] - centre
    areas = mesh.face_areas()
    with ThreadPoolExecutor(max_workers=max(1, config.threads)) as pool:  # numpy releases the GIL
        adjacency_job = pool.submit(face_adjacency, mesh.faces, mesh.num_vertices)
        lab = rgb_to_lab(median_face_colors(mesh)) if colors is not None else None
        faces_table = st.face_table(triangles, areas, mesh.face_normals(), lab, colors)
        adjacency = adjacency_job.result()
    clock.lap("prepare")

    rules = MergeRules(config.energy_bound, color_threshold, config.normal_guard_area,
                       math.cos(math.radians(config.theta_max_deg)))
    # Step 1 needs moments, winding and colour only; the other columns are summed once after it.
    labels, table, edges = grow_clusters(faces_table[:, :st.STEP1_COLUMNS], adjacency, rules,
                                         config.target_clusters)
    table = st.aggregate(faces_table, labels, len(table))
    clusters_step1 = len(table)
    clock.lap("step1_grow")

    plane_rules = PlaneRules(config.theta_max_deg, config.theta_min_deg, config.d_max, color_threshold)
    mapping, table, edges = merge_coplanar(table, edges, plane_rules)
    labels = mapping[labels]
    mapping, table, edges = absorb_fragments(table, edges, config.min_area, config.fragment_rms,
                                             rules.guard_area, rules.guard_cos)
    labels = mapping[labels]
    if config.merge_floor_ceiling:
        heights = (mesh.vertices - centre) @ up  # statistics live in centred coordinates
        extent = (float(heights.min()), float(heights.max()))
        mapping = boundary_plane_groups(table, up, extent, plane_rules, config.min_area)
        table = st.aggregate(table, mapping, int(mapping.max()) + 1)
        labels = mapping[labels]
    clusters_step2 = len(table)
    clock.lap("step2_merge")

    keep = np.flatnonzero(table[:, st.AREA] >= max(config.min_area, 1e-12))
    if len(keep) == 0:
        largest = float(table[:, st.AREA].max()) if len(table) else 0.0
        raise PerchError(
            f"no planar region of at least min_area={config.min_area} m^2 found (largest planar cluster: "
            f"{largest:.3g} m^2 of {float(areas.sum()):.3g} m^2); is this a room mesh in metres?")
    keep = keep[np.argsort(-table[keep, st.AREA], kind="stable")]
    surface_of = np.full(len(table), -1, np.int64)
    surface_of[keep] = np.arange(len(keep))
    face_labels = surface_of[labels]
    surfaces = build_surfaces(mesh, triangles, centre, table[keep], face_labels, config.boundary_cell,
                              config.boundary_simplify, config.threads)
    clock.lap("step3_surfaces")
    return SegmentationResult(surfaces, face_labels, clusters_step1, clusters_step2, clock.laps)


def median_face_colors(mesh: Mesh) -> np.ndarray:
    """(F,3) uint8 per-channel median of each face's vertex colours.

    Merging compares these: a face on the border of a flush door takes the colour of the
    majority of its corners instead of a blend that matches neither side.
    """
    c = mesh.vertex_colors[mesh.faces]  # (F, 3 corners, 3 channels)
    a, b, d = c[:, 0], c[:, 1], c[:, 2]
    return np.maximum(np.minimum(a, b), np.minimum(np.maximum(a, b), d))
