"""Proposal book: decisions, exclusion zones, which placements stay fixed, approach points."""

import threading

import numpy as np
import pytest

from perch_common.types import CameraPlacement
from perch_operator.coordinator.proposals import Decision, ProposalBook, ProposalError, Status, approach_point


def placement(x: float, slot: int = 0) -> CameraPlacement:
    pose = np.eye(4)
    pose[:3, :3] = [[0, 0, 1], [0, 1, 0], [-1, 0, 0]]  # a wall perch: drone z (the normal) is world +x
    pose[:3, 3] = [x, 0.0, 1.5]
    return CameraPlacement(drone_index=slot, region_id=slot, drone_pose=pose, camera_pose=pose, pan=0, tilt=0)


def test_accept_all_settles_without_exclusions():
    book = ProposalBook(first_id=10)
    ids = [book.propose(s, placement(s, s)).id for s in range(3)]
    assert ids == [10, 11, 12]
    assert book.open_slots() == [0, 1, 2]
    for i in ids:
        book.decide(i, Decision.ACCEPT)
    assert book.settled()
    assert book.exclusions() == []
    assert [p.status for p in book.accepted()] == [Status.ACCEPTED] * 3


def test_reject_adds_zone_at_perch_and_keeps_other_slots_fixed():
    book = ProposalBook(exclusion_radius=0.3)
    a, b, c = (book.propose(s, placement(float(s), s)) for s in range(3))
    book.decide(a.id, Decision.ACCEPT)
    rejected = book.decide(b.id, Decision.REJECT, "too close to the lamp")
    assert rejected.status == Status.REJECTED and rejected.reason == "too close to the lamp"
    [zone] = book.exclusions()
    np.testing.assert_allclose(zone.center, [1.0, 0.0, 1.5])
    assert zone.radius == 0.3
    fixed = book.fixed_for(b.slot)
    assert [p.region_id for p in fixed] == [0, 2]  # the accepted one and the still-pending one
    assert book.open_slots() == [1, 2]
    replacement = book.propose(b.slot, placement(2.0, 1))
    assert replacement.id == c.id + 1
    with pytest.raises(ProposalError, match="superseded"):
        book.decide(b.id, Decision.ACCEPT)
    book.decide(replacement.id, Decision.ACCEPT)
    book.decide(c.id, Decision.ACCEPT)
    assert book.settled()


def test_failed_in_flight_only_for_accepted_and_reopens_slot():
    book = ProposalBook()
    p = book.propose(0, placement(0.5))
    with pytest.raises(ProposalError, match="only an accepted perch can fail"):
        book.decide(p.id, Decision.FAILED_IN_FLIGHT)
    book.decide(p.id, Decision.ACCEPT)
    with pytest.raises(ProposalError, match="already accepted"):
        book.decide(p.id, Decision.REJECT)
    book.decide(p.id, Decision.FAILED_IN_FLIGHT, "landing gear slipped")
    assert book.open_slots() == [0]
    assert len(book.exclusions()) == 1


def test_unknown_id_and_empty_slot():
    book = ProposalBook()
    with pytest.raises(ProposalError, match="unknown proposal 7"):
        book.decide(7, Decision.ACCEPT)
    p = book.propose(0, placement(0.0))
    book.decide(p.id, Decision.REJECT)
    book.leave_empty(0)
    assert book.settled() and book.current() == []
    with pytest.raises(ValueError, match="positive"):
        ProposalBook(exclusion_radius=0.0)


def test_wait_settled_wakes_on_decision_from_another_thread():
    book = ProposalBook()
    p = book.propose(0, placement(0.0))
    assert not book.wait_settled(0.05)
    threading.Timer(0.05, book.decide, args=(p.id, Decision.ACCEPT)).start()
    assert book.wait_settled(5.0)


def test_approach_point_is_in_front_of_the_perch_along_the_normal():
    p = placement(1.0)
    np.testing.assert_allclose(approach_point(p, 0.5), [1.5, 0.0, 1.5])


def test_surface_review_desk_decisions_and_errors():
    import threading

    from perch_operator.coordinator.review import ReviewDesk, ReviewError

    desk = ReviewDesk()
    review = desk.open([4, 7, 9])
    waiter: dict = {}
    thread = threading.Thread(target=lambda: waiter.setdefault("rejected", desk.wait(review, 5, lambda: False)))
    thread.start()
    with pytest.raises(ReviewError, match=r"surface\(s\) \[5\] are not part of review 1"):
        desk.decide(review, [5])
    assert desk.decide(review, [7]) == {7}
    thread.join(5)
    assert waiter["rejected"] == {7}
    with pytest.raises(ReviewError, match="already decided"):
        desk.decide(review, [])
    with pytest.raises(ReviewError, match="no surface review 99"):
        desk.decide(99, [])
    second = desk.open([1])
    with pytest.raises(TimeoutError, match="no decision on surface review 2 within 0.3 s"):
        desk.wait(second, 0.3, lambda: False)
