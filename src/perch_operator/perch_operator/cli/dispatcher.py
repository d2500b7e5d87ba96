"""`perch dispatch`: a minimal drone dispatcher that receives the current mission's accepted perches.

It subscribes to perch/mission_waypoints (PerchWaypointSet) with the publisher's reliable,
transient-local QoS, so even when started after the mission it gets exactly the current mission's
accepted waypoints (never an older mission's); each new set replaces the previous one. It prints
them with the mission (goal) id and can keep a YAML file of them up to date. A real dispatcher
replaces the print with flight orders.

A set is accepted only from the coordinator that ran its mission: every writer of the waypoint
topic must belong to the process (DDS participant, the GID's first 12 bytes) that serves the mission
action, that process must be the only one serving it, and its goal status list must name the set's
mission. A set that cannot be attributed within ATTRIBUTE_WITHIN seconds (another node writes on
the topic, a second action server, an unknown mission) is refused with a log line naming the
writers, and the previous set stays.

The --output file is replaced only while it is a waypoints file of write_waypoints_yaml's layout,
writable, and not a mission's output (replace_refusal): any other file there is refused when the
dispatcher starts, and left alone (with a log line) should it appear later.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

from rclpy.node import Node

from perch_common.conventions import MISSION_STATUS_TOPIC
from perch_interfaces.msg import PerchWaypointSet
from perch_operator.coordinator.node import LATCHED_LAST
from perch_operator.outputs.mission_data import mission_id_text, waypoint_dict, write_waypoints_yaml

WAYPOINT_SET_TOPIC = "perch/mission_waypoints"
ATTRIBUTE_WITHIN = 5.0   # s for discovery to list a set's writers and the coordinator's goal status
PREFIX = 12              # bytes of an endpoint GID naming its DDS participant (its process)


class Dispatcher(Node):
    """Keeps the latest waypoint set: `mission` (hex goal id) and `received` (waypoint dicts)."""

    def __init__(self, output: Path | None = None, name: str = "perch_dispatcher", context=None):
        super().__init__(name, context=context)
        from action_msgs.msg import GoalStatusArray
        from rclpy.qos import qos_profile_action_status_default

        self.output = output
        self.mission = ""
        self.received: list[dict] = []
        self.refused: list[str] = []              # why each refused set was refused
        self._pending: list[tuple[float, PerchWaypointSet]] = []
        self._goals: set[bytes] = set()            # missions the action's status has listed
        self.create_subscription(GoalStatusArray, MISSION_STATUS_TOPIC, self._on_status,
                                 qos_profile_action_status_default)
        self.create_subscription(PerchWaypointSet, WAYPOINT_SET_TOPIC, self._on_set, LATCHED_LAST)
        self.create_timer(0.2, self._settle)
        # Said at start, so that a dispatcher started before any mission is seen to be listening.
        self.get_logger().info(f"waiting for the accepted perches on {self.resolve_topic_name(WAYPOINT_SET_TOPIC)}"
                               + (f" (kept in {output})" if output is not None else "")
                               + ": the current mission's set arrives even if it ended before this start")

    def _on_status(self, msg) -> None:
        self._goals |= {bytes(s.goal_info.goal_id.uuid) for s in msg.status_list}

    def _on_set(self, msg: PerchWaypointSet) -> None:
        self._pending.append((time.monotonic(), msg))
        self._settle()

    def attribution(self, msg: PerchWaypointSet) -> tuple[bool, str]:
        """(decided, why not): (True, '') when the set comes from the coordinator that ran its mission
        (and, on a networked graph, carries its valid token)."""
        from perch_common.network_auth import refusal_if_networked, waypoint_set_fields

        forged = refusal_if_networked(getattr(msg, "auth", ""), "waypoints", *waypoint_set_fields(msg))
        if forged:
            return True, forged
        def named(infos) -> dict[bytes, str]:
            return {bytes(i.endpoint_gid)[:PREFIX]: f"{i.node_namespace.rstrip('/')}/{i.node_name}" for i in infos}

        servers = named(self.get_publishers_info_by_topic(self.resolve_topic_name(MISSION_STATUS_TOPIC)))
        writers = named(self.get_publishers_info_by_topic(self.resolve_topic_name(WAYPOINT_SET_TOPIC)))
        if len(servers) > 1:
            return True, f"more than one process serves the mission action ({', '.join(sorted(servers.values()))})"
        foreign = {k: v for k, v in writers.items() if k not in servers}
        if foreign:
            return bool(servers), (f"{', '.join(sorted(foreign.values()))} also writes on {WAYPOINT_SET_TOPIC} and is not "
                                   "the mission coordinator")
        if not servers or not writers:
            return False, "its writer or the mission coordinator is not listed in the graph"
        if bytes(msg.mission_id.uuid) not in self._goals:
            return False, f"the coordinator has not listed mission {mission_id_text(msg.mission_id)}"
        return True, ""

    def _settle(self) -> None:
        """Accept or refuse the sets received, in order, once each can be attributed (or timed out)."""
        while self._pending:
            received, msg = self._pending[0]
            decided, why = self.attribution(msg)
            if not decided and time.monotonic() - received < ATTRIBUTE_WITHIN:
                return
            self._pending.pop(0)
            if why:
                self.refused.append(why)
                self.get_logger().error(f"refused a waypoint set for mission {mission_id_text(msg.mission_id)}: "
                                        f"{why}; keeping the previous set")
            else:
                self._accept(msg)

    def _accept(self, msg: PerchWaypointSet) -> None:
        self.mission = mission_id_text(msg.mission_id)
        self.received = [waypoint_dict(w) for w in msg.waypoints]
        log = self.get_logger()
        log.info(f"mission {self.mission}: {len(self.received)} accepted perch(es)")
        for waypoint in self.received:
            x, y, z = waypoint["position"]
            log.info(f"  drone {waypoint['drone_index']}: perch at ({x:.2f}, {y:.2f}, {z:.2f}) in "
                     f"{waypoint['frame_id']} (proposal {waypoint['proposal_id']})")
        if self.output is not None:
            refused = replace_refusal(self.output)   # the file may have changed since the start
            if refused:
                log.error(f"--output {self.output}: not written: {refused}")
                return
            try:
                write_waypoints_yaml(self.output, self.received)
            except OSError as exc:   # e.g. the disk filled up since the start: said, and the dispatcher goes on
                log.error(f"could not write --output {self.output} ({exc.strerror or exc}); its previous "
                          "content is kept")


WAYPOINT_FILE_KEYS = {"frame_id", "units", "waypoints"}   # write_waypoints_yaml's layout ("coordinates" optional)
LARGEST_WAYPOINT_FILE = 1 << 20   # bytes: a larger file is not a waypoints file (and is not read whole)


def is_waypoints_file(path: Path) -> bool:
    """Whether `path` holds a waypoints file as write_waypoints_yaml writes it: a YAML mapping of exactly
    frame_id, units, optionally coordinates, and waypoints, a list of waypoint_dict mappings."""
    import yaml

    from perch_interfaces.msg import PerchWaypoint

    try:
        if path.stat().st_size > LARGEST_WAYPOINT_FILE:
            return False
        doc = yaml.safe_load(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, yaml.YAMLError):
        return False
    keys = set(waypoint_dict(PerchWaypoint()))
    return (isinstance(doc, dict) and WAYPOINT_FILE_KEYS <= set(doc) <= WAYPOINT_FILE_KEYS | {"coordinates"}
            and isinstance(doc["frame_id"], str) and isinstance(doc["units"], str)
            and isinstance(doc["waypoints"], list)
            and all(isinstance(w, dict) and set(w) == keys for w in doc["waypoints"]))


def replace_refusal(path: Path) -> str:
    """Why the dispatcher must not replace `path` ('' when it may: absent, or a writable waypoints file
    that is not a mission's output). What the user keeps there is never replaced."""
    import os

    from perch_common.outputs import MANIFEST_NAME, written_by_perch

    if path.is_symlink():
        return ("is a symbolic link (writing would replace the link with a file); give the file it points to, "
                "or a new path")
    if not path.exists():
        return ""
    if not os.access(path, os.W_OK) or not path.stat().st_mode & 0o222:
        return (f"is read-only, and perch dispatch never replaces a read-only file; give a new path, or make it "
                f"writable (chmod u+w {path}) if it may be replaced")
    if (path.parent / MANIFEST_NAME).is_file() and path.name in written_by_perch(path.parent):
        return ("is a mission's output (listed in its folder's " + MANIFEST_NAME + "); give the dispatcher a "
                "file of its own, e.g. a new path")
    if not is_waypoints_file(path):
        return ("exists and is not a waypoints file written by perch dispatch; it is never replaced: give a new "
                "path, or move the file away")
    return ""


def main(output: Path | None = None) -> int:
    """Run the dispatcher until Ctrl-C."""
    from perch_common import namespace
    from perch_common.launch import use_perch_dds
    from perch_common.outputs import check_writable_file
    from perch_common.ros.node_main import run_node

    if output is not None:   # checked now, not when the first waypoint set arrives
        check_writable_file(output, "--output", "waypoints.yaml")
        refused = replace_refusal(output)
        if refused:
            from perch_common.errors import PerchError

            raise PerchError(f"--output {output}: {refused}")
    use_perch_dds()   # host-only like the graph, unless PERCH_NETWORK=1

    # the graph's namespace (perch --namespace N dispatch) for the relative topic name
    return run_node(lambda: Dispatcher(output), ["dispatch", "--ros-args", *namespace.ros_arguments(namespace.current())],
                    threads=1)


if __name__ == "__main__":
    sys.exit(main())
