"""ServerWatch: when a stage call's servers are gone, and when a lost request may be sent again
(no graph: a stand-in node's listings and a stepped clock)."""

from __future__ import annotations

from types import SimpleNamespace

import pytest

from perch_operator.coordinator import stages
from perch_operator.coordinator.stages import ServerWatch

SERVICE = "/perch/segment/_action/send_goal"
GRACE = 2.0


class ListingNode:
    """The request readers the graph lists for the service (an endpoint's node is its GID's first word)."""

    def __init__(self, *readers: bytes):
        self.readers = list(readers)

    def get_subscriptions_info_by_topic(self, topic: str, no_mangle: bool = False):
        assert topic == f"rq{SERVICE}Request" and no_mangle
        return [SimpleNamespace(endpoint_gid=gid, node_name=gid.decode().split()[0], node_namespace="/")
                for gid in self.readers]


@pytest.fixture
def clock(monkeypatch):
    now = SimpleNamespace(t=1000.0)
    monkeypatch.setattr(stages.time, "monotonic", lambda: now.t)
    return now


def _after(clock, seconds: float) -> None:
    clock.t += seconds


def test_a_server_listed_late_is_the_calls_own_however_late(clock):
    node = ListingNode()   # matched (wait_for_server) but not yet listed as the call goes out
    watch = ServerWatch(node, SERVICE, GRACE)
    _after(clock, 5.0)
    assert not watch.unchanged() and not watch.gone()   # nothing listed: a resend would reach nobody
    node.readers = [b"segmentation reader"]
    _after(clock, 0.5)
    assert watch.unchanged()   # the lost request may be sent again to it
    node.readers = []
    _after(clock, 0.5)
    assert not watch.gone()
    _after(clock, GRACE + 0.5)
    assert watch.gone()


def test_a_server_that_left_does_not_keep_a_lost_request_from_being_sent_again(clock):
    node = ListingNode(b"old_segmentation reader", b"segmentation reader")   # a dead node's endpoint lingers
    watch = ServerWatch(node, SERVICE, GRACE)
    node.readers = [b"segmentation reader"]   # its lease runs out
    _after(clock, 0.5)
    assert watch.unchanged() and not watch.gone()


def test_a_new_server_is_never_sent_a_call_its_predecessor_took(clock):
    node = ListingNode(b"segmentation reader")
    watch = ServerWatch(node, SERVICE, GRACE)
    node.readers = [b"segmentation reader", b"respawned_segmentation reader"]
    _after(clock, 0.5)
    assert not watch.unchanged() and not watch.gone()
    node.readers = [b"respawned_segmentation reader"]   # the call's own server died: the call fails
    _after(clock, 0.5)
    assert not watch.unchanged() and not watch.gone()
    _after(clock, GRACE + 0.5)
    assert watch.gone() and "respawned_segmentation" in watch.describe()
