"""Mesh cleaning: merge duplicates, drop small pieces, quadric decimation (fast-simplification), gravity-align."""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field

import numpy as np

from perch_common.mesh import Mesh, MeshError, validate_mesh
from perch_common.mesh_health import unreferenced_line, unreferenced_vertices
from perch_common.up_axis import UpEstimate, estimate_mesh_up
from perch_reconstruction.config import ReconstructionConfig
from perch_reconstruction.mesh_ops import (
    cluster_vertices,
    piece_areas,
    remove_small_pieces,
    weld_close_vertices,
    weld_vertices,
)

PRECLUSTER_FACTOR = 2
SOUP_VERTICES_PER_FACE = 2.0   # welded meshes have ~0.5 vertices per face; a soup that did not weld ~3
SOUP_WELD_FRACTION = 0.01      # a soup is re-welded at this fraction of its median edge ...
SOUP_WELD_MAX = 1e-3           # m ... at most
REWIND_SHARE = 0.01            # re-wind when more than this share of shared edges is inconsistent
NOTABLE_SHARE = 0.001          # duplicate/degenerate faces are reported above this share
FALLING_APART = 0.5            # warn when pieces below min_piece_diameter held more than this share of faces
# ... or when the cleaned mesh's largest connected piece holds less than this share of its area (HoloLens
# spatial maps, made of blocks, hold 15-30 % in their largest; a room in 0.25 m blocks with unwelded seams, 1 %)
FRAGMENTED_SHARE = 0.05
# fast_simplification keeps the mesh being decimated in module-global state: one decimation at a time.
_DECIMATION_LOCK = threading.Lock()


@dataclass
class CleanReport:
    """What cleaning did: face counts, the up axis found and the rotation applied."""

    faces_in: int
    faces_out: int
    pieces_removed_faces: int = 0
    up_source: str = "none"          # "gravity", "planes", "planes, sign kept" or "none"
    up_confidence: float = 0.0
    up_estimate: UpEstimate | None = None
    rotation: np.ndarray = field(default_factory=lambda: np.eye(3))  # applied: out = R @ in
    seconds: float = 0.0
    warnings: list[str] = field(default_factory=list)

    def summary(self) -> str:
        """The clean reply's message: '<faces> (<pieces>); up from <source>', then '; <warning>' each (the
        reply's `warnings` holds them one by one)."""
        return "; ".join([f"{self.faces_in} -> {self.faces_out} faces ({self.pieces_removed_faces} in small pieces)",
                          f"up from {self.up_source}", *self.warnings])


def clean_mesh(mesh: Mesh, gravity: np.ndarray | None, config: ReconstructionConfig) -> Mesh:
    """The cleaned, gravity-aligned (z-up) copy of `mesh`; the input is not modified.

    gravity: direction of gravity in the mesh's frame (any length), or None/zero to estimate the
    up axis from the dominant floor/ceiling planes.
    """
    return clean_mesh_with_report(mesh, gravity, config)[0]


def clean_mesh_with_report(mesh: Mesh, gravity: np.ndarray | None, config: ReconstructionConfig,
                           down_hint: np.ndarray | None = None) -> tuple[Mesh, CleanReport]:
    """As clean_mesh, with what was done. down_hint: rough gravity (e.g. the mean image-down axis of the
    cameras) choosing which dominant plane orientation is the floor when gravity is unknown."""
    start = time.perf_counter()
    validate_mesh(mesh, "mesh to clean")
    if gravity is not None:
        gravity = np.asarray(gravity, np.float64).reshape(-1)
        if gravity.shape != (3,) or not np.isfinite(gravity).all():
            raise ValueError(f"gravity must be three finite numbers, got {gravity.tolist()}")
        if np.linalg.norm(gravity) < 1e-9:
            gravity = None
    report = CleanReport(faces_in=mesh.num_faces, faces_out=0)
    lost = unreferenced_line(*unreferenced_vertices(mesh))   # faces lost on the way (the clean drops the rest)
    if lost:
        report.warnings.append(lost)
    cleaned = _own_arrays(_decimated_clean(mesh, config, report), mesh).with_viewpoints_of(mesh)
    if cleaned.num_faces == 0:
        raise MeshError(f"mesh to clean: nothing left after removing pieces smaller than "
                        f"{config.min_piece_diameter} m; lower min_piece_diameter")
    fragmented = fragmented_line(piece_areas(cleaned))
    if fragmented:
        report.warnings.append(fragmented)
    if config.gravity_align:
        rotation = _up_rotation(cleaned, gravity, config, report, down_hint)
        if rotation is not None:
            report.rotation = rotation
            transform = np.eye(4)
            transform[:3, :3] = rotation
            cleaned = cleaned.transformed(transform)
    report.faces_out = cleaned.num_faces
    report.seconds = time.perf_counter() - start
    return cleaned, report


def fragmented_line(areas: np.ndarray) -> str:
    """What to say of a mesh whose connected pieces have `areas` (largest first) when even the largest
    holds under FRAGMENTED_SHARE of the area ('' otherwise): segmentation finds surfaces within a piece."""
    total = float(areas.sum())
    if len(areas) < 2 or total <= 0 or areas[0] >= FRAGMENTED_SHARE * total:
        return ""
    return (f"the mesh falls apart into fragments: {len(areas):,} disconnected pieces, the largest {areas[0]:.2f} m^2 "
            f"({areas[0] / total:.0%} of the area); surfaces are found within one piece, so a scan exported in "
            "blocks without shared seams (or as a triangle soup) yields few or none: weld it (merge_distance, "
            "or your exporter's weld option) or export it as one mesh")


def _own_arrays(cleaned: Mesh, given: Mesh) -> Mesh:
    """`cleaned` with arrays of its own where it still shares the given mesh's (nothing needed
    repairing or decimating): the cleaned mesh is a copy, whatever its caller does to it."""
    given_arrays = [a for a in (given.vertices, given.faces, given.vertex_colors, given.vertex_normals) if a is not None]
    arrays = (cleaned.vertices, cleaned.faces, cleaned.vertex_colors, cleaned.vertex_normals)
    if not any(a is not None and np.may_share_memory(a, b) for a in arrays for b in given_arrays):
        return cleaned
    return Mesh(*(None if a is None else a.copy() for a in arrays), frame_id=cleaned.frame_id,
                viewpoints=cleaned.viewpoints)


def _decimated_clean(mesh: Mesh, config: ReconstructionConfig, report: CleanReport) -> Mesh:
    """Weld, drop small pieces (numpy), then quadric edge collapse to the face target.

    Above PRECLUSTER_FACTOR x the target, vertex clustering first brings the mesh down to that size:
    quadric collapse costs ~2 us per collapsed edge (fast-simplification; MeshLab's took ~20 us),
    still too slow for 1M-face TSDF meshes, while clustering at about the voxel size loses nothing
    the later collapse would keep.
    """
    welded = repair_mesh(mesh, config.merge_distance, report)
    if config.min_piece_diameter > 0:
        welded, report.pieces_removed_faces = remove_small_pieces(welded, config.min_piece_diameter)
        if welded.num_faces and report.pieces_removed_faces > FALLING_APART * mesh.num_faces:
            report.warnings.append(f"{report.pieces_removed_faces:,} of {mesh.num_faces:,} faces were in pieces "
                                   f"smaller than min_piece_diameter {config.min_piece_diameter} m: most of the "
                                   "mesh falls apart into fragments")
    target = int(config.target_faces)
    if not target or welded.num_faces <= target:
        return welded
    if welded.num_faces > PRECLUSTER_FACTOR * target:
        welded = cluster_vertices(welded, PRECLUSTER_FACTOR * target)
    return quadric_decimate(welded, target)


def repair_mesh(mesh: Mesh, merge_distance: float, report: CleanReport) -> Mesh:
    """Weld coincident corners and drop duplicate and degenerate faces; re-weld a triangle soup whose
    corners miss each other by more than merge_distance; remove needle slivers; re-wind a mesh whose
    windings flip from face to face. Each repair is said in report.warnings (perch_common.mesh_health)."""
    from perch_common.mesh_health import needle_mask, winding_flips

    welded = weld_vertices(mesh, merge_distance)
    if welded.num_vertices > SOUP_VERTICES_PER_FACE * welded.num_faces and welded.num_faces > 1:
        # Most corners met no other: a soup exported with float32 rounding. Weld at 1 % of its typical edge.
        corners = welded.triangles()
        typical = float(np.median(np.linalg.norm(corners[:, 1] - corners[:, 0], axis=1)))
        distance = min(SOUP_WELD_MAX, SOUP_WELD_FRACTION * typical)
        if distance > merge_distance:
            rewelded = weld_close_vertices(welded, distance)
            report.warnings.append(f"repaired a triangle soup: corners welded at {distance:.2g} m (merge_distance "
                                   f"{merge_distance:g} m joined too few: {welded.num_vertices:,} vertices for "
                                   f"{welded.num_faces:,} faces)")
            welded = rewelded
    dropped = mesh.num_faces - welded.num_faces
    if dropped > NOTABLE_SHARE * mesh.num_faces:   # a handful is ordinary in scans: said only when notable
        report.warnings.append(f"removed {dropped:,} duplicate or degenerate faces")
    needles = needle_mask(welded)
    if needles.any():
        report.warnings.append(f"removed {int(needles.sum()):,} needle slivers (triangles spanning space, "
                               "almost no wider than a line)")
        welded = welded.submesh(~needles)
    # ~1.5 shared edges per face; a few flipped faces (real scans have some) are left as they are.
    flips, inconsistent = winding_flips(welded.faces, REWIND_SHARE * 1.5 * welded.num_faces)
    if inconsistent > REWIND_SHARE * 1.5 * welded.num_faces:
        faces = welded.faces.copy()
        faces[flips] = faces[flips][:, ::-1]
        report.warnings.append(f"re-wound {int(flips.sum()):,} faces that faced the other way from their "
                               "neighbours (inconsistent windings)")
        welded = Mesh(welded.vertices, faces, welded.vertex_colors, frame_id=welded.frame_id)
    return welded


def quadric_decimate(mesh: Mesh, target: int) -> Mesh:
    """Quadric edge collapse (Garland-Heckbert, fast-simplification) down to `target` faces; each
    kept vertex gets the mean colour of the vertices collapsed into it."""
    import fast_simplification

    # Own writable C-ordered copies: fast-simplification's binding refuses read-only arrays (a request's
    # mesh arrays are shared and frozen) and non-contiguous or other-typed ones alike.
    faces = np.array(mesh.faces, np.int32, order="C", copy=True)
    with _DECIMATION_LOCK:
        vertices, out_faces, collapses = fast_simplification.simplify(
            np.array(mesh.vertices, np.float64, order="C", copy=True), faces, target_count=target,
            return_collapses=True)
    colors = None
    if mesh.vertex_colors is not None:
        into = _collapsed_into(mesh, faces, out_faces, collapses)
        kept = into >= 0
        counts = np.bincount(into[kept], minlength=len(vertices)).astype(np.float64)
        sums = np.column_stack([np.bincount(into[kept], mesh.vertex_colors[kept, i].astype(np.float64),
                                            len(vertices)) for i in range(3)])
        colors = np.clip(np.round(sums / np.maximum(counts, 1)[:, None]), 0, 255).astype(np.uint8)
    return Mesh(vertices, out_faces.astype(np.int64), colors, frame_id=mesh.frame_id)


def _collapsed_into(mesh: Mesh, faces: np.ndarray, out_faces: np.ndarray, collapses: np.ndarray) -> np.ndarray:
    """For each input vertex the output vertex it was collapsed into (-1: into none that was kept).

    Following the collapses (i1 into i0) to their ends gives each vertex its survivor; the kept
    faces are the input faces whose three survivors differ, numbered in input order. That is checked
    against the decimator's faces; should it ever not hold, fast-simplification's own replay decides.
    """
    survivor = np.arange(mesh.num_vertices)
    if len(collapses):
        survivor[collapses[:, 1]] = collapses[:, 0]
    while True:  # pointer jumping: log(chain length) passes
        jumped = survivor[survivor]
        if np.array_equal(jumped, survivor):
            break
        survivor = jumped
    mapped = survivor[faces]
    alive = (mapped[:, 0] != mapped[:, 1]) & (mapped[:, 1] != mapped[:, 2]) & (mapped[:, 0] != mapped[:, 2])
    kept, numbered = np.unique(mapped[alive], return_inverse=True)
    if not np.array_equal(numbered.reshape(-1, 3), out_faces):
        from fast_simplification import replay_simplification

        return replay_simplification(np.asarray(mesh.vertices, np.float32), faces, collapses)[2]
    if len(kept) == 0:
        return np.full(mesh.num_vertices, -1)
    index = np.minimum(np.searchsorted(kept, survivor), len(kept) - 1)
    return np.where(kept[index] == survivor, index, -1)


def _up_rotation(mesh: Mesh, gravity: np.ndarray | None, config: ReconstructionConfig,
                 report: CleanReport, down_hint: np.ndarray | None) -> np.ndarray | None:
    """The rotation taking the estimated (or recorded) up onto +z, or None to keep the mesh's orientation."""
    z = np.array([0.0, 0.0, 1.0])
    estimate = estimate_mesh_up(mesh, down_hint, gravity)
    report.up_estimate, report.up_confidence = estimate, estimate.confidence
    # Up onto +z and the walls onto +-x/+-y (perch_common.frames): the same room in any orientation
    # is cleaned into the same frame.
    if estimate.source == "gravity":
        report.up_source = "gravity"
        return estimate.aligned_rotation()
    if estimate.confidence >= config.min_up_confidence:
        report.up_source = "planes"
        return estimate.aligned_rotation()
    if estimate.axis_confidence >= config.min_up_confidence:
        # The vertical is clear but not which end is up: keep the end nearer the mesh's own +z.
        report.up_source = "planes, sign kept"
        report.warnings.append(f"up axis found but its sign is uncertain (confidence {estimate.sign_confidence:.2f}); "
                               "kept the end nearer the mesh's +z. Pass the gravity direction if it is wrong")
        return estimate.aligned_rotation(estimate.toward(z))
    report.warnings.append(f"no clear up axis (confidence {estimate.confidence:.2f} < {config.min_up_confidence}); "
                           "mesh left in its own orientation. " + "; ".join(estimate.notes))
    return None
