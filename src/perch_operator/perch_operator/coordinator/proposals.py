"""The operator's book of proposals: one camera slot per drone, each holding its current proposal.

Pure Python: decisions (accept, reject, failed in flight) change statuses and add exclusion
zones; the coordinator asks which placements to keep fixed when it re-optimises one slot.
Thread-safe: the confirm service and the mission thread share it.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass
from enum import IntEnum

import numpy as np

from perch_common.types import CameraPlacement, ExclusionZone


class Status(IntEnum):
    """Same codes as perch_interfaces/msg/Proposal STATUS_*."""

    PENDING = 0
    ACCEPTED = 1
    REJECTED = 2
    FAILED = 3


class Decision(IntEnum):
    """Same codes as perch_interfaces/srv/Confirm."""

    ACCEPT = 0
    REJECT = 1
    FAILED_IN_FLIGHT = 2


@dataclass
class Proposal:
    """A proposed perch for one camera slot, and the operator's decision on it."""

    id: int
    slot: int                   # camera slot (drone index) this proposal fills
    placement: CameraPlacement
    status: Status = Status.PENDING
    reason: str = ""


class ProposalError(ValueError):
    """A decision that cannot be applied (unknown id, already decided, ...)."""


class ProposalBook:
    """Proposals of one mission; ids are unique across missions (pass `first_id`)."""

    def __init__(self, exclusion_radius: float = 0.3, first_id: int = 1):
        if exclusion_radius <= 0:
            raise ValueError(f"exclusion radius must be positive, got {exclusion_radius}")
        self.exclusion_radius = exclusion_radius
        self._next_id = first_id
        self._by_id: dict[int, Proposal] = {}
        self._current: dict[int, Proposal | None] = {}   # slot -> live proposal (None: no alternative)
        self._zones: list[ExclusionZone] = []
        self.changed = threading.Condition()

    @property
    def next_id(self) -> int:
        """The id the next proposal will get."""
        return self._next_id

    def propose(self, slot: int, placement: CameraPlacement) -> Proposal:
        """Record a new pending proposal for `slot`."""
        with self.changed:
            proposal = Proposal(self._next_id, slot, placement)
            self._next_id += 1
            self._by_id[proposal.id] = proposal
            self._current[slot] = proposal
            self.changed.notify_all()
            return proposal

    def leave_empty(self, slot: int) -> None:
        """No alternative was found for this slot: the mission goes on with fewer cameras."""
        with self.changed:
            self._current[slot] = None
            self.changed.notify_all()

    def get(self, proposal_id: int) -> Proposal:
        """The proposal with this id (ProposalError naming the known ids otherwise)."""
        if proposal_id not in self._by_id:
            known = sorted(self._by_id)
            raise ProposalError(f"unknown proposal {proposal_id} (known: {known[:10]}"
                                f"{' ...' if len(known) > 10 else ''})")
        return self._by_id[proposal_id]

    def decide(self, proposal_id: int, decision: Decision, reason: str = "") -> Proposal:
        """Apply a decision; rejections and in-flight failures add an exclusion zone around the perch.

        Returns the decided proposal. Its slot then needs a new proposal unless accepted.
        """
        with self.changed:
            proposal = self.get(proposal_id)
            decision = Decision(decision)
            if self._current.get(proposal.slot) is not proposal:
                raise ProposalError(f"proposal {proposal_id} was superseded; decide on the slot's current one")
            if decision == Decision.FAILED_IN_FLIGHT:
                if proposal.status != Status.ACCEPTED:
                    raise ProposalError(f"proposal {proposal_id} is {proposal.status.name.lower()}; only an "
                                        "accepted perch can fail in flight")
                proposal.status = Status.FAILED
            elif proposal.status != Status.PENDING:
                raise ProposalError(f"proposal {proposal_id} is already {proposal.status.name.lower()}")
            else:
                proposal.status = Status.ACCEPTED if decision == Decision.ACCEPT else Status.REJECTED
            proposal.reason = reason
            if proposal.status != Status.ACCEPTED:
                self._zones.append(ExclusionZone(perch_position(proposal.placement), self.exclusion_radius))
            self.changed.notify_all()
            return proposal

    def exclusions(self) -> list[ExclusionZone]:
        """The exclusion zones of every rejected or failed perch so far."""
        with self.changed:
            return list(self._zones)

    def fixed_for(self, slot: int) -> list[CameraPlacement]:
        """Placements to keep while re-optimising `slot`: every other slot's live proposal."""
        with self.changed:
            return [p.placement for s, p in sorted(self._current.items())
                    if s != slot and p is not None and p.status in (Status.PENDING, Status.ACCEPTED)]

    def current(self) -> list[Proposal]:
        """Live proposals in slot order (empty slots left out)."""
        with self.changed:
            return [p for _, p in sorted(self._current.items()) if p is not None]

    def accepted(self) -> list[Proposal]:
        """The current proposals that are accepted."""
        return [p for p in self.current() if p.status == Status.ACCEPTED]

    def open_slots(self) -> list[int]:
        """Slots whose live proposal is still pending or was rejected/failed and not yet replaced."""
        with self.changed:
            return [s for s, p in sorted(self._current.items()) if p is not None and p.status != Status.ACCEPTED]

    def settled(self) -> bool:
        """Whether every slot is decided (accepted or left empty)."""
        return not self.open_slots()

    def wait_settled(self, timeout: float) -> bool:
        """Wait until every slot is decided; False on timeout."""
        with self.changed:
            return self.changed.wait_for(self.settled, timeout)


def perch_position(placement: CameraPlacement) -> np.ndarray:
    """The drone's position of a placement."""
    return np.asarray(placement.drone_pose, np.float64)[:3, 3].copy()


def approach_point(placement: CameraPlacement, distance: float) -> np.ndarray:
    """The point `distance` in front of the perch along the surface normal (the drone's z axis)."""
    pose = np.asarray(placement.drone_pose, np.float64)
    return pose[:3, 3] + distance * pose[:3, 2]
