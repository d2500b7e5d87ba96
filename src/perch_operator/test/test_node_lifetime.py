"""A destroyed perch_operator node leaves nothing in the graph (its module runs no other coordinator)."""

import time

import pytest

pytestmark = pytest.mark.ros

ACTION = "/perch/plan_perches/_action"


def test_a_destroyed_coordinator_leaves_no_action_server_in_the_graph(ros_node):
    """rclpy's destroy_node leaves action servers alive; a dead coordinator's server in a process that
    goes on (after a one-process graph stopped) took goals meant for the graph's live one."""
    from perch_operator.coordinator.node import OperatorNode

    def status_publishers() -> list[str]:
        return [i.node_name for i in ros_node.get_publishers_info_by_topic(f"{ACTION}/status")]

    def goal_services() -> int:
        return sum(1 for name, _ in ros_node.get_service_names_and_types() if name == f"{ACTION}/send_goal")

    def wait(done) -> None:
        deadline = time.monotonic() + 5
        while not done() and time.monotonic() < deadline:
            time.sleep(0.05)

    coordinator = OperatorNode()
    wait(lambda: status_publishers() and goal_services())
    assert status_publishers() == ["perch_operator"] and goal_services() == 1
    coordinator.destroy_node()
    wait(lambda: not status_publishers() and not goal_services())
    assert status_publishers() == [] and goal_services() == 0
