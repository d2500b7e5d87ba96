"""Calling the stages from the coordinator: waits, timeouts, vanished servers, failures.

Reconstruct, segment, filter and optimise are called through their actions (same names as their
services; perch_common.ros.service.create_stage_action): the goal's feedback reaches the caller's
`progress`, and a call abandoned (mission cancelled, no reply in time) is stopped with the standard
action cancel, or on a networked graph, which refuses that cancel, with the signed StageCancel naming
the call's request_id (the one place the coordinator still sends StageCancel for these stages: the
action cancel carries no signature). A goal survives a lost message (action_client.GoalCall): a goal
not accepted within seconds is adopted if its server lists it, else sent again; a result that does not
come once the status says the goal ended is asked for again.
The stage's action publishes its service's introspection events for each goal,
so recordings, `perch replay --check` and the report read these calls as service calls. Clean and crop
are quick and stay service calls.

Every failure becomes a StageError whose message names the stage and its service, so the
mission result says which stage to look at. Each call carries its own request_id, so abandoning it
(mission cancelled, no reply in time) stops that call's work on the stage and no other client's.
Each mesh goes to a stage once: a request whose mesh the service already holds carries its content
id only, and a "mesh not cached" reply (the node restarted) is answered by sending the arrays again
(perch_common.mesh_cache). A stage hosted in this process reads this process's cache, so it gets by
id whatever that cache holds.

A call follows the identity of the server it was sent to (the endpoint GIDs of the service's request
readers when the call went out), not only whether some server is offered: a stage node that died and
came back (`perch launch` respawns it within a second) can never answer the call the dead one took,
so the call fails as soon as every server it was sent to has left the graph for `gone_grace` seconds
(the DDS lease, 3 s, drops a killed process). The stage is not retried on the new node: a crash may
be the input's doing, and the user gets a clear reason at once instead of a second wait.

A request can be lost on its way (DDS drops data a server's reader gets before it has matched the
writer, and nothing on the caller's side shows that match). A goal's losses are GoalCall's; a service
call (clean, crop) of which nothing is heard (no reply, no progress: a stage announces every call it
starts) is sent again after RESEND_AFTER seconds, then after
twice that, ... (RESENDS times), under the same call's id (perch_common.ros.service.resent_id); the stage
runs a resend only if the first never arrived, and answers it as a duplicate otherwise. A call is resent
only while the service's servers are the ones it went to: a respawned node does not take up a call
that its dead predecessor may have been running.
"""

from __future__ import annotations

import itertools
import threading
import time
import uuid
from dataclasses import dataclass
from typing import Callable

from perch_common.conventions import NODE_SERVICES, STAGE_SERVICES
from perch_common.errors import PerchError
from perch_common.mesh_cache import PROCESS_CACHE, MeshBook, is_mesh_not_cached
from perch_common.ros.conversions import id_only_msg, is_id_only, msg_content_id
from perch_common.ros.servers import server_endpoints
from perch_common.ros.service import PROGRESS_TOPIC, copy_fields, first_call_id, is_duplicate_reply, resent_id
from perch_interfaces import action, srv

ACTION_GOAL_SERVICE = "/_action/send_goal"   # an action's goal service, under the action's name

RESEND_AFTER = 3.0   # s without a sign of a call before it is sent again (doubling after each resend)
RESENDS = 3


@dataclass(frozen=True)
class Stage:
    """One pipeline stage: its name, its service (relative to the graph's namespace) and type, and the
    type of the action served under the same name (None: called as a service)."""

    name: str
    service: str
    srv_type: type
    action_type: type | None = None


STAGES = {s.name: s for s in (
    Stage("reconstruct", STAGE_SERVICES["reconstruct"], srv.Reconstruct, action.Reconstruct),
    Stage("clean", STAGE_SERVICES["clean"], srv.CleanMesh),
    Stage("crop", STAGE_SERVICES["crop"], srv.Crop),
    Stage("segment", STAGE_SERVICES["segment"], srv.Segment, action.Segment),
    Stage("filter", STAGE_SERVICES["filter"], srv.Filter, action.Filter),
    Stage("optimise", STAGE_SERVICES["optimise"], srv.Optimise, action.Optimise),
)}
SERVICE_NODES = {service: node for node, services in NODE_SERVICES.items() for service in services}


class StageError(PerchError):
    """A stage call that failed; the message names the stage and its (resolved) service."""

    def __init__(self, stage: str, message: str, service: str | None = None):
        super().__init__(f"stage {stage} ({service or '/' + STAGES[stage].service}): {message}")
        self.stage = stage


class MissionCancelled(PerchError):
    """The mission was cancelled (by its client, or because the client left)."""

    pass


class StageCaller:
    """One client per stage (action client where the stage has an action) on `node`; `call` blocks the
    calling thread (not the executor)."""

    def __init__(self, node, callback_group, service_wait: float, timeout: float, gone_grace: float):
        self.node = node
        self.service_wait = service_wait
        self.timeout = timeout
        self.gone_grace = gone_grace
        self.clients = {name: node.create_client(s.srv_type, s.service, callback_group=callback_group)
                        for name, s in STAGES.items() if s.action_type is None}
        # Each action client in a group of its own: the executor never handles two batches of one client's
        # responses at once (its bookkeeping is unlocked), while the stages' clients stay independent.
        self.actions = {name: self._action_client(name) for name, s in STAGES.items() if s.action_type is not None}
        self.services = {name: node.resolve_service_name(s.service) for name, s in STAGES.items()}
        from perch_common.ros.service import CANCEL_TOPIC
        from perch_interfaces.msg import StageCancel, StageProgress

        self._cancel_msg = StageCancel
        self.cancel_pub = node.create_publisher(StageCancel, CANCEL_TOPIC, 10)
        self.meshes = MeshBook()
        # Request ids: this caller's own prefix (unique across processes and restarts), then a count.
        self.caller_id = f"{node.get_fully_qualified_name()}/{uuid.uuid4().hex[:12]}"
        self._calls = itertools.count(1)
        # Service calls' signs of life: a stage announces each call it starts (action goals have theirs).
        self._heard: dict[str, bool] = {}   # calls in flight (first ids): whether a stage announced them
        self._heard_lock = threading.Lock()
        node.create_subscription(StageProgress, PROGRESS_TOPIC, self._on_progress, 10, callback_group=callback_group)

    def _on_progress(self, msg) -> None:
        if not msg.request_id.startswith(f"{self.caller_id}/"):
            return   # another caller's call
        call_id = first_call_id(msg.request_id)
        with self._heard_lock:
            if call_id in self._heard:   # not a late message of a finished call
                self._heard[call_id] = True

    def _heard_of(self, request_id: str) -> bool:
        with self._heard_lock:
            return self._heard.get(request_id, False)

    def _action_client(self, stage: str):
        """A new action client for the stage, in a mutually exclusive group of its own: the executor never
        handles two batches of one client's responses at once (its bookkeeping is unlocked), while the
        stages' clients stay independent."""
        from rclpy.callback_groups import MutuallyExclusiveCallbackGroup

        from perch_operator.coordinator.action_client import RegisteringActionClient

        return RegisteringActionClient(self.node, STAGES[stage].action_type, STAGES[stage].service,
                                       callback_group=MutuallyExclusiveCallbackGroup())

    def _renew_action_client(self, stage: str):
        """Replace the stage's action client (GoalCall: its results stopped arriving)."""
        old, self.actions[stage] = self.actions[stage], self._action_client(stage)
        if not old._pending_goal_requests and len(set(map(bytes, (g.uuid for g in
                                                                  old._result_sequence_number_to_goal_id.values())))) <= 1:
            old.destroy()   # only the renewing call's goal was on it (else it stays, with its callers)
        return self.actions[stage]

    def _stop_goal(self, stage: str, goal_id, request_id: str, reason: str) -> None:
        """Stop one goal's work: the standard action cancel by goal id (a goal the server never took makes
        it a no-op); a networked graph refuses that and takes the signed StageCancel naming its request_id."""
        from rclpy.action.client import ClientGoalHandle

        from perch_common.network_auth import networked

        if networked():
            self._signed_cancel(stage, request_id, reason)
            return
        client = self.actions[stage]
        accepted = STAGES[stage].action_type.Impl.SendGoalService.Response(accepted=True)
        ClientGoalHandle(client, goal_id, accepted).cancel_goal_async()

    def _signed_cancel(self, stage: str, request_id: str, reason: str) -> None:
        """Tell the stage to stop the work of call `request_id` (it checks between steps): StageCancel, signed
        on a networked graph."""
        from perch_common.network_auth import sign_if_networked

        message = self._cancel_msg(service=STAGES[stage].service, request_id=request_id, reason=reason)
        if hasattr(message, "auth"):   # a networked graph's stages stop calls for signed cancels only
            message.auth = sign_if_networked("stage_cancel", message.service, request_id, reason)
        self.cancel_pub.publish(message)

    def call(self, stage: str, request, cancelled: Callable[[], bool] = lambda: False,
             progress: Callable[[str, float, str], None] | None = None):
        """The stage's successful reply; raises StageError (or MissionCancelled).

        The request's mesh (when it has one) travels by content id when the service holds it, and
        each sending gets a fresh request_id; the request object itself is left as given.
        progress(stage, fraction, phase): the feedback of a stage called as an action."""
        service = STAGES[stage].service
        full = getattr(request, "mesh", None)
        given_id = request.request_id
        key = ""
        if full is not None and len(full.triangles):
            full.content_id = full.content_id or msg_content_id(full)
            key = full.content_id
        try:
            if key and (self.meshes.send_id_only(service, key) or self._shares_cache(stage, key)):
                request.mesh = id_only_msg(full)
                response = self._send(stage, request, cancelled, progress)
                if response.success or not is_mesh_not_cached(response.message):
                    return self._accepted(stage, response, key, full)
                self.meshes.missed(service, key)
                request.mesh = full
            return self._accepted(stage, self._send(stage, request, cancelled, progress), key, full)
        finally:
            request.request_id = given_id
            if full is not None:
                request.mesh = full

    @staticmethod
    def _shares_cache(stage: str, key: str) -> bool:
        """The stage's node lives in this process, whose cache holds the mesh (a one-process graph)."""
        return SERVICE_NODES.get(STAGES[stage].service) in PROCESS_CACHE.hosts and key in PROCESS_CACHE

    def _accepted(self, stage: str, response, key: str, sent):
        """Raise StageError for a failed reply; note which meshes the service now holds."""
        if not response.success:
            raise StageError(stage, f"failed: {response.message}", self.services[stage])
        service = STAGES[stage].service
        self.meshes.holds(service, key)
        reply_mesh = getattr(response, "mesh", None)
        if reply_mesh is not None and reply_mesh.content_id:
            self.meshes.holds(service, reply_mesh.content_id)
            if is_id_only(reply_mesh) and reply_mesh.content_id == key:
                response.mesh = sent   # the stage named the mesh it was sent instead of echoing it
        return response

    def _send(self, stage: str, request, cancelled: Callable[[], bool], progress=None):
        """One call of the stage's service; its reply, successful or not."""
        if stage in self.actions:
            return self._send_goal(stage, request, cancelled, progress)
        client = self.clients[stage]
        if not client.wait_for_service(timeout_sec=self.service_wait):
            raise StageError(stage, f"service not available within {self.service_wait:.0f} s; is its node "
                                    "running? (`perch launch` starts the graph)", self.services[stage])
        call_id = f"{self.caller_id}/{stage}/{next(self._calls)}"
        request.request_id = call_id
        with self._heard_lock:
            self._heard[call_id] = False
        done = threading.Event()
        futures = []

        def send() -> None:
            future = client.call_async(request)
            future.add_done_callback(lambda _: done.set())
            futures.append(future)

        send()
        servers = ServerWatch(self.node, self.services[stage], self.gone_grace)
        started = time.monotonic()
        deadline, resend_at, resends = started + self.timeout, started + RESEND_AFTER, 0
        try:
            while True:
                if done.wait(0.05):
                    done.clear()
                    for future in [f for f in futures if f.done()]:
                        futures.remove(future)
                        response = future.result()
                        if response is None:
                            raise StageError(stage, "the call ended without a reply", self.services[stage])
                        if not is_duplicate_reply(response):
                            return response
                now = time.monotonic()
                if cancelled():
                    self._signed_cancel(stage, call_id, "mission cancelled")
                    raise MissionCancelled(f"mission cancelled during stage {stage}")
                if servers.gone():
                    raise StageError(stage, servers.describe(), self.services[stage])
                if now > deadline:
                    self._signed_cancel(stage, call_id, "no reply within stage_timeout")
                    heard = ("the stage announced the call" if self._heard_of(call_id) else
                             "nothing: the stage never announced the call")
                    raise StageError(stage, f"no reply within {self.timeout:.0f} s (parameter stage_timeout); sent "
                                            f"{1 + resends} time(s), heard: {heard}", self.services[stage])
                # Resent only to the servers it went to: a node that replaced them (respawned) must not take
                # up a call its dead predecessor may have been running (ServerWatch fails that call).
                if resends < RESENDS and now > resend_at and not self._heard_of(call_id) and servers.unchanged():
                    resends += 1
                    self.node.get_logger().warning(
                        f"stage {stage}: nothing heard of call {call_id!r} for {now - started:.0f} s "
                        f"(the request may have been lost); sending it again ({resends} of {RESENDS})")
                    request.request_id = resent_id(call_id, resends)
                    send()
                    request.request_id = call_id
                    resend_at = now + RESEND_AFTER * 2 ** resends
        finally:   # a reply still to come (the first call's or a resend's) is not waited for
            for future in futures:
                client.remove_pending_request(future)
            with self._heard_lock:
                del self._heard[call_id]

    def _send_goal(self, stage: str, request, cancelled: Callable[[], bool], progress):
        """One goal of the stage's action (GoalCall: sent again, adopted or its result asked again when a
        message is lost); the result as the service's reply, successful or not."""
        from perch_operator.coordinator.action_client import TERMINAL, GoalCall

        client = self.actions[stage]
        if not client.wait_for_server(timeout_sec=self.service_wait):
            raise StageError(stage, f"action not available within {self.service_wait:.0f} s; is its node "
                                    "running? (`perch launch` starts the graph)", self.services[stage])
        action_type = STAGES[stage].action_type
        stop_reason = ["sent again (an earlier attempt was lost)"]

        def make_goal(attempt: int):
            request.request_id = f"{self.caller_id}/{stage}/{next(self._calls)}"
            return copy_fields(request, action_type.Goal()), request.request_id

        def feedback(message) -> None:
            if progress is not None and not call_over.is_set():
                progress(stage, message.feedback.fraction, message.feedback.phase)

        call_over = threading.Event()
        servers = ServerWatch(self.node, self.services[stage] + ACTION_GOAL_SERVICE, self.gone_grace)
        call = GoalCall(client, make_goal, feedback,
                        lambda goal_id, request_id: self._stop_goal(stage, goal_id, request_id, stop_reason[0]),
                        self.node.get_logger(), may_resend=servers.unchanged,
                        renew=lambda: self._renew_action_client(stage))
        deadline = time.monotonic() + self.timeout
        try:
            while not call.done.wait(0.05):
                call.poll()
                if cancelled():
                    stop_reason[0] = "mission cancelled"
                    call.abandon()
                    raise MissionCancelled(f"mission cancelled during stage {stage}")
                if servers.gone():
                    raise StageError(stage, servers.describe(), self.services[stage])
                if time.monotonic() > deadline:
                    stop_reason[0] = "no reply within stage_timeout"
                    heard = call.heard()
                    call.abandon()
                    raise StageError(stage, f"no reply within {self.timeout:.0f} s (parameter stage_timeout); "
                                            f"heard: {heard}", self.services[stage])
        finally:
            call_over.set()
            call.close()
        if call.refused:
            raise StageError(stage, "the action refused the goal", self.services[stage])
        if call.answer.status not in TERMINAL:   # STATUS_UNKNOWN: the server no longer knew the goal
            raise StageError(stage, f"the goal's result was lost (status {call.answer.status})", self.services[stage])
        return copy_fields(call.answer.result, STAGES[stage].srv_type.Response())


class ServerWatch:
    """`gone()` turns True when every server of `service` present as the call went out has left the
    graph for `grace` seconds, whether or not another server (a respawned node) has appeared since.
    When none was listed yet as the call went out (it matched the server, the graph listing lags), the
    first ones listed are the call's."""

    CHECK_PERIOD = 0.2   # s between graph queries

    def __init__(self, node, service: str, grace: float):
        self.node = node
        self.service = service
        self.grace = grace
        self.servers = server_endpoints(node, service)
        self.current = dict(self.servers)
        self._absent_since: float | None = None
        self._checked = time.monotonic()

    def gone(self) -> bool:
        """True once the call's servers have all been absent for longer than the grace period."""
        now = time.monotonic()
        if now - self._checked < self.CHECK_PERIOD:
            return self._absent_since is not None and now - self._absent_since > self.grace
        self._checked = now
        self.current = server_endpoints(self.node, self.service)
        if not self.servers:
            # Matched (wait_for_service) but not yet listed here. Adopted however late: a call whose servers
            # were never listed could otherwise neither fail (gone) nor be sent again (unchanged).
            self.servers = dict(self.current)
        if not self.servers or set(self.servers) & set(self.current):
            self._absent_since = None
            return False
        self._absent_since = self._absent_since or now
        return now - self._absent_since > self.grace

    def unchanged(self) -> bool:
        """A request sent again now reaches only servers the call went to: some are listed, and none has
        joined since. One that left does not count (the ones still listed got the call too); before, a
        call that listed a server which then left could never send a lost request again."""
        self.gone()
        return bool(self.current) and set(self.current) <= set(self.servers)

    def describe(self) -> str:
        """Why the call ended: which node died or restarted, and whether a new one serves now."""
        names = ", ".join(sorted(set(self.servers.values()))) or "its node"
        if self.current:
            now = ", ".join(sorted(set(self.current.values())))
            return (f"the service disappeared during the call: the node serving it ({names}) died or restarted, "
                    f"and the new one ({now}) cannot answer a request the old one took; run the mission again")
        return (f"the service disappeared during the call: the node serving it ({names}) stopped or crashed; "
                "restart it (`perch launch` restarts nodes that die) and run the mission again")
