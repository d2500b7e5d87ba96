"""End to end across processes: missions on a generated scene through every stage node.

One graph (each node its own process) serves the whole module; tests run in file order and the
replay test reuses the first test's recording.
"""

from __future__ import annotations

import io
import re
import time

import numpy as np
import pytest
import yaml

from perch_common.ros.testing import poll_until as wait_for

pytestmark = pytest.mark.ros

CAMERAS = 3
WAITING = re.compile(r"waiting for decisions on proposal\(s\) \[([\d, ]+)\]")   # the coordinator's feedback
REVIEWING = re.compile(r"waiting for surface review (\d+) ")   # the coordinator's feedback
SCENE_SEED = 3


@pytest.fixture(scope="module")
def scene():
    from perch_common.scene_generator import generate_scene

    return generate_scene(SCENE_SEED, "room")


def make_goal(scene, auto_accept: bool = True, cameras: int = CAMERAS):
    from perch_operator.api.client import scene_goal

    return scene_goal(scene, cameras, auto_accept)




@pytest.fixture(scope="module")
def recorded(graph, scene, tmp_path_factory):
    """The first mission: auto-accept, recorded, with outputs written."""
    from perch_operator.cli.runner import run_recorded_mission, write_outputs

    out = tmp_path_factory.mktemp("mission")
    outputs = run_recorded_mission(graph.node, make_goal(scene), out, progress=False, timeout=300)
    assert outputs.result.success, outputs.result.message
    return write_outputs(outputs)


def test_auto_accept_mission_reaches_a_late_dispatcher(graph, recorded):
    from geometry_msgs.msg import PoseArray

    from perch_operator.cli.dispatcher import Dispatcher
    from perch_operator.cli.runner import spin_for
    from perch_operator.coordinator.node import LATCHED_LAST
    from perch_operator.outputs.runfile import metadata

    result = recorded.result
    assert len(result.placements) == CAMERAS and len(result.waypoints) == CAMERAS
    # waypoints.yaml went into the folder as the result came in, before the report was rendered.
    assert recorded.waypoints_at is not None and recorded.waypoints == recorded.out_dir / "waypoints.yaml"
    assert recorded.waypoints.stat().st_mtime <= recorded.report.stat().st_mtime
    assert len(yaml.safe_load(recorded.waypoints.read_text())["waypoints"]) == CAMERAS
    assert result.stage_names[:5] == ["clean", "crop", "segment", "filter", "optimise"]
    assert result.stage_names[-2:] == ["confirm", "total"] and all(s >= 0 for s in result.stage_seconds)
    assert 0 < result.coverage <= 1 and 0 < result.fitness <= 1
    # The recording holds the request and reply of every stage call the mission made (issue 22).
    assert metadata(recorded.mcap)["perch_mission"]["recording_missing"] == []
    # A dispatcher started after the mission still receives every waypoint (transient local).
    dispatcher = Dispatcher(name="late_dispatcher")
    poses: list[PoseArray] = []
    dispatcher.create_subscription(PoseArray, "/perch/waypoint_poses", poses.append, LATCHED_LAST)
    deadline = time.monotonic() + 60   # discovery of a new node on a loaded machine
    wanted = {w.proposal_id for w in result.waypoints}
    while time.monotonic() < deadline and not (wanted <= {w["proposal_id"] for w in dispatcher.received} and poses):
        spin_for(dispatcher, 0.1)
    got = {w["proposal_id"]: w for w in dispatcher.received}
    assert wanted <= set(got)
    for w in result.waypoints:
        p = w.pose.pose.position
        np.testing.assert_allclose(got[w.proposal_id]["position"], [p.x, p.y, p.z], atol=1e-6)
        # the approach point lies in front of the perch, 0.5 m along the perch normal
        assert np.linalg.norm(np.subtract(got[w.proposal_id]["approach"], [p.x, p.y, p.z])) == pytest.approx(0.5)
    assert poses and len(poses[-1].poses) == CAMERAS
    dispatcher.destroy_node()
    for name in ("run.mcap", "run.rrd", "report.html", "waypoints.yaml"):
        assert (recorded.out_dir / name).stat().st_size > 0, name


def test_late_dispatcher_gets_exactly_the_current_missions_waypoints(graph, scene):
    from perch_operator.api.client import run_mission
    from perch_operator.cli.dispatcher import Dispatcher
    from perch_operator.cli.runner import spin_for
    from perch_operator.outputs.mission_data import mission_id_text

    results = [run_mission(graph.node, make_goal(scene, cameras=cameras), timeout=300) for cameras in (2, 1)]
    assert all(r.success for r in results), [r.message for r in results]
    first, second = ({mission_id_text(w.mission_id) for w in r.waypoints} for r in results)
    assert len(first) == len(second) == 1 and first != second  # every waypoint names its own mission
    dispatcher = Dispatcher(name="late_dispatcher_after_two")
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline and not dispatcher.received:
        spin_for(dispatcher, 0.1)
    # Only the second mission's one perch: none of the first mission's two.
    assert dispatcher.mission == next(iter(second))
    assert [w["proposal_id"] for w in dispatcher.received] == [w.proposal_id for w in results[1].waypoints]
    assert {w["mission_id"] for w in dispatcher.received} == second
    dispatcher.destroy_node()


def test_a_lost_answer_to_the_goal_is_recovered_from_the_coordinators_status_list(graph, scene, monkeypatch):
    """The goal reaches the coordinator but its answer never reaches the client (as when a young
    server answers before matching the client's response reader): the client follows the goal by
    the status topic and still gets the mission's result."""
    from rclpy.action import ActionClient
    from rclpy.task import Future

    from perch_operator.api.client import run_mission

    original = ActionClient.send_goal_async

    def answer_lost(self, *args, **kwargs):
        original(self, *args, **kwargs)
        return Future()   # the answer to this request never arrives

    monkeypatch.setattr(ActionClient, "send_goal_async", answer_lost)
    started = time.monotonic()
    result = run_mission(graph.node, make_goal(scene), timeout=300, server_wait=20)
    assert result.success, result.message
    assert len(result.waypoints) == CAMERAS
    assert time.monotonic() - started < 20   # followed by its status, not waited out


def test_a_lost_result_is_asked_for_again(graph, scene, monkeypatch):
    """The mission ends but its result response never reaches the client (as when the server answers before
    matching the client's response reader): the status list says it ended, so the client asks again."""
    from rclpy.action import ActionClient
    from rclpy.task import Future

    from perch_operator.api.client import run_mission

    original = ActionClient._get_result_async
    asked: list[int] = []

    def first_answer_lost(self, goal_handle):
        asked.append(1)
        future = original(self, goal_handle)
        return Future() if len(asked) == 1 else future   # the first response never arrives

    monkeypatch.setattr(ActionClient, "_get_result_async", first_answer_lost)
    started = time.monotonic()
    result = run_mission(graph.node, make_goal(scene), timeout=300)
    assert result.success, result.message
    assert len(result.waypoints) == CAMERAS and len(asked) == 2
    assert time.monotonic() - started < 30   # asked again once the status said ended, not waited out


def test_a_goal_that_never_arrives_times_out_naming_the_cause(graph, scene, monkeypatch):
    from rclpy.action import ActionClient
    from rclpy.task import Future

    from perch_operator.api.client import run_mission

    monkeypatch.setattr(ActionClient, "send_goal_async", lambda self, *args, **kwargs: Future())   # never sent
    with pytest.raises(TimeoutError, match="did not answer the goal within 2 s"):
        run_mission(graph.node, make_goal(scene), timeout=300, server_wait=2)


def test_recording_holds_every_stage_call_and_replays_clean(graph, recorded):
    from perch_operator.cli.replay import replay
    from perch_operator.outputs.runfile import channel_counts, stage_calls

    calls = stage_calls(recorded.mcap)
    assert [c.stage for c in calls] == ["clean", "crop", "segment", "filter", "optimise"]
    assert all(c.request is not None and c.response is not None for c in calls)
    counts = channel_counts(recorded.mcap)
    assert counts["/perch/proposals"] == 2 * CAMERAS and counts["/perch/waypoints"] == CAMERAS
    # A standard MCAP ROS 2 reader decodes the topics from the file's own schemas.
    from mcap_ros2.reader import read_ros2_messages

    decoded = [m.ros_msg for m in read_ros2_messages(str(recorded.mcap), topics=["/perch/waypoints"])]
    assert sorted(m.proposal_id for m in decoded) == sorted(w.proposal_id for w in recorded.result.waypoints)
    out = io.StringIO()
    outcomes = replay(graph.node, recorded.mcap, check=True, out=out)
    assert all(o.ok for o in outcomes), out.getvalue()


def test_recording_decodes_with_rosbags_and_foxglove_and_keeps_rosbag2_metadata(graph, recorded):
    import yaml
    from mcap.reader import make_reader
    from rosbags.rosbag2.metadata import parse_qos

    from perch_common.bag_check import DecoderUnavailable, foxglove_counts, rosbags_counts
    from perch_operator.outputs.runfile import channel_counts, iter_messages

    counts = channel_counts(recorded.mcap)
    assert any(t.endswith("/_service_event") for t in counts) and "/perch/plan_perches/_action/feedback" in counts
    # Every message, service events and action feedback included, decodes from the file's own schemas.
    assert rosbags_counts(recorded.mcap) == {t: (n, n) for t, n in counts.items()}
    with open(recorded.mcap, "rb") as f:
        reader = make_reader(f)
        described = yaml.safe_load({r.name: r.metadata for r in reader.iter_metadata()}["rosbag2"]["serialized_metadata"])
        qos = {c.topic: parse_qos(c.metadata["offered_qos_profiles"]) for c in reader.get_summary().channels.values()}
    assert described["version"] == 9 and described["message_count"] == sum(counts.values())
    assert {t["topic_metadata"]["name"]: t["message_count"] for t in described["topics_with_message_count"]} == counts
    # `ros2 bag play` re-offers the waypoints transient local, as the operator publishes them.
    assert {q.durability.name for q in qos["/perch/waypoints"]} == {"TRANSIENT_LOCAL"}
    # What a viewer needs: the mission's picture, published once for the auto-accepted set (not after
    # each of its 2 x CAMERAS events) with every perch accepted; the waypoint set emptied when the
    # mission starts, then its accepted set; and the camera frames.
    assert counts["/perch/markers"] == 1 and counts["/perch/mission_waypoints"] == 2
    [picture] = [m for _, m, _ in iter_messages(recorded.mcap, ["/perch/markers"])]
    perches = [m for m in picture.markers if m.ns == "perch_proposals"]
    assert len(perches) == CAMERAS and all(m.color.g > 0.5 > m.color.r for m in perches)   # accepted: green
    waypoint_sets = [m for _, m, _ in iter_messages(recorded.mcap, ["/perch/mission_waypoints"])]
    assert [len(m.waypoints) for m in waypoint_sets] == [0, CAMERAS]
    # one simulated view (Image + CameraInfo) per proposal: the auto-accepted mission made CAMERAS of them
    assert counts["/perch/views/image"] == counts["/perch/views/camera_info"] == CAMERAS
    [view] = [m for _, m, _ in iter_messages(recorded.mcap, ["/perch/views/image"])][:1]
    assert view.encoding == "rgb8" and view.width > 0 and len(view.data) == view.height * view.step
    assert np.frombuffer(bytes(view.data), np.uint8).std() > 0  # a picture, not a blank
    frames = {tf.child_frame_id for _, msg, _ in iter_messages(recorded.mcap, ["/tf_static"]) for tf in msg.transforms}
    assert {f"perch_drone_{i}_camera_optical" for i in range(CAMERAS)} <= frames
    try:
        decoded = foxglove_counts(recorded.mcap)
    except DecoderUnavailable as exc:
        pytest.skip(f"Foxglove's decoders not run: {exc} (rosbags decoded every message)")
    assert decoded == {t: (n, n) for t, n in counts.items()}
    print("Foxglove decode of run.mcap:", {t: decoded[t] for t in sorted(decoded)})


def test_replay_check_fails_after_a_parameter_change(graph, recorded, restart_with):
    from perch_operator.cli.replay import replay

    with restart_with("perch_placement", {"seed": 12345}):
        out = io.StringIO()
        outcomes = replay(graph.node, recorded.mcap, check=True, stages=["optimise"], out=out)
    assert not outcomes[0].ok
    assert "placements" in out.getvalue() or "fitness" in out.getvalue()


class LiveMission:
    """A mission driven from the test: goal sent, proposals watched, decisions sent, all async."""

    def __init__(self, node, goal):
        from perch_interfaces.action import PlanPerches
        from perch_interfaces.msg import Proposal
        from perch_interfaces.srv import Confirm
        from perch_operator.coordinator.action_client import RegisteringActionClient
        from perch_operator.coordinator.node import LATCHED

        self.node = node
        self.proposals: dict[int, Proposal] = {}
        self.sub = node.create_subscription(Proposal, "/perch/proposals", self._on_proposal, LATCHED)
        # The goal is sent while a spinner thread spins the node: rclpy's own ActionClient can drop the
        # answer to it (rclpy#1123; a CI rehearsal: "Ignoring unexpected goal response", the goal accepted
        # and its mission waiting for decisions the test never sent, and the next four tests refused).
        self.client = RegisteringActionClient(node, PlanPerches, "/perch/plan_perches")
        self.confirm = node.create_client(Confirm, "/perch/confirm")
        self.goal = goal
        self.feedback: list = []

    def _on_proposal(self, msg) -> None:
        self.proposals[msg.id] = msg

    def start(self) -> None:
        sent = self.client.send_goal_async(self.goal, feedback_callback=lambda m: self.feedback.append(m.feedback))
        handle = wait_for(lambda: sent.result() if sent.done() else None, 30, "goal acceptance")
        assert handle.accepted
        self.result_future = handle.get_result_async()

    def mine(self, status=None) -> list:
        """This mission's proposals (latched ones of earlier missions may arrive at any time): from the
        first id the mission's feedback names as waiting for a decision."""
        named = [WAITING.search(f.message) for f in list(self.feedback)]
        first = next((min(int(i) for i in m.group(1).split(",")) for m in named if m), None)
        return [] if first is None else [p for i, p in sorted(self.proposals.items())
                                         if i >= first and (status is None or p.status == status)]

    def review_id(self) -> int | None:
        """The surface review this mission waits for, once its feedback names it."""
        named = [REVIEWING.search(f.message) for f in list(self.feedback)]
        return next((int(m.group(1)) for m in named if m), None)

    def decide(self, proposal_id: int, decision: int, reason: str = ""):
        from perch_interfaces.srv import Confirm

        future = self.confirm.call_async(Confirm.Request(proposal_id=proposal_id, decision=decision, reason=reason))
        return wait_for(lambda: future.result() if future.done() else None, 60, f"decision on {proposal_id}")

    def result(self, timeout: float = 300):
        return wait_for(lambda: self.result_future.result() if self.result_future.done() else None,
                        timeout, "the mission result").result

    def close(self) -> None:
        self.node.destroy_subscription(self.sub)
        self.node.destroy_client(self.confirm)
        self.client.destroy()


def _own_review(mission: LiveMission, reviews: list, timeout: float = 120):
    """The mission's surface review, heard on /perch/surface_review, by the id its feedback names (an
    earlier test's latched review may arrive at any time, before or after this one)."""
    review_id = wait_for(mission.review_id, timeout, "the mission's feedback naming its surface review")
    return wait_for(lambda: next((r for r in list(reviews) if r.review_id == review_id), None), 60,
                    f"surface review {review_id} on /perch/surface_review")


def _position(placement_msg) -> np.ndarray:
    p = placement_msg.drone_pose.position
    return np.array([p.x, p.y, p.z])


def test_accept_reject_and_failed_in_flight(graph, scene):
    from perch_interfaces.msg import Proposal
    from perch_interfaces.srv import Confirm

    mission = LiveMission(graph.node, make_goal(scene, auto_accept=False))
    with graph.spinner(graph.node):
        mission.start()
        pending = wait_for(lambda: (lambda p: p if len(p) == CAMERAS else None)(mission.mine(Proposal.STATUS_PENDING)),
                           300, f"{CAMERAS} pending proposals")
        keep, reject, last = pending
        assert mission.decide(keep.id, Confirm.Request.ACCEPT).success
        started = time.monotonic()
        reply = mission.decide(reject.id, Confirm.Request.REJECT, "too close to the lamp")
        replan_seconds = time.monotonic() - started
        assert reply.success, reply.message
        new = reply.replacement
        assert new.id > last.id and new.status == Proposal.STATUS_PENDING
        assert new.placement.drone_index == reject.placement.drone_index
        # The replacement keeps out of the exclusion zone around the rejected perch.
        assert np.linalg.norm(_position(new.placement) - _position(reject.placement)) >= 0.3
        # The reply can overtake the proposal update on the topic (two channels): wait for it.
        wait_for(lambda: mission.proposals[reject.id].status == Proposal.STATUS_REJECTED, 10, "the rejection")
        assert mission.proposals[reject.id].reason == "too close to the lamp"
        again = mission.decide(reject.id, Confirm.Request.ACCEPT)
        assert not again.success and "superseded" in again.message
        for p in (new, last):
            assert mission.decide(p.id, Confirm.Request.ACCEPT).success
        result = mission.result()
        assert result.success, result.message
        by_drone = {p.drone_index: p for p in result.placements}
        # The accepted perch is kept exactly; the rejected one is replaced.
        np.testing.assert_allclose(_position(by_drone[keep.placement.drone_index]), _position(keep.placement))
        np.testing.assert_allclose(_position(by_drone[reject.placement.drone_index]), _position(new.placement))
        assert {w.proposal_id for w in result.waypoints} == {keep.id, new.id, last.id}

        # After the mission: an accepted perch fails in flight and is re-planned, the others kept.
        failed = mission.decide(last.id, Confirm.Request.FAILED_IN_FLIGHT, "slipped off")
        assert failed.success and failed.replacement.id > new.id
        assert np.linalg.norm(_position(failed.replacement.placement) - _position(last.placement)) >= 0.3
        assert np.linalg.norm(_position(failed.replacement.placement) - _position(reject.placement)) >= 0.3
        assert mission.decide(failed.replacement.id, Confirm.Request.ACCEPT).success
        # Feedback crosses processes (its order and completeness are unit-tested in
        # src/perch_operator/test/test_mission.py). With two full test suites running at once, late
        # feedback messages were twice seen to go missing across processes (cause not found), so
        # only arrival is asserted here.
        wait_for(lambda: {"clean", "segment"} <= {f.stage for f in mission.feedback}, 10, "feedback naming stages")
    mission.close()
    print(f"re-plan after a rejection: {replan_seconds:.2f} s")


def test_surface_review_rejection_keeps_perches_off_the_rejected_surface(graph, scene):
    from perch_common.polygons import to_shapely
    from perch_common.ros.conversions import surface_from_msg
    from perch_interfaces.msg import SurfaceReview
    from perch_interfaces.srv import ReviewSurfaces
    from perch_operator.coordinator.node import LATCHED_LAST

    reviews: list = []
    sub = graph.node.create_subscription(SurfaceReview, "/perch/surface_review", reviews.append, LATCHED_LAST)
    goal = make_goal(scene)
    goal.review_surfaces = 4
    mission = LiveMission(graph.node, goal)
    with graph.spinner(graph.node):
        mission.start()
        review = _own_review(mission, reviews)
        surfaces = [surface_from_msg(s) for s in review.surfaces]
        assert len(surfaces) == 4 and surfaces[0].area >= surfaces[-1].area
        ceiling = max((s for s in surfaces if abs(s.frame.normal[2]) > 0.9), key=lambda s: s.frame.origin[2])
        client = graph.node.create_client(ReviewSurfaces, "/perch/review_surfaces")
        bad = client.call_async(ReviewSurfaces.Request(review_id=review.review_id, rejected_surface_ids=[999]))
        assert not wait_for(lambda: bad.result() if bad.done() else None, 30, "a bad review reply").success
        ok = client.call_async(ReviewSurfaces.Request(review_id=review.review_id, rejected_surface_ids=[ceiling.id],
                                                      reason="fragile ceiling tiles"))
        assert wait_for(lambda: ok.result() if ok.done() else None, 30, "the review reply").success
        result = mission.result()
    graph.node.destroy_subscription(sub)
    graph.node.destroy_client(client)
    mission.close()
    assert result.success, result.message
    assert "review" in result.stage_names and len(result.placements) == CAMERAS
    outline = to_shapely(ceiling.boundary)
    import shapely
    for placement in result.placements:
        p = _position(placement)
        on_plane = abs((p - ceiling.frame.origin) @ ceiling.frame.normal) < 0.05
        inside = outline.buffer(0.05).contains(shapely.Point(*ceiling.frame.to_plane(p[None])[0]))
        assert not (on_plane and inside), f"perch at {p.round(2)} lies on the rejected ceiling"


def test_surface_review_crop_keeps_perch_regions_inside_the_kept_part(graph, scene):
    """The operator crops the largest wall of the review to 60 % of its length (its box in the input
    frame, as the console and `perch operator review --crop` send it): the filter is given only that
    part, and every perch region it finds on that wall lies inside the box."""
    from rclpy.qos import qos_profile_services_default

    from perch_common.polygons import to_shapely
    from perch_common.ros.conversions import mesh_from_msg, pose_msg, surface_from_msg, vector_msg
    from perch_common.ros.static_transforms import TF_STATIC_QOS, matrix_from_transform
    from perch_interfaces.msg import OrientedBox, SurfaceReview
    from perch_interfaces.srv import Filter, ReviewSurfaces
    from perch_operator.coordinator.node import LATCHED_LAST
    from tf2_msgs.msg import TFMessage

    reviews: list = []
    replies: list = []
    frames: dict = {}
    subs = [graph.node.create_subscription(SurfaceReview, "/perch/surface_review", reviews.append, LATCHED_LAST),
            graph.node.create_subscription(Filter.Event, "/perch/filter/_service_event",
                                           lambda e: replies.extend(e.response), qos_profile_services_default),
            graph.node.create_subscription(TFMessage, "/tf_static", lambda m: frames.update(
                {t.child_frame_id: matrix_from_transform(t) for t in m.transforms}), TF_STATIC_QOS)]
    goal = make_goal(scene)
    goal.review_surfaces = 4
    mission = LiveMission(graph.node, goal)
    client = graph.node.create_client(ReviewSurfaces, "/perch/review_surfaces")

    with graph.spinner(graph.node):
        mission.start()
        review = _own_review(mission, reviews, 300)
        surfaces = [surface_from_msg(s) for s in review.surfaces]   # the input frame
        wall = max((s for s in surfaces if abs(s.frame.normal[2]) < 0.2), key=lambda s: s.area)
        outline = to_shapely(wall.boundary)
        u0, v0, u1, v1 = outline.bounds
        # the box: 60 % of the wall along u from its low end, all its height, 0.6 m across the wall
        pose = np.eye(4)
        pose[:3, :3] = np.column_stack([wall.frame.axis_u, wall.frame.axis_v, wall.frame.normal])
        pose[:3, 3] = wall.frame.to_world(np.array([[u0 + 0.3 * (u1 - u0), (v0 + v1) / 2]]))[0]
        size = np.array([0.6 * (u1 - u0), (v1 - v0) + 0.2, 0.6])
        missing = client.call_async(ReviewSurfaces.Request(review_id=review.review_id,
                                                           cropped_surface_ids=[wall.id]))
        refused = wait_for(lambda: missing.result() if missing.done() else None, 30, "a refused crop")
        assert not refused.success and "1 cropped surface id(s) but 0 crop box(es)" in refused.message
        ok = client.call_async(ReviewSurfaces.Request(
            review_id=review.review_id, cropped_surface_ids=[wall.id],
            crop_boxes=[OrientedBox(pose=pose_msg(pose), size=vector_msg(size))], reason="poster on the right"))
        reply = wait_for(lambda: ok.result() if ok.done() else None, 30, "the review reply")
        assert f"cropped [{wall.id}]" in reply.message, reply.message
        result = mission.result()
        filtered = wait_for(lambda: next((r for r in reversed(replies) if r.success), None), 30, "the filter reply")
        to_input, = wait_for(lambda: next(([m] for f, m in frames.items() if f.endswith("_gravity_aligned")), None),
                             30, "the input -> gravity-aligned transform")
    for sub in subs:
        graph.node.destroy_subscription(sub)
    graph.node.destroy_client(client)
    mission.close()
    assert result.success, result.message
    removal = next(r for r in filtered.removals if r.surface_id == wall.id)
    kept_area = outline.area * 0.6
    assert removal.area_total == pytest.approx(kept_area, rel=0.15), (removal.area_total, outline.area)
    regions = [r for r in filtered.regions if r.source_surface == wall.id]
    assert regions, "the kept part of the wall holds no perch region (the test needs one)"
    for region in regions:
        points = mesh_from_msg(region.mesh).vertices @ to_input[:3, :3].T + to_input[:3, 3]
        local = (points - pose[:3, 3]) @ pose[:3, :3]
        assert (np.abs(local) <= size / 2 + 0.03).all(), \
            f"region {region.id} reaches {np.abs(local).max(axis=0).round(2)} m from the box centre (half {size / 2})"


def test_killed_stage_ends_the_mission_with_its_name_and_the_next_one_succeeds(graph, scene, restart_with):
    from rclpy.qos import qos_profile_services_default

    from perch_interfaces.srv import Optimise
    from perch_operator.api.client import run_mission

    # A deliberately long search, so that the stage dies in the middle of its call.
    slow = {"pso.particles": 400, "pso.iterations": 400, "pso.tolerance": 0.0, "pso.patience": 1000}
    with restart_with("perch_placement", slow) as changed:
        received = []
        events = graph.node.create_subscription(Optimise.Event, "/perch/optimise/_service_event",
                                                received.append, qos_profile_services_default)
        mission = LiveMission(graph.node, make_goal(scene))
        with graph.spinner(graph.node):
            # Both writers of the node's events: its service's and its action's (the goal's events).
            wait_for(lambda: events.get_publisher_count() >= 2, 30, "the optimise event writers")
            mission.start()
            # Inside the call: its request event, or progress the stage reported (the mission's feedback).
            # In one CI rehearsal the event went unheard for 300 s: this subscription had matched the
            # service's writer (it waited for one writer), and the action's matched after the request.
            wait_for(lambda: any(e.info.event_type == 1 for e in received)
                     or any(f.stage == "optimise" and f.stage_fraction > 0 for f in list(mission.feedback)),
                     300, "the optimise call under way")
            time.sleep(0.5)
            changed.processes["perch_placement"].kill()   # SIGKILL: no goodbye to the graph
            started = time.monotonic()
            result = mission.result(timeout=120)
            detected = time.monotonic() - started
        mission.close()
        graph.node.destroy_subscription(events)
    assert not result.success
    assert result.message.startswith("stage optimise (/perch/optimise):"), result.message
    assert "disappeared during the call" in result.message
    assert result.stage_names == ["clean", "crop", "segment", "filter"]
    assert detected < 30
    # restart_with has brought the normal placement node back: the next mission succeeds.
    again = run_mission(graph.node, make_goal(scene), timeout=300)
    assert again.success, again.message
    print(f"killed stage reported {detected:.1f} s after the kill")


def test_killing_the_node_holding_a_cached_mesh_mid_mission_is_recovered_by_resending(graph, scene):
    """The filter node holds the cropped mesh from an earlier mission; it is killed and restarted
    while the mission waits for a surface review. Its first request then names the mesh by id
    only, it answers "mesh not cached", and the coordinator sends the arrays again: success."""
    from rclpy.qos import qos_profile_services_default

    from perch_common.mesh_cache import MESH_NOT_CACHED
    from perch_common.ros.servers import server_endpoints
    from perch_interfaces.msg import SurfaceReview
    from perch_interfaces.srv import Filter, ReviewSurfaces
    from perch_operator.api.client import run_mission
    from perch_operator.coordinator.node import LATCHED_LAST

    warm = run_mission(graph.node, make_goal(scene), timeout=300)   # every stage now holds the meshes
    assert warm.success, warm.message
    calls: list = []   # (the calling client's GID, the event's response if any) of every filter event
    events = graph.node.create_subscription(Filter.Event, "/perch/filter/_service_event",
                                            lambda e: calls.append((bytes(e.info.client_gid), list(e.response))),
                                            qos_profile_services_default)
    reviews: list = []
    sub = graph.node.create_subscription(SurfaceReview, "/perch/surface_review", reviews.append, LATCHED_LAST)
    goal = make_goal(scene)
    goal.review_surfaces = 2
    mission = LiveMission(graph.node, goal)
    client = graph.node.create_client(ReviewSurfaces, "/perch/review_surfaces")
    with graph.spinner(graph.node):
        mission.start()
        review = _own_review(mission, reviews)
        killed = set(server_endpoints(graph.node, "/perch/filter"))
        assert killed, "the filter's server is not in the graph before the kill"
        graph.processes.processes["perch_filtering"].kill()        # SIGKILL: its mesh cache is gone
        graph.processes.processes["perch_filtering"].wait()
        log = graph.tmp / "logs" / "perch_filtering.log"
        ready_before = log.read_text(errors="replace").count("ready")
        graph.processes.start_node("perch_filtering")
        wait_for(lambda: log.read_text(errors="replace").count("ready") > ready_before, 120,
                 "the restarted filter node")
        # The killed process's server leaves the graph at its lease's end (3 s), the restarted one's arrives.
        wait_for(lambda: (now := set(server_endpoints(graph.node, "/perch/filter"))) and not now & killed, 60,
                 "the killed filter's server leaving the graph and the restarted one's arriving")
        # The restarted node's events reach this test once its event publisher has matched the subscription:
        # probe it (an empty request, answered with an error) until one of its events is heard.
        probe, sent = graph.node.create_client(Filter, "/perch/filter"), [0.0]

        def heard() -> bool:
            if calls:
                return True
            if time.monotonic() - sent[0] > 1.0:   # resent: discovery may still drop a first request
                probe.call_async(Filter.Request())
                sent[0] = time.monotonic()
            return False

        wait_for(heard, 60, "an event of the restarted filter node")
        # The probe's events come from the service's writer; the mission's goal's from the action's own.
        wait_for(lambda: events.get_publisher_count() >= 2, 60, "the restarted filter's action event writer")
        probes = {gid for gid, _ in calls}   # only the probe has called the new node so far

        def mission_replies() -> list:
            return [r for gid, responses in list(calls) if gid not in probes for r in responses]

        ok = client.call_async(ReviewSurfaces.Request(review_id=review.review_id))
        assert wait_for(lambda: ok.result() if ok.done() else None, 30, "the review reply").success
        result = mission.result()
        wait_for(lambda: any(r.success for r in mission_replies()), 10, "the filter's successful reply event")
    graph.node.destroy_subscription(events)
    graph.node.destroy_subscription(sub)
    graph.node.destroy_client(client)
    graph.node.destroy_client(probe)
    mission.close()
    assert result.success, result.message
    replies = mission_replies()
    misses = [r for r in replies if not r.success]
    assert misses and all(r.message.startswith(MESH_NOT_CACHED) for r in misses), [r.message for r in replies]
    assert "send the mesh arrays again" in misses[0].message
    assert replies[-1].success
    assert [p.drone_index for p in result.placements] == [p.drone_index for p in warm.placements]
    np.testing.assert_allclose([_position(p) for p in result.placements], [_position(p) for p in warm.placements],
                               atol=1e-6)
