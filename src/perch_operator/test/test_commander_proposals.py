"""PerchCommander keeps the running mission's proposals only (no graph: its subscription callback fed
directly). The proposals topic keeps the last 100 proposals of every mission for late joiners."""

from __future__ import annotations

import threading

from unique_identifier_msgs.msg import UUID

from perch_interfaces import msg as pm
from perch_operator.api.commander import PerchCommander


def commander(mission: bytes | None) -> PerchCommander:
    """A commander's proposal state alone (its node, clients and subscription are not needed here)."""
    perch = PerchCommander.__new__(PerchCommander)
    perch._lock = threading.Lock()
    perch._proposals = {}
    perch._mission_uuid = mission
    return perch


def proposal(number: int, mission: bytes) -> pm.Proposal:
    return pm.Proposal(id=number, mission_id=UUID(uuid=list(mission)), status=pm.Proposal.STATUS_PENDING)


def test_proposals_of_other_missions_are_not_this_missions():
    mine, earlier = bytes(range(16)), bytes(range(1, 17))
    perch = commander(mine)
    for message in (proposal(0, earlier), proposal(1, earlier), proposal(0, mine), proposal(2, mine)):
        perch._on_proposal(message)
    assert [(p.id, bytes(p.mission_id.uuid)) for p in perch.getProposals()] == [(0, mine), (2, mine)]


def test_before_any_mission_no_proposal_is_kept():
    perch = commander(None)
    perch._on_proposal(proposal(0, bytes(16)))   # an earlier mission's, latched, or one without an id
    assert perch.getProposals(pending_only=False) == []
