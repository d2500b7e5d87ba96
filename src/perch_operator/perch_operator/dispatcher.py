"""`perch dispatch`: a minimal drone dispatcher that receives the current mission's accepted perches.

It subscribes to perch/mission_waypoints (PerchWaypointSet) with the publisher's reliable,
transient-local QoS, so even when started after the mission it gets exactly the current mission's
accepted waypoints (never an older mission's); each new set replaces the previous one. It prints
them with the mission (goal) id and can keep a YAML file of them up to date. A real dispatcher
replaces the print with flight orders.
"""

from __future__ import annotations

import sys
from pathlib import Path

from rclpy.node import Node

from perch_interfaces.msg import PerchWaypointSet
from perch_operator.mission_data import mission_id_text, waypoint_dict, write_waypoints_yaml
from perch_operator.node import LATCHED_LAST


class Dispatcher(Node):
    """Keeps the latest waypoint set: `mission` (hex goal id) and `received` (waypoint dicts)."""

    def __init__(self, output: Path | None = None, name: str = "perch_dispatcher"):
        super().__init__(name)
        self.output = output
        self.mission = ""
        self.received: list[dict] = []
        self.create_subscription(PerchWaypointSet, "perch/mission_waypoints", self._on_set, LATCHED_LAST)

    def _on_set(self, msg: PerchWaypointSet) -> None:
        self.mission = mission_id_text(msg.mission_id)
        self.received = [waypoint_dict(w) for w in msg.waypoints]
        log = self.get_logger()
        log.info(f"mission {self.mission}: {len(self.received)} accepted perch(es)")
        for waypoint in self.received:
            x, y, z = waypoint["position"]
            log.info(f"  drone {waypoint['drone_index']}: perch at ({x:.2f}, {y:.2f}, {z:.2f}) in "
                     f"{waypoint['frame_id']} (proposal {waypoint['proposal_id']})")
        if self.output is not None:
            write_waypoints_yaml(self.output, self.received)


def main(output: Path | None = None) -> int:
    """Run the dispatcher until Ctrl-C."""
    from perch_common import namespace
    from perch_common.ros.node_main import run_node

    # the graph's namespace (perch --namespace N dispatch) for the relative topic name
    return run_node(lambda: Dispatcher(output), ["dispatch", "--ros-args", *namespace.ros_arguments(namespace.current())],
                    threads=1)


if __name__ == "__main__":
    sys.exit(main())
