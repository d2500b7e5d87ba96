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
