"""Client side of a mission: send a PlanPerches goal, show progress, wait for the result.

The client follows the coordinator that accepted its goal by identity (the endpoint GIDs of the
action's status publisher): when that coordinator dies or restarts (`perch launch` respawns it
within a second, with an empty goal list), its endpoints leave the graph (at once on a clean exit,
after the DDS lease of 3 s when killed) and the mission ends within seconds with that reason
instead of waiting out the client's time limit.
"""

from __future__ import annotations

import time
import uuid
from typing import Callable

import rclpy
from rclpy.action import ActionClient
from unique_identifier_msgs.msg import UUID

from perch_common.conventions import MISSION_ACTION, MISSION_STATUS_TOPIC
from perch_common.errors import PerchError
from perch_common.ros.spinning import destroyable_publisher
from perch_interfaces.action import PlanPerches
from perch_operator.api.presence import ClientPresence
from perch_operator.coordinator.action_client import RESULT_WAIT, TERMINAL

ACTION = MISSION_ACTION   # the name `perch operator` and the soak import
LOST_ANSWER_GRACE = 1.0   # s a listed goal waits for its answer before the answer counts as lost
GOAL_RESEND_AFTER = 3.0   # s without an answer or a status listing before a goal is sent again
SERVER_GONE_GRACE = 1.0   # s the accepting coordinator may be absent from the graph before the mission ends


class GoalRejected(PerchError):
    """The coordinator refused the goal (another mission is running); nothing was started."""


class NoCoordinator(GoalRejected):
    """No mission coordinator answered: the mission was never sent; nothing was started."""


class CoordinatorGone(PerchError):
    """The coordinator running the mission died or restarted; the mission is lost with it."""


CANCEL_WAIT = 5.0   # s for the coordinator to answer a cancel
CANCEL_RESEND = 1.0   # s between signed cancels until the coordinator lists the goal as cancelling (a fresh token each)


def _spin_until(node, future, deadline: float, what: str, gone: Callable[[], str] | None = None,
                give_up: Callable[[], bool] | None = None) -> bool:
    """Spin until `future` is done (True), or `give_up()` says so first (False). TimeoutError past the
    deadline; CoordinatorGone as soon as `gone()` names a reason."""
    while not future.done():
        if time.monotonic() > deadline:
            raise TimeoutError(f"{what} did not finish in time")
        reason = gone() if gone is not None else ""
        if reason:
            raise CoordinatorGone(reason)
        if give_up is not None and give_up():
            return False
        _spin_briefly(node, future)
    return True


def _spin_briefly(node, future=None) -> None:
    """Spin for up to 0.1 s (or until `future` is done). A SIGINT can land while rclpy turns a taken
    message (a feedback, a status) into Python: the KeyboardInterrupt then leaves rclpy's C++ as
    pybind11's TypeError "Unable to convert function return value" raised from it, or the context it
    shut down fails the next call. Either is the interrupt, and is raised as one."""
    try:
        if future is None:
            rclpy.spin_once(node, timeout_sec=0.1)
        else:
            rclpy.spin_until_future_complete(node, future, timeout_sec=0.1)
    except KeyboardInterrupt:
        raise
    except Exception as exc:
        if isinstance(exc.__cause__, KeyboardInterrupt) or not node.context.ok():
            raise KeyboardInterrupt from exc
        raise


class MissionCanceller:
    """The signed mission cancel of a networked graph (PERCH_NETWORK=1), whose coordinator refuses the
    action's standard cancel (it has no room for a token).

    It travels on the stage-cancel topic (perch_interfaces/StageCancel, signed and checked as for stage
    calls): `service` the mission action, `request_id` the mission's goal id (32 hex digits), `auth` an
    HMAC token over both and the reason. The coordinator takes it once (a replayed token is refused) and
    only for the mission it runs, and then lists the goal as cancelling. Make it with the action client,
    so that it has matched the coordinator by the time it is needed."""

    def __init__(self, node, callback_group=None):
        from perch_common.ros.service import CANCEL_TOPIC
        from perch_interfaces.msg import StageCancel

        self.node = node
        self._msg = StageCancel
        self.publisher = destroyable_publisher(node, StageCancel, CANCEL_TOPIC, 10, callback_group=callback_group)

    def send(self, goal_id: UUID, reason: str) -> None:
        """Publish one signed cancel of the mission `goal_id` (a new token each second)."""
        from perch_common.network_auth import sign_if_networked

        mission = bytes(bytearray(goal_id.uuid)).hex()
        self.publisher.publish(self._msg(service=MISSION_ACTION, request_id=mission, reason=reason,
                                         auth=sign_if_networked("stage_cancel", MISSION_ACTION, mission, reason)))

    def cancel(self, goal_id: UUID, reason: str, status: Callable[[], int], wait: float = CANCEL_WAIT,
               step: Callable[[], None] | None = None) -> bool:
        """Send the cancel (again every CANCEL_RESEND s, each with a fresh token, while unanswered) until
        `status()` (the goal's status as the coordinator lists it) is cancelling or ended; whether it was
        within `wait` s. `step` waits a moment (default: spin the node 0.1 s)."""
        from action_msgs.msg import GoalStatus

        running = (GoalStatus.STATUS_UNKNOWN, GoalStatus.STATUS_ACCEPTED, GoalStatus.STATUS_EXECUTING)
        deadline, sent = time.monotonic() + wait, None
        while status() in running:
            now = time.monotonic()
            if now > deadline:
                return False
            if sent is None or now - sent >= CANCEL_RESEND:
                self.send(goal_id, reason)
                sent = now
            (step or (lambda: rclpy.spin_once(self.node, timeout_sec=0.1)))()
        return True

    def destroy(self) -> None:
        """Stop publishing."""
        self.node.destroy_publisher(self.publisher)


def _cancel_or_say_why_not(node, handle, signed: MissionCanceller | None = None, reason: str = "",
                           ended: Callable[[], bool] = lambda: False) -> None:
    """Ask the coordinator to cancel the goal (signed when `signed` is given: a networked graph); when
    it refuses or does not answer, say so, and let the caller's own error (Ctrl-C, time limit) stand.
    `ended()`: the coordinator lists the goal as ended (a refusal then means there was nothing to cancel)."""
    if signed is not None:
        if not signed.cancel(handle.goal_id, reason, lambda: handle.status):
            node.get_logger().warning(
                f"the coordinator did not take the signed cancel within {CANCEL_WAIT:.0f} s (its log says why: "
                "another key, clocks further apart than the token window, or the link is down); the mission ends "
                "when it notices its client has left (parameter client_grace)")
        return
    cancel = handle.cancel_goal_async()
    try:
        _spin_until(node, cancel, time.monotonic() + CANCEL_WAIT, "cancelling the mission")
    except TimeoutError:
        node.get_logger().warning(f"the coordinator did not answer the cancel within {CANCEL_WAIT:.0f} s; "
                                  "the mission ends when it notices its client has left (parameter client_grace)")
        return
    if cancel.result().goals_canceling:
        return
    if ended():
        node.get_logger().info("the mission had already ended when the cancel arrived: nothing to cancel")
    else:
        node.get_logger().warning("the coordinator refused the cancel (a networked graph takes no unsigned cancel); "
                                  "the mission ends when it notices its client has left (parameter client_grace)")


def scene_goal(scene, cameras: int, auto_accept: bool = True, seed: int = -1, **fields) -> PlanPerches.Goal:
    """A mission goal on a generated scene (perch_common.scene_generator): its mesh and target volume,
    `cameras` perches; `fields` set other goal fields (up_axis=, review_surfaces=, ...)."""
    from perch_common.ros.conversions import mesh_to_msg, target_to_msg

    return PlanPerches.Goal(mesh=mesh_to_msg(scene.mesh), target=target_to_msg(scene.target),
                            num_cameras=max(0, cameras), auto_accept=auto_accept, seed=seed, **fields)


def run_mission(node, goal: PlanPerches.Goal, timeout: float = 600.0, server_wait: float = 30.0,
                on_feedback: Callable[[PlanPerches.Feedback], None] | None = None) -> PlanPerches.Result:
    """Run one mission on the live graph and return its result (success or not)."""
    from perch_common.network_auth import networked

    client = ActionClient(node, PlanPerches, ACTION)
    statuses = GoalStatusWatch(node)
    signed = MissionCanceller(node) if networked() else None   # a networked graph takes signed cancels only
    goal_id = UUID(uuid=list(uuid.uuid4().bytes))
    presence = ClientPresence(node)   # this goal's client, for the coordinator (GoalWatch)
    presence.announce(goal_id.uuid)
    try:
        server_wait = min(server_wait, timeout)
        if not client.wait_for_server(timeout_sec=server_wait):
            raise NoCoordinator(f"no mission coordinator: action {ACTION} did not appear within {server_wait:g} s; "
                                "start the graph with `perch launch` (`perch plan` without --no-launch starts "
                                "its own)")
        deadline = time.monotonic() + timeout
        def send():
            return client.send_goal_async(
                goal, feedback_callback=(lambda m: on_feedback(m.feedback)) if on_feedback else None, goal_uuid=goal_id)

        handle = _goal_handle(node, client, send, goal_id, statuses,
                              min(deadline, time.monotonic() + server_wait), server_wait)
        if not handle.accepted:
            raise GoalRejected("the coordinator rejected the goal: another mission is running (wait for it, "
                               "or cancel it with `perch operator cancel`); nothing was written")
        statuses.follow_server()
        try:
            result = _result_of(node, handle, statuses, deadline, f"the mission ({timeout:.0f} s limit)")
        except CoordinatorGone as exc:
            node.get_logger().error(str(exc))
            return PlanPerches.Result(success=False, message=str(exc))
        except (TimeoutError, KeyboardInterrupt) as exc:
            why = "interrupted (Ctrl-C)" if isinstance(exc, KeyboardInterrupt) else f"client time limit ({timeout:.0f} s)"
            _cancel_or_say_why_not(node, handle, signed, f"perch plan: {why}",
                                   lambda: statuses.status.get(bytes(handle.goal_id.uuid)) in TERMINAL)
            raise
        return result.result
    finally:
        presence.close()
        if signed is not None:
            signed.destroy()
        statuses.destroy()
        client.destroy()


class GoalStatusWatch:
    """The goals the coordinator's status topic lists (transient local: a late reader gets the last list)."""

    def __init__(self, node):
        from action_msgs.msg import GoalStatusArray
        from rclpy.qos import qos_profile_action_status_default

        self.node = node
        self.accepted: dict[bytes, object] = {}   # goal id -> the time the coordinator accepted it
        self.status: dict[bytes, int] = {}        # goal id -> its latest status (action_msgs/GoalStatus)
        self.topic = node.resolve_topic_name(MISSION_STATUS_TOPIC)
        self.servers: dict[bytes, str] = {}       # the accepting coordinator's status writer GIDs -> node
        self._current: dict[bytes, str] = {}
        self._absent_since: float | None = None
        self._checked = 0.0
        self._sub = node.create_subscription(GoalStatusArray, MISSION_STATUS_TOPIC, self._on_status,
                                             qos_profile_action_status_default)

    @staticmethod
    def writers_of(node) -> dict[bytes, str]:
        """The coordinators in the graph now: their status writers' GIDs -> node name."""
        return {bytes(i.endpoint_gid): f"{i.node_namespace.rstrip('/')}/{i.node_name}"
                for i in node.get_publishers_info_by_topic(node.resolve_topic_name(MISSION_STATUS_TOPIC))}

    def _writers(self) -> dict[bytes, str]:
        return self.writers_of(self.node)

    def follow_server(self) -> None:
        """Remember the coordinator(s) in the graph now, once the goal is accepted."""
        self.servers = self._writers()
        self._checked = time.monotonic()

    def server_gone(self) -> str:
        """Why the mission is lost ('' while the coordinator that accepted the goal is in the graph)."""
        now = time.monotonic()
        if now - self._checked < 0.25:
            return self._reason(now)
        self._checked = now
        current = self._writers()
        if not self.servers:
            self.servers = current   # accepted before its endpoints were listed here (discovery lag)
        if not self.servers or set(self.servers) & set(current):
            self._absent_since = None
        else:
            self._absent_since = self._absent_since or now
        self._current = current
        return self._reason(now)

    def _reason(self, now: float) -> str:
        if self._absent_since is None or now - self._absent_since <= SERVER_GONE_GRACE:
            return ""
        names = ", ".join(sorted(set(self.servers.values())))
        after = (f"; a new coordinator ({', '.join(sorted(set(self._current.values())))}) now serves, without "
                 "this mission" if self._current else "")
        return (f"the mission coordinator ({names}) died or restarted during the mission: its action server "
                f"left the graph{after}; run the mission again")

    def _on_status(self, msg) -> None:
        for status in msg.status_list:
            self.accepted.setdefault(bytes(status.goal_info.goal_id.uuid), status.goal_info.stamp)
            self.status[bytes(status.goal_info.goal_id.uuid)] = status.status

    def destroy(self) -> None:
        """Stop listening."""
        self.node.destroy_subscription(self._sub)


def _result_of(node, handle, statuses: GoalStatusWatch, deadline: float, what: str):
    """The accepted goal's result (its GetResult response). A result response can be lost as the goal's
    answer can (a server answering before it matched this client's response reader; a CI rehearsal's
    client waited out its 300 s for a mission that had ended in 1.4 s). The status list still says the
    goal ended: RESULT_WAIT s after that without the result, it is asked for again (the coordinator
    keeps a result for its action server's result timeout)."""
    key = bytes(handle.goal_id.uuid)
    ended_at: list[float] = []   # when the status list first said the goal ended, since the last ask

    def lost() -> bool:
        if statuses.status.get(key) not in TERMINAL:
            return False
        ended_at[:] = ended_at or [time.monotonic()]
        return time.monotonic() - ended_at[0] > RESULT_WAIT

    future = handle.get_result_async()
    while not _spin_until(node, future, deadline, what, statuses.server_gone, lost):
        node.get_logger().warning("the mission ended but its result was lost on the way; asking for it again")
        future, ended_at[:] = handle.get_result_async(), []
    return future.result()


def _goal_handle(node, client, send, goal_id, statuses: GoalStatusWatch, deadline: float, server_wait: float):
    """Send the goal (`send()`: its future); its handle from the coordinator's answer, or from its status
    list when the answer is lost.

    A service response is dropped when the server answers before it has matched this client's
    response reader (a young coordinator, or a young client on a busy machine). The goal is then
    running all the same, and the status topic lists it: the mission is followed from there.
    A request can be lost the same way (a young coordinator's reader drops what comes before it matched
    this client), so a goal neither answered nor listed after GOAL_RESEND_AFTER s is sent again under its
    own id (then after twice that, ...): the coordinator refuses a goal id it holds, so the mission runs once;
    such a refusal is only taken for the answer when the goal does not show up in the status list."""
    from rclpy.action.client import ClientGoalHandle

    key = bytes(goal_id.uuid)
    listed_at = refused_at = refusal = None
    sent, started, resends = [send()], time.monotonic(), 0
    resend_at = started + GOAL_RESEND_AFTER
    while True:
        for future in sent:
            if future.done() and future.result().accepted:
                return future.result()
        if len(sent) == 1 and sent[0].done():
            return sent[0].result()   # refused, and never sent twice: the refusal is the answer
        if refusal is None and any(f.done() for f in sent):
            refusal, refused_at = next(f.result() for f in sent if f.done()), time.monotonic()
        now = time.monotonic()
        if key in statuses.accepted:
            listed_at = listed_at or now
            if now - listed_at > LOST_ANSWER_GRACE:
                node.get_logger().warning("the coordinator's answer to the goal was lost on the way; "
                                          "following the goal by its status instead")
                answer = PlanPerches.Impl.SendGoalService.Response(accepted=True, stamp=statuses.accepted[key])
                return ClientGoalHandle(client, goal_id, answer)
        elif refused_at is not None and now - refused_at > LOST_ANSWER_GRACE + 1.0:
            return refusal   # refused, and not running (a goal it holds would be listed by now)
        if now > deadline:
            # The coordinator answers a goal at once (accepted or refused); no answer means it never got it.
            raise TimeoutError(f"the coordinator did not answer the goal within {server_wait:.0f} s (another "
                               "process on this ROS domain may serve the action without running it: "
                               "`ros2 action info` lists the servers, a restart of the graph clears it)")
        if now > resend_at and listed_at is None and refusal is None:
            resends += 1
            node.get_logger().warning(f"no answer to the goal for {now - started:.0f} s (the request may have "
                                      "been lost on the way); sending it again")
            sent.append(send())
            resend_at = now + GOAL_RESEND_AFTER * 2 ** resends
        pending = [f for f in sent if not f.done()]
        _spin_briefly(node, pending[0] if pending else None)


class ProgressPrinter:
    """Prints a line when the stage changes and a progress bar in place on a terminal."""

    def __init__(self, stream=None, tty: bool | None = None):
        import sys

        self.stream = stream or sys.stderr
        self.tty = self.stream.isatty() if tty is None else tty
        self.stage = None
        self.started = time.monotonic()

    def __call__(self, feedback: PlanPerches.Feedback) -> None:
        """Print one feedback message (a new line per stage, updated in place on a terminal)."""
        elapsed = time.monotonic() - self.started
        if feedback.stage != self.stage:
            self.stage = feedback.stage
            if self.tty:
                self.stream.write("\n")
            self.stream.write(f"[{elapsed:5.1f} s] {feedback.stage}: {feedback.message}\n" if not self.tty else "")
        if self.tty:
            bar = "#" * int(30 * feedback.fraction)
            self.stream.write(f"\r[{bar:<30}] {100 * feedback.fraction:3.0f}%  {feedback.stage:<9} "
                              f"{elapsed:5.1f} s  {feedback.message[:60]:<60}")
        self.stream.flush()

    def close(self) -> None:
        """End the progress line."""
        if self.tty:
            self.stream.write("\n")
            self.stream.flush()
