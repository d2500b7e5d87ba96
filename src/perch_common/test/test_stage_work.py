"""StageWork: a cancel stops the call it names (also one that has not started yet) and nothing else."""

from __future__ import annotations

from types import SimpleNamespace

import pytest

from perch_common.cancellation import Cancelled, checkpoint

pytestmark = pytest.mark.ros


@pytest.fixture
def work():
    import rclpy

    from perch_common.ros.service import StageWork
    from perch_common.ros.testing import use_isolated_ros_env

    use_isolated_ros_env()
    context = rclpy.Context()
    rclpy.init(context=context)
    node = rclpy.create_node("stage_work_test", context=context, start_parameter_services=False)
    try:
        yield StageWork.of(node)
    finally:
        node.destroy_node()
        rclpy.shutdown(context=context)


def served(work, service: str):
    """A served callback that reaches one checkpoint and answers 'done'."""
    def callback(request, response):
        checkpoint("the work")
        return "done"

    return work.serve(service, callback)


def test_a_cancel_before_the_call_starts_stops_only_that_call(work):
    segment = served(work, "perch/segment")
    assert work.cancel("perch/segment", "mission_a/segment/1") == 0   # not started: remembered
    with pytest.raises(Cancelled, match="perch/segment: cancelled by its caller"):
        segment(SimpleNamespace(request_id="mission_a/segment/1"), None)
    assert segment(SimpleNamespace(request_id="mission_b/segment/1"), None) == "done"
    assert segment(SimpleNamespace(request_id="mission_a/segment/1"), None) == "done"   # used up


def test_a_cancel_for_a_service_the_node_does_not_serve_is_not_its_own(work):
    segment = served(work, "perch/segment")
    assert work.cancel("perch/filter", "mission_a/filter/1") is None   # neither stopped nor remembered
    assert segment(SimpleNamespace(request_id="mission_a/segment/2"), None) == "done"


def test_a_request_without_an_id_is_cancelled_only_by_an_empty_id(work):
    import threading

    started, release = threading.Event(), threading.Event()

    def slow(request, response):
        started.set()
        release.wait(10)
        checkpoint("the work")
        return "done"

    run = work.serve("perch/segment", slow)
    outcome = {}
    thread = threading.Thread(target=lambda: outcome.setdefault("r", _catch(run, SimpleNamespace(request_id=""))))
    thread.start()
    assert started.wait(10)
    assert work.cancel("perch/segment", "someone_else/segment/1") == 0
    assert work.cancel("perch/segment", "") == 1
    release.set()
    thread.join(10)
    assert isinstance(outcome["r"], Cancelled)


def _catch(run, request):
    try:
        return run(request, None)
    except Cancelled as exc:
        return exc


def test_a_resent_call_runs_only_when_the_first_never_arrived(work):
    from perch_common.ros.service import STARTED_PHASE, is_duplicate_reply, resent_id

    runs, announced = [], []
    work._publish_progress = lambda service, request_id, fraction, phase: announced.append((request_id, phase))

    def callback(request, response):
        runs.append(request.request_id)
        response.success, response.message = True, "done"
        return response

    segment = work.serve("perch/segment", callback)

    def reply(request_id):
        return segment(SimpleNamespace(request_id=request_id), SimpleNamespace(success=False, message=""))

    # The first arrived: its resends are answered as duplicates and do not run.
    assert reply("caller/segment/1").message == "done"
    duplicate = reply(resent_id("caller/segment/1", 1))
    assert is_duplicate_reply(duplicate) and "caller/segment/1" in duplicate.message
    assert is_duplicate_reply(reply(resent_id("caller/segment/1", 2)))
    # The first was lost: its first resend runs, the next is a duplicate of it.
    assert reply(resent_id("caller/segment/2", 1)).message == "done"
    assert is_duplicate_reply(reply(resent_id("caller/segment/2", 2)))
    # A first id is never refused (a caller that sends one id twice gets two runs).
    assert reply("caller/segment/1").message == "done"
    assert runs == ["caller/segment/1", resent_id("caller/segment/2", 1), "caller/segment/1"]
    # Each call that ran announced itself as it started (the caller's sign that its request arrived).
    assert [r for r, phase in announced if phase == STARTED_PHASE] == runs


def test_a_cancel_of_a_call_stops_its_resend(work):
    from perch_common.ros.service import resent_id

    segment = served(work, "perch/segment")
    assert work.cancel("perch/segment", "caller/segment/3") == 0   # before either arrived
    with pytest.raises(Cancelled):
        segment(SimpleNamespace(request_id=resent_id("caller/segment/3", 1)), None)
