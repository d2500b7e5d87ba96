"""ClientPresence: the writer the coordinator takes as a goal's client is there exactly while the goal runs."""

from __future__ import annotations

import pytest

pytestmark = pytest.mark.ros


def test_one_writer_for_the_running_goal_and_none_after(ros_node):
    from perch_common.conventions import mission_client_topic
    from perch_operator.api.presence import ClientPresence

    first, second = bytes(range(16)), bytes(range(1, 17))
    topics = [ros_node.resolve_topic_name(mission_client_topic(goal)) for goal in (first, second)]

    def writers() -> list[int]:   # the node's own endpoints: listed at once, no discovery to wait for
        return [ros_node.count_publishers(topic) for topic in topics]

    presence = ClientPresence(ros_node)
    presence.withdraw()   # nothing announced: nothing to do
    assert writers() == [0, 0]
    presence.announce(list(first))   # a UUID message's list, as the clients pass it
    assert writers() == [1, 0]
    assert topics[0].endswith("/perch/plan_perches/_client/g" + first.hex())
    presence.announce(second)   # the next goal: the earlier goal's writer goes
    assert writers() == [0, 1]
    presence.withdraw()
    presence.withdraw()
    assert writers() == [0, 0]
