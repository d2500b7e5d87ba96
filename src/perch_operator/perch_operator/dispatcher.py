"""`perch dispatch`: a minimal drone dispatcher that receives the accepted perch waypoints.

It subscribes to /perch/waypoints with the publisher's reliable, transient-local QoS, so it gets
every waypoint even when started after the mission; it prints them and can keep a YAML file of
the latest waypoint per drone up to date. A real dispatcher replaces the print with flight orders.
"""

from __future__ import annotations

import sys
from pathlib import Path

from rclpy.node import Node

from perch_interfaces.msg import PerchWaypoint
from perch_operator.mission_data import waypoint_dict, write_waypoints_yaml
from perch_operator.node import LATCHED


class Dispatcher(Node):
    def __init__(self, output: Path | None = None, name: str = "perch_dispatcher"):
        super().__init__(name)
        self.output = output
        self.received: list[dict] = []
        self.create_subscription(PerchWaypoint, "perch/waypoints", self._on_waypoint, LATCHED)

    def _on_waypoint(self, msg: PerchWaypoint) -> None:
        waypoint = waypoint_dict(msg)
        self.received.append(waypoint)
        x, y, z = waypoint["position"]
        self.get_logger().info(f"drone {waypoint['drone_index']}: perch at ({x:.2f}, {y:.2f}, {z:.2f}) "
                               f"(proposal {waypoint['proposal_id']})")
        if self.output is not None:
            write_waypoints_yaml(self.output, self.received)


def main(output: Path | None = None) -> int:
    from perch_common.ros.node_main import run_node

    return run_node(lambda: Dispatcher(output), [], threads=1)


if __name__ == "__main__":
    sys.exit(main())
