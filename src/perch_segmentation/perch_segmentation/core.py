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
from perch_common.work import report, span
from perch_segmentation import stats as st
from perch_segmentation.adjacency import face_adjacency
from perch_segmentation.agglomerate import MergeRules, grow_clusters
from perch_segmentation.color import rgb_to_lab
from perch_segmentation.config import SegmentationConfig
from perch_segmentation.fragments import absorb_fragments
from perch_segmentation.merge_pass import PlaneRules, boundary_plane_groups, merge_coplanar
from perch_segmentation.surfaces import build_surfaces

AREA_DECIMALS = 4  # m^2 digits at which surface areas are compared (see segment_mesh)
# A face whose height is below this share of its longest edge is a sliver: its normal is float
# rounding (of float32 message vertices too) and points elsewhere in every frame. It gets none, as
# an exactly degenerate face has (a 0.02 deg turn changed up to 73 faces of holo1_room_window).
SLIVER_HEIGHT_RATIO = 1e-4


@dataclass
class SegmentationResult:
    """The surfaces found, each face's surface, and diagnostics."""

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
    report(0.0, "prepare")   # progress (perch_common.work) at the existing phase boundaries
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
        faces_table = st.face_table(triangles, areas, reliable_face_normals(triangles, mesh.face_normals()),
                                    lab, colors)
        adjacency = adjacency_job.result()
    clock.lap("prepare")

    rules = MergeRules(config.energy_bound, color_threshold, config.normal_guard_area,
                       math.cos(math.radians(config.theta_max_deg)))
    # Step 1 needs moments, winding and colour only; the other columns are summed once after it.
    with span(0.15, 0.6):
        labels, table, edges = grow_clusters(faces_table[:, :st.STEP1_COLUMNS], adjacency, rules,
                                             config.target_clusters)
    table = st.aggregate(faces_table, labels, len(table))
    clusters_step1 = len(table)
    clock.lap("step1_grow")
    report(0.6, "merge planes")

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
    report(0.8, "surface outlines")

    # Areas to 1 cm^2: a surface of exactly min_area, or two of equal area (generated rooms have them),
    # are kept and ordered alike when the same mesh comes in another orientation (float rounding).
    area = np.round(table[:, st.AREA], AREA_DECIMALS)
    keep = np.flatnonzero(area >= max(config.min_area, 1e-12))
    if len(keep) == 0:
        largest = float(table[:, st.AREA].max()) if len(table) else 0.0
        raise PerchError(
            f"no planar region of at least min_area={config.min_area} m^2 found (largest planar cluster: "
            f"{largest:.3g} m^2 of {float(areas.sum()):.3g} m^2); is this a room mesh in metres?")
    keep = keep[np.argsort(-area[keep], kind="stable")]
    surface_of = np.full(len(table), -1, np.int64)
    surface_of[keep] = np.arange(len(keep))
    face_labels = surface_of[labels]
    surfaces = build_surfaces(mesh, triangles, centre, table[keep], face_labels, config.boundary_cell,
                              config.boundary_simplify, config.threads)
    clock.lap("step3_surfaces")
    return SegmentationResult(surfaces, face_labels, clusters_step1, clusters_step2, clock.laps)


def reliable_face_normals(triangles: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """Unit face normals, zero for slivers (height under SLIVER_HEIGHT_RATIO of the longest edge)."""
    edges = triangles - triangles[:, [2, 0, 1]]  # np.roll(triangles, 1, axis=1) without its overhead
    longest2 = np.einsum("fij,fij->fi", edges, edges).max(axis=1)
    cross = st.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0])  # np.cross's floats
    twice_area = np.sqrt(np.einsum("ij,ij->i", cross, cross))  # = longest edge x height
    sliver = twice_area <= SLIVER_HEIGHT_RATIO * longest2
    return np.where(sliver[:, None], 0.0, normals)


def median_face_colors(mesh: Mesh) -> np.ndarray:
    """(F,3) uint8 per-channel median of each face's vertex colours.

    Merging compares these: a face on the border of a flush door takes the colour of the
    majority of its corners instead of a blend that matches neither side.
    """
    c = mesh.vertex_colors[mesh.faces]  # (F, 3 corners, 3 channels)
    a, b, d = c[:, 0], c[:, 1], c[:, 2]
    return np.maximum(np.minimum(a, b), np.minimum(np.maximum(a, b), d))
