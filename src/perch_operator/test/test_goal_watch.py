"""The coordinator's watch on a mission's client (goal_watch.GoalWatch) on a scripted graph: the client
is a participant (GUID prefix) with a get_result request writer and a feedback reader; it is adopted
even when it is listed late, a plain feedback reader never keeps a mission alive, and the client is
gone `grace` s after its participant's endpoints left the listing (its lease ran out)."""

from __future__ import annotations

from types import SimpleNamespace

from perch_operator.coordinator.goal_watch import ADOPT_SECONDS, NEVER_LISTED, GoalWatch

FEEDBACK = "/perch/plan_perches/_action/feedback"
RESULT_REQUESTS = "rq/perch/plan_perches/_action/get_resultRequest"


def _gid(participant: int, entity: int) -> bytes:
    return bytes([participant] * 12) + entity.to_bytes(4, "big")


class _Graph:
    """A node's graph queries, answered from what the test lists; and the clock."""

    def __init__(self):
        self.now = 100.0
        self.feedback_readers: set[bytes] = set()
        self.result_writers: set[bytes] = set()

    def client(self, participant: int, present: bool = True) -> None:
        for endpoints, entity in ((self.feedback_readers, 4), (self.result_writers, 3)):
            (endpoints.add if present else endpoints.discard)(_gid(participant, entity))

    def resolve_topic_name(self, name: str) -> str:
        return "/" + name

    def get_subscriptions_info_by_topic(self, topic: str, no_mangle: bool = False):
        assert topic == FEEDBACK
        return [SimpleNamespace(endpoint_gid=list(g)) for g in self.feedback_readers]

    def get_publishers_info_by_topic(self, topic: str, no_mangle: bool = False):
        assert topic == RESULT_REQUESTS and no_mangle
        return [SimpleNamespace(endpoint_gid=list(g)) for g in self.result_writers]

    def watch(self, grace: float) -> GoalWatch:
        return GoalWatch(self, grace, clock=lambda: self.now)

    def run(self, watch: GoalWatch, seconds: float, step: float = 0.25) -> float | None:
        """Advance the clock; the time (from now) at which `gone()` first said True, else None."""
        start = self.now
        while self.now - start < seconds:
            self.now += step
            if watch.gone():
                return self.now - start
        return None


def test_the_client_is_gone_grace_seconds_after_its_participant_left():
    graph = _Graph()
    graph.client(1)
    watch = graph.watch(grace=2.0)
    assert graph.run(watch, 30.0) is None   # it stays: the mission goes on
    graph.client(1, present=False)          # its lease ran out: its endpoints left the listing
    gone_after = graph.run(watch, 10.0)
    assert gone_after is not None and 2.0 < gone_after <= 2.0 + 1.0   # grace + one check period (0.5 s) + a step
    assert "client left the graph" in watch.describe()


def test_a_client_listed_late_is_adopted_and_followed():
    graph = _Graph()
    watch = graph.watch(grace=2.0)
    assert graph.run(watch, ADOPT_SECONDS + 3.0) is None   # not listed yet (discovery across hosts): no verdict
    graph.client(1)
    assert graph.run(watch, 20.0) is None
    graph.client(1, present=False)
    assert graph.run(watch, 10.0) is not None


def test_a_plain_feedback_reader_does_not_keep_the_mission_alive():
    graph = _Graph()
    graph.client(1)
    graph.feedback_readers.add(_gid(9, 4))   # a recorder or `ros2 topic echo`: no result requests
    watch = graph.watch(grace=2.0)
    graph.run(watch, 3.0)
    graph.client(1, present=False)
    assert graph.run(watch, 10.0) is not None


def test_a_client_never_listed_ends_the_mission_after_the_discovery_allowance():
    graph = _Graph()
    watch = graph.watch(grace=2.0)
    gone_after = graph.run(watch, NEVER_LISTED + 10.0)
    assert gone_after is not None and NEVER_LISTED < gone_after <= NEVER_LISTED + 2.0 + 1.0
    assert "never appeared" in watch.describe()


def test_clients_appearing_after_the_adoption_window_are_not_the_goal_s_client():
    graph = _Graph()
    graph.client(1)
    watch = graph.watch(grace=2.0)
    graph.run(watch, ADOPT_SECONDS + 1.0)
    graph.client(2)                          # the next mission's client, waiting for the graph
    graph.client(1, present=False)
    assert graph.run(watch, 10.0) is not None


def test_grace_zero_never_ends_a_mission():
    graph = _Graph()
    graph.client(1)
    watch = graph.watch(grace=0.0)
    graph.client(1, present=False)
    assert graph.run(watch, 60.0) is None
