"""Precision / recall of filter output against the independent oracle (filtering_checker).

Used by the accuracy tests and by `perch bench filter --scene` (loaded from this folder).
"""

from __future__ import annotations

import numpy as np
import shapely
from filtering_checker import SceneOracle, Spec, sample_mesh_surface, sample_plane

from perch_common.scene_generator import GeneratedScene, SemanticClass

NOT_PERCHABLE = (SemanticClass.DOOR, SemanticClass.WINDOW)


def filter_input_surfaces(scene: GeneratedScene) -> list:
    """Ground-truth surfaces without doors and windows (not perchable whatever their geometry)."""
    out = []
    for s in scene.ground_truth_surfaces():
        if scene.face_class[s.face_indices[0]] not in NOT_PERCHABLE:
            out.append(s)
    return out


def plane_of(scene: GeneratedScene, surface) -> int:
    return int(np.bincount(scene.face_plane[surface.face_indices]).argmax())


def spec_from(config) -> Spec:
    return Spec(**{k: getattr(config, k) for k in Spec.__dataclass_fields__})


def evaluate(scene: GeneratedScene, surfaces: list, result, spec: Spec, seed: int = 0,
             precision_samples: int = 1500, recall_spacing: float = 0.15) -> dict:
    """precision, recall and the hard failures (wrong side, above furniture, unreachable) as area shares."""
    rng = np.random.default_rng(seed)
    oracle = SceneOracle(scene, spec)
    plane_by_surface = {s.id: plane_of(scene, s) for s in surfaces}
    out: dict = {"regions": len(result.regions), "area_m2": float(sum(r.area for r in result.regions))}

    # Precision: uniform samples over all output regions, each judged on its source plane.
    wrong_side = 0.0
    for region in result.regions:
        plane = scene.planes[plane_by_surface[region.source_surface]]
        if region.frame.normal @ plane.normal < 0.99:
            wrong_side += region.area
    out["wrong_side_m2"] = wrong_side
    if result.regions:
        areas = np.array([r.area for r in result.regions])
        counts = rng.multinomial(precision_samples, areas / areas.sum())
        valid, unreachable, furniture = [], [], []
        for region, count in zip(result.regions, counts):
            if count == 0:
                continue
            points, _ = sample_mesh_surface(region.mesh, int(count), rng)
            pid = plane_by_surface[region.source_surface]
            valid.append(oracle.valid(pid, points))
            unreachable.append(~oracle.reachable(pid, points))
            furniture.append(above_furniture(scene, oracle, pid, points, spec))
        valid = np.concatenate(valid)
        out["precision"] = float(valid.mean())
        out["unreachable_share"] = float(np.concatenate(unreachable).mean())
        out["above_furniture_share"] = float(np.concatenate(furniture).mean())
        out["precision_samples"] = int(len(valid))
    else:
        out.update(precision=1.0, unreachable_share=0.0, above_furniture_share=0.0, precision_samples=0)

    # Recall: oracle-valid samples on the enabled input planes that some output region covers.
    hits, total = 0, 0
    for s in surfaces:
        pid = plane_by_surface[s.id]
        if not oracle.enabled(pid):
            continue
        points = sample_plane(scene, pid, recall_spacing, rng)
        ok = oracle.valid(pid, points)
        if not ok.any():
            continue
        covered = np.zeros(int(ok.sum()), bool)
        for region in result.regions:
            if region.source_surface != s.id:
                continue
            uv = region.frame.to_plane(points[ok])
            for rings in region.polygons:
                covered |= shapely.contains_xy(shapely.Polygon(rings[0], rings[1:]), uv[:, 0], uv[:, 1])
        hits += int(covered.sum())
        total += int(ok.sum())
    out["recall"] = float(hits / total) if total else 1.0
    out["recall_samples"] = total
    return out


def above_furniture(scene: GeneratedScene, oracle: SceneOracle, plane_id: int, points: np.ndarray,
                    spec: Spec) -> np.ndarray:
    """Wall points with furniture surface in their fall corridor (the window grown by the approach
    margin wide, 2 rho deep) less than h_min below them, from dense random samples of the furniture
    faces."""
    if oracle.plane_class(plane_id) != "wall":
        return np.zeros(len(points), bool)
    furniture = _furniture_points(scene)
    n, up = scene.planes[plane_id].normal, oracle.up
    side = np.cross(up, n)
    side /= np.linalg.norm(side)
    depth = (furniture - points[0]) @ n
    furniture = furniture[(depth > 0.01) & (depth <= 2 * spec.drone_radius)]
    bad = np.zeros(len(points), bool)
    for k, p in enumerate(points):
        d = furniture - p
        below = d @ up
        bad[k] = bool(np.any((np.abs(d @ side) <= spec.window_width / 2 + spec.approach_margin) & (below < 0)
                             & (below >= -spec.min_recovery_height)))
    return bad


def _furniture_points(scene: GeneratedScene, density: float = 2500.0) -> np.ndarray:
    cache = getattr(scene, "_furniture_samples", None)
    if cache is None:
        rng = np.random.default_rng(7)
        faces = np.flatnonzero(scene.face_class == SemanticClass.FURNITURE)
        if len(faces) == 0:
            cache = np.zeros((0, 3))
        else:
            areas = scene.mesh.face_areas()[faces]
            count = int(areas.sum() * density) + 1
            pick = rng.choice(faces, size=count, p=areas / areas.sum())
            tris = scene.mesh.triangles()[pick]
            r1, r2 = rng.random(count), rng.random(count)
            flip = r1 + r2 > 1
            r1[flip], r2[flip] = 1 - r1[flip], 1 - r2[flip]
            cache = tris[:, 0] + r1[:, None] * (tris[:, 1] - tris[:, 0]) + r2[:, None] * (tris[:, 2] - tris[:, 0])
        scene._furniture_samples = cache
    return cache
