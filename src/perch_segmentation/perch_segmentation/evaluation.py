"""Accuracy of a segmentation against per-face ground-truth plane labels (procedural scenes)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from perch_common.types import Surface

FLOOR, CEILING = 1, 3  # perch_common.scene_generator.SemanticClass codes


@dataclass
class PlaneScores:
    """How well surfaces match the ground-truth planes: recall, precision and normal errors."""

    plane_recall: float        # ground-truth planes >= min_area matched with IoU >= iou
    plane_precision: float     # predicted surfaces >= min_area matched with IoU >= iou
    normal_error_deg: float    # largest normal error over matched pairs
    mean_normal_error_deg: float
    ground_truth_planes: int
    predicted_surfaces: int
    matched: int

    def as_dict(self) -> dict:
        """The scores as a plain dict."""
        return dict(self.__dict__)


def unite_boundary_planes(face_plane: np.ndarray, planes, tolerance: float = 0.05) -> np.ndarray:
    """Ground truth with the pieces of the floor (and of the ceiling) that lie in one plane as one
    plane: the stage reports the floor and the ceiling as single surfaces (the issue's step 2)."""
    new_id = np.arange(max(len(planes), 1))
    for cls in (FLOOR, CEILING):
        members = [p for p in planes if int(p.semantic_class) == cls]
        for p in members:
            for q in members:
                if q.id < p.id and new_id[q.id] == q.id and float(p.normal @ q.normal) > 0.99 \
                        and abs(p.offset - q.offset) < tolerance:
                    new_id[p.id] = q.id
                    break
    out = face_plane.copy()
    labelled = face_plane >= 0
    out[labelled] = new_id[face_plane[labelled]]
    return out


def score_planes(face_labels: np.ndarray, surfaces: list[Surface], face_plane: np.ndarray,
                 plane_normals: np.ndarray, areas: np.ndarray, min_area: float = 0.5,
                 iou_threshold: float = 0.8) -> PlaneScores:
    """Face-area IoU matching of predicted surfaces to ground-truth planes.

    plane_normals: (G,3) ground-truth unit normals indexed by plane id (united ids share one).
    """
    g_count = int(face_plane.max()) + 1 if (face_plane >= 0).any() else 0
    p_count = len(surfaces)
    gt = np.where(face_plane >= 0, face_plane, g_count)
    pred = np.where(face_labels >= 0, face_labels, p_count)
    inter = np.bincount(gt * (p_count + 1) + pred, weights=areas,
                        minlength=(g_count + 1) * (p_count + 1)).reshape(g_count + 1, p_count + 1)
    gt_area, pred_area = inter.sum(axis=1)[:g_count], inter.sum(axis=0)[:p_count]
    inter = inter[:g_count, :p_count]
    iou = inter / np.maximum(gt_area[:, None] + pred_area[None, :] - inter, 1e-18)
    big_gt = np.flatnonzero(gt_area >= min_area)
    big_pred = np.flatnonzero(pred_area >= min_area)
    gt_hit = iou[big_gt].max(axis=1) >= iou_threshold if p_count else np.zeros(len(big_gt), bool)
    pred_hit = iou[:, big_pred].max(axis=0) >= iou_threshold if g_count else np.zeros(len(big_pred), bool)
    errors = []
    for g in big_gt[gt_hit]:
        p = int(np.argmax(iou[g]))
        cos = float(np.clip(surfaces[p].frame.normal @ plane_normals[g], -1.0, 1.0))
        errors.append(np.degrees(np.arccos(cos)))
    return PlaneScores(
        plane_recall=float(gt_hit.mean()) if len(big_gt) else 1.0,
        plane_precision=float(pred_hit.mean()) if len(big_pred) else 1.0,
        normal_error_deg=float(max(errors)) if errors else float("nan"),
        mean_normal_error_deg=float(np.mean(errors)) if errors else float("nan"),
        ground_truth_planes=int(len(big_gt)), predicted_surfaces=int(len(big_pred)), matched=int(gt_hit.sum()))


def score_scene(scene, result, unite_floor_ceiling: bool = True, **kwargs) -> PlaneScores:
    """score_planes for a perch_common.scene_generator.GeneratedScene and a SegmentationResult."""
    face_plane = scene.face_plane
    if unite_floor_ceiling:
        face_plane = unite_boundary_planes(face_plane, scene.planes)
    normals = np.array([p.normal for p in scene.planes]).reshape(-1, 3)
    return score_planes(result.face_labels, result.surfaces, face_plane, normals,
                        scene.mesh.face_areas(), **kwargs)
