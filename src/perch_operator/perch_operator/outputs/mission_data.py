"""What a recorded mission contains, in pure-Python form: read once from run.mcap for the views.

A recording alone rebuilds the report and the rerun file (`load_mission`); after a live mission the
accepted placements, waypoints and scores come from the PlanPerches result instead
(`mission_data_from_result`), so they never depend on what a recorder happened to catch.
The geometry (mesh, surfaces, regions, target, placements) is kept in the gravity-aligned frame the
stages worked in; `alignment` takes it to the input's own frame, in which the waypoints are.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from perch_common.frames import ALIGNED_SUFFIX, Alignment
from perch_common.mesh import Mesh
from perch_common.target import TargetVolume
from perch_common.types import CameraPlacement, FilterRemoval, PerchRegion, Surface
from perch_operator.coordinator.proposals import Status
from perch_operator.outputs.report_robustness import ROBUSTNESS_FIELDS

MISSION_METADATA = "perch_mission"


@dataclass
class MissionData:
    """A mission read back from its run.mcap: inputs, stage results, proposals and waypoints."""

    mesh: Mesh | None = None                 # the environment the cameras were placed in
    cropped: Mesh | None = None              # what segmentation saw
    surfaces: list[Surface] = field(default_factory=list)
    regions: list[PerchRegion] = field(default_factory=list)
    removals: list[FilterRemoval] = field(default_factory=list)
    target: TargetVolume | None = None
    placements: list[CameraPlacement] = field(default_factory=list)   # accepted, by drone index
    rejected: list[tuple[CameraPlacement, str]] = field(default_factory=list)
    waypoints: list[dict] = field(default_factory=list)              # in the input frame
    summary: dict = field(default_factory=dict)   # stage times, scores (metadata record)
    alignment: Alignment = field(default_factory=lambda: Alignment("map", np.eye(3), "none", 0.0))


    @property
    def input_frame(self) -> str:
        """The frame the user gave the input in (waypoints, tables, console lines)."""
        return self.alignment.input_frame

    @property
    def aligned_frame(self) -> str:
        """The gravity-aligned frame the stages worked in (only in views labelled so)."""
        return self.alignment.aligned_frame

    def position_in_input(self, pose) -> np.ndarray:
        """The position of a gravity-aligned 4x4 pose (a placement's, a rejected perch's) in the input frame."""
        return self.alignment.pose_to_input(np.asarray(pose, np.float64))[:3, 3]


def load_mission(path: str | Path) -> MissionData:
    """Read the stage replies, proposals and waypoints of one recorded mission."""
    from perch_common.ros.conversions import (
        held_mesh,
        mesh_from_msg,
        placement_from_msg,
        region_from_msg,
        removal_from_msg,
        surface_from_msg,
        target_from_msg,
    )
    from perch_common.ros.static_transforms import TF_STATIC_TOPIC, alignment_from_msg
    from perch_operator.coordinator.messages import classed_surfaces
    from perch_operator.outputs.runfile import iter_messages, metadata, stage_calls

    def recorded_mesh(msg):
        # A mesh sent by content id only (its arrays went in an earlier mission) is not in this file.
        if not len(msg.triangles):
            return None
        return held_mesh(msg) or mesh_from_msg(msg)

    data = MissionData()
    for call in stage_calls(path):
        reply = call.response
        if reply is None or not reply.success:
            continue
        if call.stage in ("clean", "reconstruct"):
            data.mesh = recorded_mesh(reply.mesh)
        elif call.stage == "crop":
            data.cropped = recorded_mesh(reply.mesh)
            data.target = target_from_msg(reply.target)
            if data.mesh is None and call.request is not None:
                data.mesh = recorded_mesh(call.request.mesh)
        elif call.stage == "segment" and not data.surfaces:
            data.surfaces = [surface_from_msg(s) for s in reply.surfaces]
        elif call.stage == "filter":
            # The filter classes the surfaces it was sent (the reply echoes them only when asked).
            sent = reply.surfaces or (call.request.surfaces if call.request is not None else [])
            if sent:
                data.surfaces = [surface_from_msg(s) for s in classed_surfaces(sent, reply.removals)]
            data.regions = [region_from_msg(r) for r in reply.regions]
            data.removals = [removal_from_msg(r) for r in reply.removals]
        elif call.stage == "optimise" and data.mesh is None and call.request is not None:
            data.mesh = recorded_mesh(call.request.mesh)
    latest: dict[int, object] = {}
    tf_static = "/" + TF_STATIC_TOPIC  # iter_messages names topics relative to the recorded namespace
    for topic, msg, _ in iter_messages(path, ["/perch/proposals", "/perch/waypoints", tf_static]):
        if topic == "/perch/proposals":
            latest[msg.id] = msg
        elif topic == tf_static:
            for transform in msg.transforms:
                if transform.child_frame_id.endswith(ALIGNED_SUFFIX):
                    data.alignment = alignment_from_msg(transform)
        else:
            data.waypoints.append(waypoint_dict(msg))
    by_slot: dict[int, CameraPlacement] = {}
    for proposal in latest.values():
        # Proposals went out in the input frame; the rest of the mission data is gravity-aligned.
        placement = data.alignment.placement_to_aligned(placement_from_msg(proposal.placement))
        if proposal.status == Status.ACCEPTED:
            by_slot[placement.drone_index] = placement
        elif proposal.status in (Status.REJECTED, Status.FAILED):
            data.rejected.append((placement, proposal.reason))
    data.placements = [by_slot[k] for k in sorted(by_slot)]
    data.summary = metadata(path).get(MISSION_METADATA, {})
    if data.mesh is None:
        data.mesh = data.cropped
    return data


def mission_data_from_result(path: str | Path, result, goal=None) -> MissionData:
    """The views' data for a finished mission: placements, waypoints and scores from the PlanPerches
    result; mesh, surfaces, regions and target from the recorded stage replies, else from the goal."""
    from perch_common.ros.conversions import mesh_from_msg, placement_from_msg, target_from_msg
    from perch_common.ros.static_transforms import alignment_from_msg
    from perch_operator.coordinator.messages import target_to_aligned

    data = load_mission(path)
    if result.alignment.header.frame_id:
        data.alignment = alignment_from_msg(result.alignment)
    # The result is in the input frame; the views' geometry is gravity-aligned (see the module doc).
    data.placements = sorted((data.alignment.placement_to_aligned(placement_from_msg(p)) for p in result.placements),
                             key=lambda p: p.drone_index)
    data.waypoints = [waypoint_dict(w) for w in result.waypoints]
    if goal is not None and data.mesh is None and len(goal.mesh.triangles):
        data.mesh = mesh_from_msg(goal.mesh, "goal mesh").transformed(data.alignment.to_aligned())
    if goal is not None and data.target is None:
        data.target = target_from_msg(target_to_aligned(goal.target, data.alignment))  # None for KIND_DEFAULT
    data.summary = {**data.summary, "success": bool(result.success), "message": result.message,
                    "stage_names": list(result.stage_names), "stage_seconds": list(result.stage_seconds),
                    "fitness": result.fitness, "coverage": result.coverage,
                    "mean_uncertainty": result.mean_uncertainty, "cameras": len(result.placements),
                    **{name: float(getattr(result, name)) for name in ROBUSTNESS_FIELDS}}
    return data


def mission_id_text(mission_id) -> str:
    """A mission (goal) id (unique_identifier_msgs/UUID) as 32 hex digits, as dispatchers show it."""
    return bytes(bytearray(mission_id.uuid)).hex()


def waypoint_dict(msg) -> dict:
    """A waypoint message as plain data (for waypoints.yaml)."""
    p, q, a = msg.pose.pose.position, msg.pose.pose.orientation, msg.approach
    return {"mission_id": mission_id_text(msg.mission_id),
            "drone_index": int(msg.drone_index), "proposal_id": int(msg.proposal_id),
            "frame_id": msg.pose.header.frame_id,
            "position": [round(float(v), 6) for v in (p.x, p.y, p.z)],
            "orientation_xyzw": [round(float(v), 6) for v in (q.x, q.y, q.z, q.w)],
            "approach": [round(float(v), 6) for v in (a.x, a.y, a.z)],
            "pan": round(float(msg.pan), 6), "tilt": round(float(msg.tilt), 6), "zoom": round(float(msg.zoom), 6)}


def latest_waypoints(waypoints: list[dict]) -> list[dict]:
    """The last waypoint of each drone (a re-plan supersedes earlier ones), by drone index."""
    latest = {w["drone_index"]: w for w in waypoints}
    return [latest[k] for k in sorted(latest)]


def write_waypoints_yaml(path: str | Path, waypoints: list[dict], coordinates: str = "") -> Path:
    """waypoints.yaml: the latest accepted waypoint per drone, for a dispatcher without ROS.
    `coordinates`: how the positions relate to the mesh file when it was scaled or shifted on loading."""
    import yaml

    latest = latest_waypoints(waypoints)
    doc = {"frame_id": latest[0]["frame_id"] if latest else "map",
           "units": "metres, radians; orientation is the drone body (z along the perch normal)",
           **({"coordinates": coordinates} if coordinates else {}),
           "waypoints": latest}
    from perch_common.outputs import atomic_path

    path = Path(path)
    with atomic_path(path) as temporary:   # `perch dispatch --output` rewrites it while others read it
        temporary.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


def scaled_coordinates(scale: float, shift) -> str:
    """The waypoints.yaml note for a mesh loaded with --scale/--shift ('' for neither)."""
    if scale == 1.0 and shift is None:
        return ""
    offset = ", ".join(f"{float(v):.12g}" for v in (shift if shift is not None else (0.0, 0.0, 0.0)))
    return (f"the mesh file's coordinates x {scale:.12g} + [{offset}] m (--scale, --shift): "
            f"(position - [{offset}]) / {scale:.12g} is in the file's")


def target_point_scores(data: MissionData) -> tuple[np.ndarray, np.ndarray] | None:
    """Target sample points and their score (0 unseen .. 1 certain) under the accepted cameras.

    Uses the placement stage's own evaluator and its configured camera, so the colours mean what
    the optimiser maximised. None when perch_placement is not installed.
    """
    import importlib.util

    if data.target is None or data.mesh is None or importlib.util.find_spec("perch_placement") is None:
        return None
    from perch_placement.core import scene_for
    from perch_placement.fitness import Evaluator, point_score

    config = placement_config()
    points = data.target.sample(config.target_points, seed=config.seed)
    # The mesh's own scene (kept with it): the one the views were rendered with, or the stages' own.
    evaluator = Evaluator(scene_for(data.mesh), points, config.camera, config.occlusion_epsilon)
    for p in data.placements:
        pose = np.asarray(p.camera_pose)
        evaluator.commit(pose[:3, 3], pose[:3, :3], max(float(p.zoom), 1.0))
    scores, _ = point_score(evaluator.info, evaluator.seen)
    return points, np.asarray(scores, np.float64)


def placement_config():
    """The placement stage's configuration as the graph runs it (config/perch.yaml)."""
    from perch_common.config import ConfigError, from_parameters, node_parameters
    from perch_placement.config import PlacementConfig

    try:
        return from_parameters(PlacementConfig, node_parameters("perch_placement")).resolved()
    except (ConfigError, OSError):
        return PlacementConfig().resolved()
