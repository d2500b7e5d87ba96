"""perch_interfaces messages built by the operator (proposals, waypoints, boxes).

The frame contract's boundary: what goes out (proposals, placements, waypoints, pose arrays) is
turned from the gravity-aligned frame the stages work in into the input's own frame here, and what
comes in with a goal (boxes, target) the other way.
"""

from __future__ import annotations

import numpy as np
from geometry_msgs.msg import PoseArray, PoseStamped
from unique_identifier_msgs.msg import UUID

from perch_common.frames import Alignment
from perch_common.ros.conversions import (
    box_from_msg,
    evidence_to_msg,
    mesh_from_msg,
    mesh_to_msg,
    placement_to_msg,
    point_msg,
    pose_msg,
)
from perch_common.transforms import pose_to_matrix
from perch_common.types import PerchEvidence
from perch_interfaces import msg as pm
from perch_operator.coordinator.crop import Box
from perch_operator.coordinator.proposals import Proposal, approach_point


def box_from_ros(msg: pm.OrientedBox, what: str) -> Box:
    """A crop box of a perch_interfaces/OrientedBox (ValueError naming `what` when unusable)."""
    center, size, rotation = box_from_msg(msg)
    try:
        return Box(center, size, rotation)
    except ValueError as exc:
        raise ValueError(f"{what}: {exc}") from None


def proposal_msg(proposal: Proposal, alignment: Alignment, regions=(), mission_id: UUID | None = None) -> pm.Proposal:
    """A proposal as published, its placement in the input frame, with the safety evidence of its
    perch region (one of `regions`, PerchRegion messages; -1 values when it is not among them), tagged
    with its mission (the goal id: the topic's history holds earlier missions' proposals too)."""
    region = next((r for r in regions if r.id == proposal.placement.region_id), None)
    return pm.Proposal(id=proposal.id, mission_id=mission_id or UUID(), status=int(proposal.status), reason=proposal.reason,
                       placement=placement_msg(proposal, alignment),
                       evidence=region.evidence if region is not None else evidence_to_msg(PerchEvidence()))


def placement_msg(proposal: Proposal, alignment: Alignment) -> pm.CameraPlacement:
    """The proposal's placement in the input frame, numbered by its drone slot."""
    msg = placement_to_msg(alignment.placement_to_input(proposal.placement))
    msg.drone_index = proposal.slot
    return msg


def waypoint_msg(proposal: Proposal, approach_distance: float, alignment: Alignment, stamp,
                 mission_id: UUID | None = None) -> pm.PerchWaypoint:
    """The waypoint of an accepted proposal, in the input frame (frame_id: alignment.input_frame), tagged
    with its mission (the goal id)."""
    p = proposal.placement
    approach = alignment.point_to_input(approach_point(p, approach_distance))
    msg = pm.PerchWaypoint(mission_id=mission_id or UUID(), approach=point_msg(approach), drone_index=proposal.slot,
                           proposal_id=proposal.id, pan=float(p.pan), tilt=float(p.tilt), zoom=float(p.zoom))
    msg.pose = PoseStamped(pose=pose_msg(alignment.pose_to_input(p.drone_pose)))
    msg.pose.header.frame_id = alignment.input_frame
    msg.pose.header.stamp = stamp
    return msg


def waypoint_set_msg(mission_id: UUID, waypoints: list[pm.PerchWaypoint], frame_id: str, stamp) -> pm.PerchWaypointSet:
    """The current mission's accepted waypoints as one latched message."""
    msg = pm.PerchWaypointSet(mission_id=mission_id, waypoints=list(waypoints))
    msg.header.frame_id = frame_id
    msg.header.stamp = stamp
    return msg


def pose_array_msg(proposals: list[Proposal], alignment: Alignment, stamp) -> PoseArray:
    """The drone poses of `proposals` in the input frame."""
    msg = PoseArray(poses=[pose_msg(alignment.pose_to_input(p.placement.drone_pose)) for p in proposals])
    msg.header.frame_id = alignment.input_frame
    msg.header.stamp = stamp
    return msg


def boxes_to_aligned(boxes, alignment: Alignment) -> list[pm.OrientedBox]:
    """Goal boxes (input frame) in the gravity-aligned frame."""
    to_aligned = alignment.to_aligned()
    out = []
    for box in boxes:
        pose = to_aligned @ pose_to_matrix(box.pose)
        out.append(pm.OrientedBox(pose=pose_msg(pose), size=box.size))
    return out


def target_to_aligned(target: pm.TargetVolume, alignment: Alignment) -> pm.TargetVolume:
    """A goal's target (input frame) in the gravity-aligned frame; a footprint is then projected along
    the true up."""
    if alignment.is_identity() or target.kind == pm.TargetVolume.KIND_DEFAULT:
        return target
    out = pm.TargetVolume(kind=target.kind, height=target.height)
    if target.kind == pm.TargetVolume.KIND_BOX:
        out.box, *out.more_boxes = boxes_to_aligned([target.box, *target.more_boxes], alignment)
    elif target.kind == pm.TargetVolume.KIND_EXTRUDED_FOOTPRINT:
        footprint = mesh_from_msg(target.footprint, "target footprint").transformed(alignment.to_aligned())
        footprint.frame_id = alignment.aligned_frame
        out.footprint = mesh_to_msg(footprint)
    else:
        out = target  # an unknown kind: crop answers it with a clear error
    return out


def surface_to_input(surface: pm.Surface, alignment: Alignment) -> pm.Surface:
    """A copy of a (gravity-aligned) surface message with its plane frame in the input frame; its
    outline stays in plane coordinates and its face indices in the mesh it was segmented from."""
    import copy

    out = copy.deepcopy(surface)
    r = np.asarray(alignment.rotation).T
    frame = out.frame
    frame.origin = point_msg(r @ [frame.origin.x, frame.origin.y, frame.origin.z])
    for name in ("axis_u", "axis_v", "normal"):
        v = getattr(frame, name)
        moved = r @ [v.x, v.y, v.z]
        v.x, v.y, v.z = (float(c) for c in moved)
    return out


def classed_surfaces(surfaces, removals) -> list[pm.Surface]:
    """Copies of the surfaces sent to the filter, each with the class the filter gave it (its removal's
    surface_class): what viewers and reports show, without the filter echoing every surface."""
    import copy

    classes = {r.surface_id: r.surface_class for r in removals}
    out = []
    for surface in surfaces:
        classed = copy.copy(surface)
        classed.surface_class = classes.get(surface.id, surface.surface_class)
        out.append(classed)
    return out
