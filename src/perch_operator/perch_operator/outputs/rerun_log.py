"""A rerun recording (.rrd) of one mission: mesh, surfaces by class, what the filters removed,
perch regions, target volume and its points coloured by score, camera frustums with their
simulated views, waypoints and rejected perches. The recording's root is the input frame; the
entity `frames` names the frame of each part."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from perch_common.conventions import FILTER_COLOURS
from perch_common.conventions import FILTER_NAMES as FILTERS
from perch_common.mesh import Mesh
from perch_operator.outputs.mission_data import MissionData, latest_waypoints, target_point_scores

CLASS_COLOURS = {0: ("unknown", (150, 150, 150)), 1: ("floor", (200, 170, 90)), 2: ("wall", (90, 140, 220)),
                 3: ("ceiling", (200, 200, 240)), 4: ("intermediate", (220, 120, 60))}


def _mesh3d(rr, mesh: Mesh, colour=None):
    kwargs = {}
    if colour is not None:
        kwargs["albedo_factor"] = np.array([*colour, 255], np.uint8)
    elif mesh.vertex_colors is not None:
        kwargs["vertex_colors"] = mesh.vertex_colors
    return rr.Mesh3D(vertex_positions=mesh.vertices.astype(np.float32), triangle_indices=mesh.faces.astype(np.uint32),
                     **kwargs)


def write_rrd(data: MissionData, path: str | Path, views: list | None = None) -> Path:
    """Write the recording; `views` are the cameras' simulated images (BGR) if already rendered."""
    import rerun as rr

    path = Path(path)
    rec = rr.RecordingStream("perch")
    rec.save(str(path))
    # The recording's root is the input's own frame; "world" is the gravity-aligned frame the
    # stages worked in, placed in it by the mission's alignment (waypoints are logged at the root).
    rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    rec.log("world", rr.Transform3D(mat3x3=data.alignment.to_input()[:3, :3]), static=True)
    rec.log("frames", rr.TextDocument(frames_markdown(data), media_type=rr.MediaType.MARKDOWN), static=True)
    if data.mesh is not None:
        rec.log("world/mesh", _mesh3d(rr, data.mesh), static=True)
    _log_surfaces(rr, rec, data)
    for region in data.regions:
        rec.log(f"world/regions/{region.id}", _mesh3d(rr, region.mesh, (60, 200, 60)), static=True)
    if data.target is not None:
        rec.log("world/target/volume", rr.LineStrips3D(data.target.edges(), colors=[(255, 140, 0)]), static=True)
        scored = target_point_scores(data)
        if scored is not None:
            points, scores = scored
            colours = np.column_stack([255 * (1 - scores), 255 * scores, np.full(len(scores), 40)]).astype(np.uint8)
            rec.log("world/target/points", rr.Points3D(points, colors=colours, radii=0.03), static=True)
    _log_cameras(rr, rec, data, views)
    if data.rejected:
        centres = np.array([np.asarray(p.drone_pose)[:3, 3] for p, _ in data.rejected])
        rec.log("world/rejected", rr.Points3D(centres, colors=[(230, 40, 40)], radii=0.3 / 3,
                                              labels=[r or "rejected" for _, r in data.rejected]), static=True)
    if data.summary:
        rec.log("summary", rr.TextDocument(_summary_markdown(data), media_type=rr.MediaType.MARKDOWN), static=True)
    rec.flush()
    rec.disconnect()
    return path


def _log_surfaces(rr, rec, data: MissionData) -> None:
    if data.cropped is None or not data.surfaces:
        return
    by_class: dict[int, list[np.ndarray]] = {}
    for s in data.surfaces:
        by_class.setdefault(int(s.surface_class), []).append(np.asarray(s.face_indices))
    for code, faces in by_class.items():
        name, colour = CLASS_COLOURS.get(code, CLASS_COLOURS[0])
        rec.log(f"world/surfaces/{name}", _mesh3d(rr, data.cropped.submesh(np.concatenate(faces)), colour),
                static=True)
    # Each surface coloured by the filter that removed most of its area (kept ones are regions).
    removal = {r.surface_id: r for r in data.removals}
    by_filter: dict[str, list[np.ndarray]] = {}
    for s in data.surfaces:
        r = removal.get(s.id)
        if r is None:
            continue
        amounts = [getattr(r, f) for f in FILTERS]
        if max(amounts) > 0:
            by_filter.setdefault(FILTERS[int(np.argmax(amounts))], []).append(np.asarray(s.face_indices))
    for name, faces in by_filter.items():
        rec.log(f"world/removed_by/{name}", _mesh3d(rr, data.cropped.submesh(np.concatenate(faces)),
                                                    FILTER_COLOURS[FILTERS.index(name)]), static=True)


def _log_cameras(rr, rec, data: MissionData, views: list | None) -> None:
    import importlib.util

    camera = None
    if importlib.util.find_spec("perch_placement") is not None:
        from perch_operator.outputs.mission_data import placement_config

        camera = placement_config().camera
    for i, p in enumerate(data.placements):
        pose = np.asarray(p.camera_pose)
        entity = f"world/cameras/{p.drone_index}"
        rec.log(entity, rr.Transform3D(translation=pose[:3, 3], mat3x3=pose[:3, :3]), static=True)
        if camera is not None:
            rec.log(entity, rr.Pinhole(focal_length=[camera.fx, camera.fy], principal_point=[camera.cx, camera.cy],
                                       width=camera.width, height=camera.height,
                                       camera_xyz=rr.ViewCoordinates.RDF, image_plane_distance=0.4), static=True)
            if views and i < len(views) and views[i] is not None:
                rec.log(f"{entity}/view", rr.Image(np.ascontiguousarray(views[i][:, :, ::-1])), static=True)
    if data.waypoints:
        latest = latest_waypoints(data.waypoints)
        positions = np.array([w["position"] for w in latest])
        approach = np.array([w["approach"] for w in latest])
        rec.log("waypoints", rr.Points3D(positions, colors=[(30, 90, 230)], radii=0.06,
                                         labels=[f"drone {w['drone_index']} ({w.get('frame_id') or data.input_frame})"
                                                 for w in latest]), static=True)
        rec.log("waypoints/approach", rr.Arrows3D(origins=approach, vectors=positions - approach,
                                                  colors=[(30, 90, 230)]), static=True)


def frames_markdown(data: MissionData) -> str:
    """Which frame each entity of the recording is in (the root is the input frame)."""
    return "\n".join([
        f"- **root** (`waypoints`, `waypoints/approach`): the input frame `{data.input_frame}`, as waypoints.yaml",
        f"- **world** and below (mesh, surfaces, regions, target, cameras, rejected perches): the gravity-aligned "
        f"frame `{data.aligned_frame}` (up is +z), placed in `{data.input_frame}` by the mission's alignment, so "
        f"the viewer shows everything in `{data.input_frame}`"])


def _summary_markdown(data: MissionData) -> str:
    from perch_operator.outputs.report import summary_rows

    lines = ["| | |", "|---|---|"] + [f"| {k} | {v} |" for k, v in summary_rows(data)]
    stages = zip(data.summary.get("stage_names", []), data.summary.get("stage_seconds", []))
    lines += ["", "| stage | seconds |", "|---|---|"] + [f"| {n} | {t:.2f} |" for n, t in stages]
    return "\n".join(lines)
