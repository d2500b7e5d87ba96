"""Conventions every stage shares: surface classes by the configured angle, the filter names and the
stage service names (and which node offers each)."""

from __future__ import annotations

import math
from dataclasses import fields

import numpy as np

from perch_common.types import FilterRemoval, SurfaceClass

# Tolerance of the floor / wall / ceiling classes (FilterConfig.class_angle_deg's default).
DEFAULT_CLASS_ANGLE_DEG = 15.0


def surface_classes(normals: np.ndarray, up: np.ndarray, angle_deg: float = DEFAULT_CLASS_ANGLE_DEG) -> np.ndarray:
    """SurfaceClass codes (K,) of oriented unit normals (K,3): FLOOR within `angle_deg` of up, CEILING
    within it of down, WALL within it of horizontal, INTERMEDIATE between."""
    cos_up = np.asarray(normals, np.float64).reshape(-1, 3) @ np.asarray(up, np.float64)
    angle = math.radians(angle_deg)
    out = np.full(len(cos_up), int(SurfaceClass.INTERMEDIATE))
    out[np.abs(cos_up) <= np.sin(angle)] = SurfaceClass.WALL
    out[cos_up <= -np.cos(angle)] = SurfaceClass.CEILING
    out[cos_up >= np.cos(angle)] = SurfaceClass.FLOOR
    return out


def surface_class(normal: np.ndarray, up: np.ndarray, angle_deg: float = DEFAULT_CLASS_ANGLE_DEG) -> SurfaceClass:
    """The SurfaceClass of one oriented unit normal (see surface_classes)."""
    return SurfaceClass(int(surface_classes(normal, up, angle_deg)[0]))


def is_wall(normals: np.ndarray, up: np.ndarray, angle_deg: float = DEFAULT_CLASS_ANGLE_DEG) -> np.ndarray:
    """Whether each unit normal (K,3), either way round, is within `angle_deg` of horizontal."""
    return surface_classes(normals, up, angle_deg) == SurfaceClass.WALL


# The safety filters in pipeline order: FilterRemoval's per-filter area fields (add a filter there).
FILTER_NAMES: tuple[str, ...] = tuple(f.name for f in fields(FilterRemoval)
                                      if f.name not in ("surface_id", "area_total", "area_kept"))
# One colour (RGB 0-255) per filter, FILTER_NAMES order, for every picture of removed area.
FILTER_COLOURS: tuple[tuple[int, int, int], ...] = (
    (150, 150, 150), (230, 200, 40), (240, 140, 30), (230, 60, 40), (120, 80, 40), (170, 60, 200), (40, 160, 220))

# Each pipeline stage's service (relative: resolved in the node's namespace).
STAGE_SERVICES: dict[str, str] = {
    "reconstruct": "perch/reconstruct",
    "clean": "perch/clean_mesh",
    "crop": "perch/crop",
    "segment": "perch/segment",
    "filter": "perch/filter",
    "optimise": "perch/optimise",
}
CONFIRM_SERVICE = "perch/confirm"  # the operator's accept/reject service (not a pipeline stage)
# The mission action and the two of its topics a client or recorder names itself (relative names).
MISSION_ACTION = "perch/plan_perches"
MISSION_FEEDBACK_TOPIC = MISSION_ACTION + "/_action/feedback"
MISSION_STATUS_TOPIC = MISSION_ACTION + "/_action/status"
MISSION_SEND_GOAL_SERVICE = MISSION_ACTION + "/_action/send_goal"  # every action client of the mission has one
# A mission client's presence: while it waits for goal G it keeps a writer on MISSION_CLIENT_PREFIX + G's
# hex (a hidden topic, never published on). The coordinator watches that writer, not every feedback
# reader, so a console or a recorder left open does not keep a killed client's mission alive. Perch's
# tools that read every mission's feedback (console, commander, recorder, perch plan) keep a writer on
# MISSION_OBSERVER_TOPIC: for a plain ROS client's goal, the coordinator does not take their readers for
# the client's. Nothing is ever sent under MISSION_PRESENCE_PREFIX (recordings leave it out).
MISSION_PRESENCE_PREFIX = MISSION_ACTION + "/_client/"
MISSION_CLIENT_PREFIX = MISSION_PRESENCE_PREFIX + "g"
MISSION_OBSERVER_TOPIC = MISSION_PRESENCE_PREFIX + "observer"


def mission_client_topic(goal_id) -> str:
    """The presence topic (relative) of the client of goal `goal_id` (16 bytes, or a UUID message's list)."""
    return MISSION_CLIENT_PREFIX + bytes(goal_id).hex()
# Which node offers which services; the first one tells that the node is up.
NODE_SERVICES: dict[str, list[str]] = {
    "perch_operator": [STAGE_SERVICES["crop"], CONFIRM_SERVICE],
    "perch_reconstruction": [STAGE_SERVICES["clean"], STAGE_SERVICES["reconstruct"]],
    "perch_segmentation": [STAGE_SERVICES["segment"]],
    "perch_filtering": [STAGE_SERVICES["filter"]],
    "perch_placement": [STAGE_SERVICES["optimise"]],
}
