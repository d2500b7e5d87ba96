"""GoalWatch: which endpoints tell that a mission's client is gone (no graph: a stand-in node's listings)."""

from __future__ import annotations

from types import SimpleNamespace

import pytest

from perch_common.conventions import (
    MISSION_FEEDBACK_TOPIC,
    MISSION_OBSERVER_TOPIC,
    MISSION_SEND_GOAL_SERVICE,
    mission_client_topic,
)
from perch_operator.coordinator import goal_watch
from perch_operator.coordinator.goal_watch import GoalWatch

GOAL = bytes(range(16))
GRACE = 5.0


class ListingNode:
    """What GoalWatch asks of a node: its topic names, the endpoints the graph lists on them (an
    endpoint's node is its GID's first word: b"console reader" is node /console's) and the service
    clients of a listed node (`action_clients`: the nodes with a client of the mission's send_goal)."""

    def __init__(self):
        self.readers: dict[str, list[bytes]] = {}
        self.writers: dict[str, list[bytes]] = {}
        self.action_clients = {"client", "plain_client", "console"}   # the console's PerchCommander has one too

    def resolve_topic_name(self, name: str) -> str:
        return "/" + name

    def get_subscriptions_info_by_topic(self, topic: str):
        return [_endpoint(gid) for gid in self.readers.get(topic, [])]

    def get_publishers_info_by_topic(self, topic: str):
        return [_endpoint(gid) for gid in self.writers.get(topic, [])]

    def get_client_names_and_types_by_node(self, name: str, namespace: str):
        listed = {gid.decode().split()[0] for gids in (*self.readers.values(), *self.writers.values()) for gid in gids}
        if namespace != "/" or name not in listed:
            raise RuntimeError(f"cannot get client names and types for nonexistent node: {name}")  # as rclpy
        return [("/" + MISSION_SEND_GOAL_SERVICE, ["perch_interfaces/action/PlanPerches_SendGoal"])] \
            if name in self.action_clients else [("/other/service", ["std_srvs/srv/Trigger"])]


def _endpoint(gid: bytes) -> SimpleNamespace:
    return SimpleNamespace(endpoint_gid=gid, node_name=gid.decode().split()[0], node_namespace="/")


class NamedLater(ListingNode):
    """Lists the console's reader as _NODE_NAME_UNKNOWN_ until `named` (discovered before its node names)."""

    named = False

    def get_subscriptions_info_by_topic(self, topic: str):
        out = super().get_subscriptions_info_by_topic(topic)
        for info in out:
            if info.node_name == "console" and not self.named:
                info.node_name = "_NODE_NAME_UNKNOWN_"
        return out


@pytest.fixture
def clock(monkeypatch):
    now = SimpleNamespace(t=1000.0)
    monkeypatch.setattr(goal_watch.time, "monotonic", lambda: now.t)
    return now


def _gone_after(watch: GoalWatch, clock, seconds: float) -> bool:
    """Whether the watch says gone after `seconds` more, looked at every CHECK_PERIOD as the mission does."""
    end = clock.t + seconds
    while clock.t < end:
        clock.t += goal_watch.CHECK_PERIOD
        if watch.gone():
            return True
    return False


FEEDBACK = "/" + MISSION_FEEDBACK_TOPIC
PRESENCE = "/" + mission_client_topic(GOAL)
OBSERVERS = "/" + MISSION_OBSERVER_TOPIC


def test_a_bystander_reader_does_not_keep_a_killed_clients_mission(clock):
    node = ListingNode()
    node.readers[FEEDBACK] = [b"console", b"client"]   # a console left open, and the goal's own client
    node.writers[PRESENCE] = [b"client presence"]
    watch = GoalWatch(node, GRACE, GOAL)
    assert not _gone_after(watch, clock, 10.0)
    node.readers[FEEDBACK] = [b"console"]   # the client killed: its endpoints leave, the console's stay
    node.writers[PRESENCE] = []
    assert not _gone_after(watch, clock, GRACE - 1.0)
    assert _gone_after(watch, clock, 2.0)
    assert "presence writer" in watch.describe()


def test_the_presence_writer_tells_even_when_discovered_after_the_readers(clock):
    node = ListingNode()
    node.readers[FEEDBACK] = [b"console"]
    watch = GoalWatch(node, GRACE, GOAL)
    clock.t += 1.0
    node.writers[PRESENCE] = [b"client presence"]
    assert not _gone_after(watch, clock, 30.0)   # the console's reader stays; the writer is there
    node.writers[PRESENCE] = []
    assert _gone_after(watch, clock, GRACE + 1.0)


def test_another_goals_presence_is_not_this_goals_client(clock):
    node = ListingNode()
    node.writers["/" + mission_client_topic(bytes(16))] = [b"someone else"]
    node.readers[FEEDBACK] = [b"client"]
    watch = GoalWatch(node, GRACE, GOAL)
    node.readers[FEEDBACK] = []
    assert _gone_after(watch, clock, GRACE + 1.0)   # judged by its feedback reader, as a plain ROS client


def test_a_plain_ros_client_is_judged_by_the_feedback_readers_of_the_goals_first_seconds(clock):
    node = ListingNode()
    node.readers[FEEDBACK] = [b"client"]
    watch = GoalWatch(node, GRACE, GOAL)
    assert not _gone_after(watch, clock, goal_watch.ADOPT_SECONDS + 1.0)
    node.readers[FEEDBACK] = [b"late reader"]   # a reader that came after the goal's first seconds
    assert not _gone_after(watch, clock, GRACE - 1.0)
    assert _gone_after(watch, clock, 2.0)
    assert "no feedback reader" in watch.describe()


def test_no_grace_never_ends_a_mission(clock):
    node = ListingNode()
    node.writers[PRESENCE] = [b"client presence"]
    watch = GoalWatch(node, 0.0, GOAL)
    node.writers[PRESENCE] = []
    assert not _gone_after(watch, clock, 60.0)


def test_a_perch_observer_does_not_keep_a_killed_plain_clients_mission(clock):
    node = ListingNode()
    # A console left open (a Perch observer) and a plain ROS client without a presence writer.
    node.readers[FEEDBACK] = [b"console reader", b"plain_client reader"]
    watch = GoalWatch(node, GRACE, GOAL)
    clock.t += 1.0
    node.writers[OBSERVERS] = [b"console observer"]   # discovered after the readers: still left out
    assert not _gone_after(watch, clock, 10.0)
    node.readers[FEEDBACK] = [b"console reader"]   # the plain client killed; the console stays
    assert not _gone_after(watch, clock, GRACE - 1.0)
    assert _gone_after(watch, clock, 2.0)
    assert "no feedback reader" in watch.describe()


def test_a_tool_that_only_reads_the_feedback_does_not_keep_a_killed_plain_clients_mission(clock):
    node = ListingNode()
    # Foxglove's bridge or `ros2 topic echo`: a feedback reader on a node with no send_goal client.
    node.readers[FEEDBACK] = [b"foxglove_bridge reader", b"plain_client reader"]
    watch = GoalWatch(node, GRACE, GOAL)
    assert not _gone_after(watch, clock, 10.0)
    node.readers[FEEDBACK] = [b"foxglove_bridge reader"]   # the plain client killed; the bridge stays
    assert not _gone_after(watch, clock, GRACE - 1.0)
    assert _gone_after(watch, clock, 2.0)


def test_another_action_client_of_the_mission_is_still_taken_for_a_plain_clients(clock):
    node = ListingNode()
    node.action_clients.add("dispatcher_b")   # a second dispatcher (not Perch's), idle, its client open
    node.readers[FEEDBACK] = [b"dispatcher_b reader", b"plain_client reader"]
    watch = GoalWatch(node, GRACE, GOAL)
    node.readers[FEEDBACK] = [b"dispatcher_b reader"]
    assert not _gone_after(watch, clock, 60.0)   # the documented limit: it may be the client


def test_a_killed_clients_node_still_counts_once_it_has_left_the_graph(clock):
    """The node's service clients cannot be listed once it has gone (rclpy raises): what was seen of it
    while it was there decides."""
    node = ListingNode()
    node.readers[FEEDBACK] = [b"echo reader", b"plain_client reader"]
    watch = GoalWatch(node, GRACE, GOAL)
    assert not _gone_after(watch, clock, 1.0)
    node.readers[FEEDBACK] = [b"echo reader"]   # /plain_client is no longer listed anywhere
    assert _gone_after(watch, clock, GRACE + 1.0)


def test_a_reader_of_a_node_not_yet_named_counts_as_the_client(clock):
    node = NamedLater()
    node.action_clients.discard("console")
    node.readers[FEEDBACK] = [b"console reader"]   # listed as _NODE_NAME_UNKNOWN_ while the goal starts
    watch = GoalWatch(node, GRACE, GOAL)
    node.readers[FEEDBACK] = []
    assert _gone_after(watch, clock, GRACE + 1.0)


def test_readers_of_observers_only_tell_nothing_of_a_plain_client(clock):
    """Every reader of the goal's first seconds on observer nodes: nothing tells who the client is, and
    the mission is never ended for it (as with no reader at all)."""
    node = ListingNode()
    node.readers[FEEDBACK] = [b"console reader"]
    node.writers[OBSERVERS] = [b"console observer"]
    watch = GoalWatch(node, GRACE, GOAL)
    node.readers[FEEDBACK] = []
    assert not _gone_after(watch, clock, 60.0)


def test_an_observers_reader_named_only_after_the_goals_first_seconds_is_still_left_out(clock):
    node = NamedLater()
    node.readers[FEEDBACK] = [b"console reader", b"plain_client reader"]
    node.writers[OBSERVERS] = [b"console observer"]
    watch = GoalWatch(node, GRACE, GOAL)
    assert not _gone_after(watch, clock, goal_watch.ADOPT_SECONDS + 1.0)
    node.named = True
    node.readers[FEEDBACK] = [b"console reader"]   # the plain client killed
    assert _gone_after(watch, clock, GRACE + 1.0)
