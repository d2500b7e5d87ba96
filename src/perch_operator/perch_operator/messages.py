"""perch_interfaces messages built by the operator (proposals, waypoints, boxes)."""

from __future__ import annotations

import numpy as np
from geometry_msgs.msg import PoseArray, PoseStamped

from perch_common.ros.conversions import box_from_msg, placement_to_msg, point_msg, pose_msg
from perch_interfaces import msg as pm
from perch_operator.crop import Box
from perch_operator.proposals import Proposal, approach_point


def box_from_ros(msg: pm.OrientedBox, what: str) -> Box:
    center, size, rotation = box_from_msg(msg)
    try:
        return Box(center, size, rotation)
    except ValueError as exc:
        raise ValueError(f"{what}: {exc}") from None


def proposal_msg(proposal: Proposal) -> pm.Proposal:
    return pm.Proposal(id=proposal.id, status=int(proposal.status), reason=proposal.reason,
                       placement=placement_msg(proposal))


def placement_msg(proposal: Proposal) -> pm.CameraPlacement:
    msg = placement_to_msg(proposal.placement)
    msg.drone_index = proposal.slot
    return msg


def waypoint_msg(proposal: Proposal, approach_distance: float, frame_id: str, stamp) -> pm.PerchWaypoint:
    p = proposal.placement
    msg = pm.PerchWaypoint(approach=point_msg(approach_point(p, approach_distance)), drone_index=proposal.slot,
                           proposal_id=proposal.id, pan=float(p.pan), tilt=float(p.tilt), zoom=float(p.zoom))
    msg.pose = PoseStamped(pose=pose_msg(np.asarray(p.drone_pose)))
    msg.pose.header.frame_id = frame_id
    msg.pose.header.stamp = stamp
    return msg


def pose_array_msg(proposals: list[Proposal], frame_id: str, stamp) -> PoseArray:
    msg = PoseArray(poses=[pose_msg(np.asarray(p.placement.drone_pose)) for p in proposals])
    msg.header.frame_id = frame_id
    msg.header.stamp = stamp
    return msg
