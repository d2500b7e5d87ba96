"""Service callbacks that always answer: expected errors become success=false with their message,
unexpected ones are logged with a traceback and answered as internal errors; the node keeps serving.

Every request is validated first (perch_common.request_validation); one stage call's work can be
cancelled by its caller (a perch_interfaces/StageCancel naming the service and the request's
request_id on CANCEL_TOPIC stops that call at its next `checkpoint()`, and no other call), and
after each call the node gives freed memory back to the system.

Each call runs under a perch_common.work.WorkContext: what the core reports (`report`, `steps`) is
published on PROGRESS_TOPIC (perch_interfaces/StageProgress, naming the service and request_id), and
the node sets the call's work budget once it knows its input (`set_work_budget`).

A request can be lost on its way (DDS drops what a server's reader receives before it has matched the
caller's writer, just after either side started), so a caller that hears nothing of a call may send it
again under `resent_id(request_id, n)`. StageWork runs a resent call only when the first never arrived;
otherwise it answers at once with a reply that `is_duplicate_reply` recognises, and the caller keeps
waiting for the first call's reply. Every call announces itself on PROGRESS_TOPIC as it starts, so a caller
knows that its request arrived.

A stage's action (create_stage_action) publishes the introspection events its service would publish
for the same call (ActionIntrospection), so recordings, `perch replay --check` and the report read
action calls exactly as service calls; rclpy Jazzy has no action introspection.
"""

from __future__ import annotations

import contextlib
import functools
import threading
import time
import traceback
from collections import OrderedDict
from typing import Callable

from perch_common.cancellation import CancelToken, cancellable, checkpoint
from perch_common.errors import EXPECTED
from perch_common.memory import KEEP_FREED_MEMORY, release_memory
from perch_common.request_validation import validate_request
from perch_common.work import SOUP_HINT, WorkContext, current, work_budget

CANCEL_TOPIC = "perch/stage_cancel"    # perch_interfaces/StageCancel: the one call whose work to stop
PROGRESS_TOPIC = "perch/stage_progress"  # perch_interfaces/StageProgress: how far each call in progress is
RELEASE_DELAY = 0.2                    # s after a reply before freeing memory (the reply is sent by then)
EARLY_CANCELS = 256                    # cancels remembered for calls not started yet (queued behind others)
CALLS_REMEMBERED = 1024                # request ids kept to recognise a resent call as a duplicate
RESENT_MARK = "#resent"                # request_id + RESENT_MARK + n: the n-th resend of that call
DUPLICATE_REPLY = "duplicate of call"  # a resent call's reply when the first arrived (its reply is the answer)
STARTED_PHASE = "request received"


def resent_id(request_id: str, attempt: int) -> str:
    """The request_id of the `attempt`-th resend of call `request_id`."""
    return f"{request_id}{RESENT_MARK}{attempt}"


def first_call_id(request_id: str) -> str:
    """The call a request_id belongs to: itself, or the call that a resend repeats."""
    return request_id.split(RESENT_MARK, 1)[0]


def is_duplicate_reply(response) -> bool:
    """True for StageWork's answer to a resend of a call that had arrived (not the call's answer)."""
    return not response.success and response.message.startswith(DUPLICATE_REPLY)


def answering(callback: Callable) -> Callable:
    """Decorate `callback(self, request, response) -> response` of a Node.

    The response type must have `success` and `message`; a `seconds` field, when present, is set
    to the callback's duration.
    """

    @functools.wraps(callback)
    def wrapper(self, request, response):
        started = time.perf_counter()
        try:
            try:
                validate_request(request)
            except ValueError as exc:
                raise type(exc)(f"invalid request: {exc}") from None
            checkpoint("starting")   # cancelled while it waited behind another call
            response = callback(self, request, response)
        except EXPECTED as exc:
            response.success, response.message = False, str(exc)
        except Exception as exc:  # keep serving; the traceback goes to the log
            self.get_logger().error(traceback.format_exc())
            response.success, response.message = False, f"internal error: {type(exc).__name__}: {exc}"
        if hasattr(response, "seconds"):
            response.seconds = time.perf_counter() - started
        # rclpy ties a severity to each logging call site: one line per severity.
        if response.success:
            self.get_logger().info(f"{callback.__name__}: {response.message}")
        else:
            self.get_logger().warning(f"{callback.__name__}: {response.message}")
        return response

    return wrapper


class StageWork:
    """The calls a node is serving, by (service, request_id), with their cancel tokens; one per node.

    A cancel names one call. One that arrives before its call started (the call waits behind
    another in the service's callback group) is remembered, so the call stops as soon as it starts.
    """

    def __init__(self, node) -> None:
        from rclpy.callback_groups import MutuallyExclusiveCallbackGroup

        from perch_interfaces.msg import StageCancel, StageProgress

        self.node = node
        self._lock = threading.Lock()
        self._running: dict[tuple[str, str], set[CancelToken]] = {}
        self._services: set[str] = set()   # what this node serves: cancels for other services are not its own
        self.introspection: dict[str, bool] = {}   # service name -> whether its calls publish events
        self._early: OrderedDict[tuple[str, str], str] = OrderedDict()
        self._seen: OrderedDict[tuple[str, str], None] = OrderedDict()   # calls that arrived, by first id
        self._serial = threading.Lock()   # one call at a time, whether it came as a service call or an action goal
        self._release_timer = None
        # Its own group: a cancel must get through while a service callback is busy.
        self.group = MutuallyExclusiveCallbackGroup()
        node.create_subscription(StageCancel, CANCEL_TOPIC, self._on_cancel, 10, callback_group=self.group)
        self._progress_type = StageProgress
        self._progress = node.create_publisher(StageProgress, PROGRESS_TOPIC, 10)

    @classmethod
    def of(cls, node) -> "StageWork":
        """The node's StageWork (created on first use)."""
        work = getattr(node, "_perch_stage_work", None)
        if work is None:
            work = cls(node)
            node._perch_stage_work = work
        return work

    def cancel(self, service: str, request_id: str, reason: str = "") -> int | None:
        """Cancel the call to `service` whose request carries `request_id`; the number of running calls
        it stopped (0: remembered for when that call starts), None when this node does not serve `service`."""
        key = (service, request_id)
        reason = f"{service}: cancelled by its caller" + (f" ({reason})" if reason else "")
        with self._lock:
            if service not in self._services:
                return None
            tokens = list(self._running.get(key, ()))
            if not tokens and request_id:
                self._early[key] = reason
                while len(self._early) > EARLY_CANCELS:
                    self._early.popitem(last=False)
        for token in tokens:
            token.cancel(reason)
        return len(tokens)

    def _on_cancel(self, msg) -> None:
        from perch_common.network_auth import refusal_if_networked

        refused = refusal_if_networked(getattr(msg, "auth", ""), "stage_cancel", msg.service, msg.request_id, msg.reason)
        if refused:   # a networked graph stops calls for signed cancels only
            self.node.get_logger().error(f"{msg.service}: refused a cancel of {msg.request_id!r}: {refused}")
            return
        stopped = self.cancel(msg.service, msg.request_id, msg.reason)
        if stopped is None:
            return
        call = f"call {msg.request_id!r}" if msg.request_id else "calls without a request_id"
        if stopped:
            self.node.get_logger().warning(f"{msg.service}: cancelling {call} in progress")
        elif msg.request_id:
            self.node.get_logger().info(f"{msg.service}: {call} cancelled before it started")

    def serve(self, name: str, callback: Callable, serial: bool = True) -> Callable:
        """Wrap a service callback: run it under its call's cancel token, then schedule a memory release.

        serial: one such call at a time in this node (a service in the node's default, mutually exclusive
        group is serial anyway; the lock also keeps an action goal from overlapping it)."""
        with self._lock:
            self._services.add(name)

        def run(request, response, on_progress: Callable[[float, str], None] | None = None):
            request_id = str(getattr(request, "request_id", ""))
            key = (name, first_call_id(request_id))   # a resend is cancelled and recognised by its first id
            if self._duplicate(key, request_id):
                self.node.get_logger().info(f"{name}: {request_id!r} repeats a call that arrived; answered as such")
                response.success, response.message = False, f"{DUPLICATE_REPLY} {key[1]!r}, which arrived; its reply answers"
                return response
            publish = functools.partial(self._publish_progress, name, request_id)
            token = WorkContext(name, publish if on_progress is None else
                                lambda fraction, phase: (publish(fraction, phase), on_progress(fraction, phase)))
            if request_id:
                publish(0.0, STARTED_PHASE)
            with self._lock:
                self._running.setdefault(key, set()).add(token)
                early = self._early.pop(key, None)
            if early is not None:
                token.cancel(early)
            try:
                with KEEP_FREED_MEMORY, self._serial if serial else contextlib.nullcontext(), cancellable(token):
                    return callback(request, response)
            finally:
                with self._lock:
                    running = self._running[key]
                    running.discard(token)
                    if not running:
                        del self._running[key]
                del request
                self._schedule_release()

        return run

    def _duplicate(self, key: tuple[str, str], request_id: str) -> bool:
        """Note that call `key` arrived; True when `request_id` resends a call that had arrived already."""
        if not key[1]:
            return False
        with self._lock:
            arrived = key in self._seen
            self._seen[key] = None
            while len(self._seen) > CALLS_REMEMBERED:
                self._seen.popitem(last=False)
        return arrived and request_id != key[1]

    def _publish_progress(self, service: str, request_id: str, fraction: float, phase: str) -> None:
        msg = self._progress_type(service=service, request_id=request_id, fraction=float(fraction), phase=phase)
        msg.header.stamp = self.node.get_clock().now().to_msg()
        self._progress.publish(msg)

    def _schedule_release(self) -> None:
        if self._release_timer is None:
            self._release_timer = self.node.create_timer(RELEASE_DELAY, self._release, callback_group=self.group)
        else:
            self._release_timer.reset()

    def _release(self) -> None:
        self._release_timer.cancel()
        release_memory()




def set_work_budget(node, config, size: int, unit: str = "faces", hint: str = SOUP_HINT, per: float = 1000.0,
                    rate: float | None = None) -> float:
    """Give the current call its work budget: `config.work_budget_base + rate x size / per` seconds from its
    start (rate: `config.work_budget_rate` unless given); returns it (0 outside a call). The refusal names
    the node's parameters to raise when the input is sound."""
    context = current()
    if context is None:
        return 0.0
    rate = config.work_budget_rate if rate is None else rate
    seconds = work_budget(size, config.work_budget_base, rate, per)
    raise_it = (f"if the input is sound, raise {node.get_name()}'s work_budget_base or work_budget_rate "
                f"(perch plan -p {node.get_name()}:work_budget_base:={max(2 * seconds, 60):.0f})")
    context.set_budget(seconds, f"{size:,} {unit}", f"{hint}; {raise_it}" if hint else raise_it)
    return seconds


def create_stage_service(node, srv_type, name: str, callback: Callable, introspection: bool = True,
                         **kwargs):
    """A cancellable stage service whose requests and replies are published as introspection events
    when enabled, so a recorder (perch_operator) can capture and replay them."""
    from rclpy.qos import qos_profile_services_default
    from rclpy.service_introspection import ServiceIntrospectionState

    # A service in its own (reentrant) group keeps its concurrency; in the node's default group it is serial.
    work = StageWork.of(node)
    serve = work.serve(name, callback, serial="callback_group" not in kwargs)
    work.introspection[name] = introspection   # the stage's action publishes alike (create_stage_action)
    service = node.create_service(srv_type, name, serve, **kwargs)
    if introspection:
        service.configure_introspection(node.get_clock(), qos_profile_services_default,
                                        ServiceIntrospectionState.CONTENTS)
    return service


class ActionIntrospection:
    """The introspection events of service `name` for calls that came as goals of its action.

    As rcl publishes them for a service server (REQUEST_RECEIVED with the request as received, then
    RESPONSE_SENT with the reply; CONTENTS state; stamp from the node's clock; topic
    `<service>/_service_event`, QoS services default), with one difference rclpy forces: its action
    server does not expose the client's writer GID, so `client_gid` is the goal id (16 bytes, one goal
    = one call) and `sequence_number` the goal request's sequence number at its client, as a
    service's is. Readers pair the two events by (client_gid, sequence_number) as for a service.
    """

    REQUEST_RECEIVED, RESPONSE_SENT = 1, 2   # service_msgs/ServiceEventInfo event types

    def __init__(self, node, srv_type, name: str) -> None:
        from rclpy.qos import qos_profile_services_default

        self.node = node
        self.srv_type = srv_type
        self.publisher = node.create_publisher(srv_type.Event, f"{name}/_service_event", qos_profile_services_default)

    def publish(self, event_type: int, goal_id: bytes, sequence_number: int, request=None, response=None) -> None:
        """One event of the goal `goal_id`, with the request or the reply (as the service's types)."""
        event = self.srv_type.Event()
        event.info.event_type = event_type
        event.info.stamp = self.node.get_clock().now().to_msg()
        event.info.client_gid = list(goal_id)
        event.info.sequence_number = int(sequence_number)
        if request is not None:
            event.request = [request]
        if response is not None:
            event.response = [response]
        self.publisher.publish(event)


def create_stage_action(node, action_type, srv_type, name: str, callback: Callable, *,
                        result_timeout: float, introspection: bool | None = None):
    """The long-running form of a stage service: action `name` (the service's own name) of `action_type`,
    whose goal and result have the service's request and response fields. The goal runs the very callback
    the service runs (validation, work budget, one call at a time with the service's calls); feedback
    carries what the core reports (fraction, phase); the standard cancel stops it at its next checkpoint.
    A networked graph refuses the standard cancel: it carries no token (perch_common.network_auth); the
    signed StageCancel on CANCEL_TOPIC still stops a goal by its request_id.

    introspection: publish each goal as the service's introspection events (ActionIntrospection);
    default: as the stage's service created before it is configured (on when there is none).
    result_timeout: seconds a finished goal's result stays for a late get_result (the node's
    action_server_result_timeout). The goal's request (its meshes) is dropped as soon as it has run."""
    import uuid

    from rclpy.action import ActionServer, CancelResponse, GoalResponse
    from rclpy.callback_groups import ReentrantCallbackGroup

    from perch_common.network_auth import networked

    work = StageWork.of(node)
    run = work.serve(name, callback)
    goals: dict[bytes, str] = {}   # goal id -> the request_id its call runs under
    if introspection is None:
        introspection = work.introspection.get(name, True)
    events = ActionIntrospection(node, srv_type, name) if introspection else None
    sequences: dict[bytes, int] = {}   # goal id -> its goal request's sequence number (for the events)

    class StageActionServer(ActionServer):
        async def _execute_goal_request(self, request_header_and_message):
            # The goal request's header is the only place rclpy shows its sequence number.
            header, goal_request = request_header_and_message
            if events is not None:
                sequences[bytes(goal_request.goal_id.uuid)] = header.sequence_number
            return await super()._execute_goal_request(request_header_and_message)

    def execute(goal_handle):
        goal_id = bytes(goal_handle.goal_id.uuid)
        request = copy_fields(goal_handle.request, srv_type.Request())
        sequence = sequences.pop(goal_id, 0)
        if events is not None:
            events.publish(events.REQUEST_RECEIVED, goal_id, sequence, request=request)
        if not request.request_id:   # the standard cancel finds the call by the id given here
            request.request_id = f"action/{uuid.UUID(bytes=goal_id).hex}"
        goals[goal_id] = request.request_id
        if goal_handle.is_cancel_requested:   # cancelled before it started: remembered, it stops at once
            work.cancel(name, request.request_id, "action cancel")

        def feedback(fraction: float, phase: str) -> None:
            goal_handle.publish_feedback(action_type.Feedback(fraction=float(fraction), phase=phase))

        try:
            response = run(request, srv_type.Response(), feedback)
        finally:
            goals.pop(goal_id, None)
            # rclpy keeps the goal handle, and with it the goal's request, until the result expires:
            # every stage input of the last minute (each mission's meshes) would stay in memory.
            del request
            clear_fields(goal_handle.request)
        if events is not None:   # before the result, so a recording that ends with the call holds it
            events.publish(events.RESPONSE_SENT, goal_id, sequence, response=response)
        result = copy_fields(response, action_type.Result())
        if goal_handle.is_cancel_requested and not result.success:
            goal_handle.canceled()
        elif result.success:
            goal_handle.succeed()
        else:
            goal_handle.abort()
        return result

    def on_cancel(goal_handle) -> CancelResponse:
        if networked():
            node.get_logger().error(f"{name}: refused an action cancel: a networked graph takes signed "
                                    f"cancels only ({CANCEL_TOPIC})")
            return CancelResponse.REJECT
        request_id = goals.get(bytes(goal_handle.goal_id.uuid))
        if request_id is not None:
            work.cancel(name, request_id, "action cancel")
        return CancelResponse.ACCEPT

    # Reentrant: a cancel must get through while the goal runs (StageWork serialises the calls themselves).
    return StageActionServer(node, action_type, name, execute, callback_group=ReentrantCallbackGroup(),
                             goal_callback=lambda goal: GoalResponse.ACCEPT, cancel_callback=on_cancel,
                             result_timeout=max(1, round(result_timeout)))


def clear_fields(message) -> None:
    """Set every field of `message` back to its default (drops the arrays it holds)."""
    empty = type(message)()
    for field in message.get_fields_and_field_types():
        setattr(message, field, getattr(empty, field))


def copy_fields(source, target):
    """Copy the fields `target` has from `source` (a goal into a request, a response into a result, and back)."""
    for field in target.get_fields_and_field_types():
        setattr(target, field, getattr(source, field))
    return target
