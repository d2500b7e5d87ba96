"""rclpy's ActionClient made safe for the coordinator's stage calls: no answer lost to a race, and a goal
that survives a lost message (GoalCall)."""

from __future__ import annotations

import threading
import time
import uuid
from typing import Callable

from action_msgs.msg import GoalStatus
from rclpy.action import ActionClient
from rclpy.action.client import ClientGoalHandle
from unique_identifier_msgs.msg import UUID

TERMINAL = (GoalStatus.STATUS_SUCCEEDED, GoalStatus.STATUS_CANCELED, GoalStatus.STATUS_ABORTED)
STATUS_NAMES = {GoalStatus.STATUS_UNKNOWN: "none (the goal was never listed)", GoalStatus.STATUS_ACCEPTED: "accepted",
                GoalStatus.STATUS_EXECUTING: "executing", GoalStatus.STATUS_CANCELING: "canceling",
                GoalStatus.STATUS_SUCCEEDED: "succeeded", GoalStatus.STATUS_CANCELED: "canceled",
                GoalStatus.STATUS_ABORTED: "aborted"}
# s without a goal response before the status topic is asked whether the goal arrived. Longer than the
# DDS lease + ServerWatch's grace (3 + 2 s): a dead or frozen stage fails the call first, and never gets
# the goal (a mesh of megabytes) again, which it would hold (the first fault soak with 3 s, when the
# profile still used shared memory: after a frozen-then-killed filter node, the soak's client lost sight
# of the coordinator).
ACCEPT_WAIT = 8.0
RESULT_WAIT = 3.0   # s the status may say "ended" without the result arriving before it is asked for again
RESULT_WAIT_MAX = 6.0   # s at most between asks
RENEW_EVERY = 3     # unanswered result asks before the next goes through a new client


class RegisteringActionClient(ActionClient):
    """rclpy's ActionClient (Jazzy 7.1.5) sends a goal, cancel or result request first and registers the
    future its response completes afterwards. An executor thread that takes the response in between drops
    it ("Ignoring unexpected ... response") and the future never completes: the caller waits for its
    whole timeout (ros2/rclpy#1123, fixed upstream after this version). Here each send and its
    registration hold one lock, and the handling of taken responses waits for that lock.

    It also keeps, for the goals a caller `watch`es, the latest status their server published: rclpy
    updates only goal handles the caller still holds, and only once it has the goal's response.
    And `destroy` is safe while an executor spins its node in another thread."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        # Reentrant: a response's done callback may send the next request (the result after the goal).
        self._registering = threading.RLock()
        self._watched: dict[bytes, int] = {}   # goal id -> latest status listed (STATUS_UNKNOWN: not yet)
        self._forgotten: list[bytes] = []      # goals whose feedback callbacks go (in execute: no race with it)

    def destroy(self) -> None:
        """rclpy's destroy frees the handle, then takes the client off its node. An executor that listed
        the node's clients in between adds the freed handle to its next wait set, and its spin thread
        dies ("action client pointer is invalid"; a renewed stage client, or a test's, can do that to
        the coordinator). Here the client leaves the node first, and the handle is freed from a one-shot
        timer: between two wait sets, when no executor lists it any more."""
        node = self._node
        node.remove_waitable(self)
        executor = node.executor
        # Nothing spins the node (no executor, or one shut down: rclpy's shutdown drops its nodes but
        # leaves node.executor set), so nothing can hold the handle, and a timer would never run.
        if executor is None or node not in executor.get_nodes():
            self._client_handle.destroy_when_not_in_use()
            return
        def free() -> None:
            node.destroy_timer(timer)
            self._client_handle.destroy_when_not_in_use()

        timer = node.create_timer(0.0, free, autostart=False)   # started once `free` can name it
        timer.reset()

    def send_goal_async(self, *args, **kwargs):
        """rclpy's send_goal_async, registered before its answer is handled."""
        with self._registering:
            return super().send_goal_async(*args, **kwargs)

    def _cancel_goal_async(self, goal_handle):
        with self._registering:
            return super()._cancel_goal_async(goal_handle)

    def _get_result_async(self, goal_handle):
        with self._registering:
            return super()._get_result_async(goal_handle)

    def watch(self, goal_id: bytes) -> None:
        """Follow this goal's status (status_of) until `forget`."""
        self._watched.setdefault(goal_id, GoalStatus.STATUS_UNKNOWN)

    def forget(self, goal_id: bytes) -> None:
        """Stop following the goal; its feedback callback goes too (a goal stopped without its result
        asked for would keep it for ever)."""
        self._watched.pop(goal_id, None)
        self._forgotten.append(goal_id)

    def status_of(self, goal_id: bytes) -> int:
        """The latest status the server listed for a watched goal (STATUS_UNKNOWN: never listed)."""
        return self._watched.get(goal_id, GoalStatus.STATUS_UNKNOWN)

    async def execute(self, taken_data):
        """rclpy's handling of taken responses, feedback and status, once no request is half registered."""
        with self._registering:   # a request sent but not yet registered is registered first
            pass
        while self._forgotten:   # one execute at a time (the client's own exclusive group)
            self._feedback_callbacks.pop(self._forgotten.pop(), None)
        status = taken_data.get("status")
        if status is not None and self._watched:
            for entry in status.status_list:
                goal_id = bytes(entry.goal_info.goal_id.uuid)
                if goal_id in self._watched:
                    self._watched[goal_id] = entry.status
        await super().execute(taken_data)


class GoalCall:
    """One goal of a stage's action, kept alive across a lost message.

    DDS can drop a request sent just after a server (re)started (wait_for_server says only that the
    client's request writer matched the server's reader, not the reverse), and any of the four messages
    of a call may be lost. Signs of life decide what to do:
    - no goal response within `accept_wait` (8 s): if the status topic lists the goal, the server took it and
      its response was lost: the goal is adopted as accepted; else it is sent again under a new goal id
      and request_id (`make_goal(attempt)`), the wait doubling each time;
    - the status says the goal ended but no result came within `result_wait`: the result is asked again,
      the wait doubling each time (seen in a kill soak: while a SIGKILLed mission client was still
      listed, ~30 s, a stage's result responses to the coordinator were lost, though its small goal
      responses and status got through); every RENEW_EVERY-th ask goes through a new client from
      `renew()` (a result reader that stays broken after that window: the only ask it must not take);
    - a goal is sent again only while `may_resend()` (the servers the call went to are the ones listed:
      a goal is never moved to a respawned node; ServerWatch fails that call);
    - once one attempt is adopted, every other one is stopped (`stop(goal_id, request_id)`), now if it
      is listed or later if its acceptance arrives late, so no forgotten goal holds the stage.
    `done` is set with the result (`answer`, GetResult's response) or when the goal is refused."""

    def __init__(self, client: RegisteringActionClient, make_goal: Callable[[int], tuple[object, str]],
                 feedback: Callable | None, stop: Callable[[UUID, str], None], log,
                 may_resend: Callable[[], bool] = lambda: True,
                 renew: Callable[[], RegisteringActionClient] | None = None,
                 accept_wait: float = ACCEPT_WAIT, result_wait: float = RESULT_WAIT):
        self.client = client
        self.may_resend = may_resend
        self.renew = renew
        self._result_asks = 0
        self.make_goal = make_goal
        self._given_feedback = feedback
        self.feedback = self._on_feedback
        self.stop = stop
        self.log = log
        self.accept_wait = accept_wait
        self.result_wait = result_wait
        self.done = threading.Event()
        self.answer = None            # GetResult response
        self.refused = False
        self.handle: ClientGoalHandle | None = None
        self.attempts: list[tuple[UUID, str, object]] = []   # (goal id, request_id, goal future)
        self._lock = threading.RLock()
        self._finished = False        # the caller stopped waiting: late acceptances are stopped
        self._sent_at = 0.0
        self._result_asked_at = 0.0
        self._ended_since: float | None = None
        self._held_back = False       # said that a lost goal is not sent again (its servers changed)
        self._first_sent_at = time.monotonic()
        self._accepted_after: float | None = None   # s from the first sending to the adoption
        self._adopted_by = ""                       # "its response" or "the status list"
        self._feedback_count = 0
        self._feedback_at = 0.0
        self._unknown_answers = 0   # result answers from a server that did not know the goal
        self._send()

    @property
    def request_id(self) -> str:
        """The request_id of the attempt adopted, else of the latest one."""
        with self._lock:
            if self.handle is not None:
                return next(r for g, r, _ in self.attempts if g == self.handle.goal_id)
            return self.attempts[-1][1]

    def _on_feedback(self, message) -> None:
        self._feedback_count += 1
        self._feedback_at = time.monotonic()
        if self._given_feedback is not None:
            self._given_feedback(message)

    def heard(self) -> str:
        """What the caller heard of the call so far (for an error that ends it): what was sent, accepted,
        listed, fed back and asked, so a call that got no reply says which message never came."""
        now = time.monotonic()
        with self._lock:
            parts = [f"goal sent {len(self.attempts)} time(s)"]
            if self.handle is None:
                parts.append("never accepted: no goal response, and its server never listed it")
            else:
                parts.append(f"accepted after {self._accepted_after:.1f} s (by {self._adopted_by})")
                status = self.client.status_of(bytes(self.handle.goal_id.uuid))
                parts.append(f"last status listed: {STATUS_NAMES.get(status, status)}")
            parts.append(f"{self._feedback_count} feedback message(s)" +
                         (f", the last {now - self._feedback_at:.0f} s ago" if self._feedback_count else ""))
            if self.handle is not None:
                parts.append(f"result asked {self._result_asks} time(s), no result came" +
                             (f" ({self._unknown_answers} answer(s) said the server does not know the goal)"
                              if self._unknown_answers else ""))
        return "; ".join(parts)

    def _send(self) -> None:
        goal_id = UUID(uuid=list(uuid.uuid4().bytes))
        goal, request_id = self.make_goal(len(self.attempts))
        self.client.watch(bytes(goal_id.uuid))
        future = self.client.send_goal_async(goal, feedback_callback=self.feedback, goal_uuid=goal_id)
        self.attempts.append((goal_id, request_id, future))
        self._sent_at = time.monotonic()
        future.add_done_callback(lambda f, goal_id=goal_id: self._on_goal(goal_id, f))

    def _on_goal(self, goal_id: UUID, future) -> None:
        handle = None if future.exception() is not None else future.result()
        with self._lock:
            if self.handle is not None or self._finished:
                if handle is not None and handle.accepted and (self.handle is None or handle != self.handle):
                    self._stop(goal_id)   # a superseded attempt accepted late
                return
            if handle is None or not handle.accepted:
                if goal_id == self.attempts[-1][0]:
                    self.refused = True
                    self.done.set()
                return
            self._adopt(handle)

    def _adopt(self, handle: ClientGoalHandle, by: str = "its response") -> None:
        self.handle = handle
        self._accepted_after, self._adopted_by = time.monotonic() - self._first_sent_at, by
        self._ask_result()
        for goal_id, _, future in self.attempts:
            if goal_id != handle.goal_id and (not future.done() or
                                              self.client.status_of(bytes(goal_id.uuid)) != GoalStatus.STATUS_UNKNOWN):
                self._stop(goal_id)

    def _ask_result(self) -> None:
        self._result_asked_at = time.monotonic()
        self._result_asks += 1
        self.handle.get_result_async().add_done_callback(self._on_result)

    def _renew_client(self) -> None:
        """Carry the goal over to a new client of the same server."""
        old, self.client = self.client, self.renew()
        goal_id = bytes(self.handle.goal_id.uuid)
        self.client.watch(goal_id)
        self.client._watched[goal_id] = old.status_of(goal_id)
        if self.feedback is not None:
            self.client._feedback_callbacks[goal_id] = self.feedback
        self.handle = ClientGoalHandle(self.client, self.handle.goal_id, self.handle._goal_response)

    def _on_result(self, future) -> None:
        answer = None if future.exception() is not None else future.result()
        if answer is not None and answer.status == GoalStatus.STATUS_UNKNOWN:
            self._unknown_answers += 1
            return   # a server that does not know the goal (another one): ServerWatch or the timeout ends the call
        if answer is not None and not self.done.is_set():
            self.answer = answer
            self.done.set()

    def _stop(self, goal_id: UUID) -> None:
        request_id = next(r for g, r, _ in self.attempts if g == goal_id)
        self.stop(goal_id, request_id)

    def poll(self) -> None:
        """Act on the signs of life (or their absence); called by the waiting thread between waits."""
        now = time.monotonic()
        with self._lock:
            if self.done.is_set() or self._finished:
                return
            if self.handle is None:
                if now - self._sent_at < self.accept_wait * 2 ** (len(self.attempts) - 1):
                    return
                goal_id, request_id, future = self.attempts[-1]
                status = self.client.status_of(bytes(goal_id.uuid))
                if status != GoalStatus.STATUS_UNKNOWN:
                    self.log.warning(f"{self.client._action_name}: goal {request_id} is listed by its server but its "
                                     "acceptance never arrived (lost): taking it as accepted")
                    self.client._remove_pending_goal_request(future)
                    response = self.client._action_type.Impl.SendGoalService.Response(accepted=True)
                    self._adopt(ClientGoalHandle(self.client, goal_id, response), "the status list")
                    return
                if not self.may_resend():
                    if not self._held_back:
                        self._held_back = True
                        self.log.warning(f"{self.client._action_name}: goal {request_id} got no answer in "
                                         f"{now - self._sent_at:.1f} s, and the action's servers changed since "
                                         "(none listed now, or a new one joined): not sent again (the call "
                                         "fails once its servers are gone, parameter gone_grace, or at "
                                         "stage_timeout)")
                    return
                self.log.warning(f"{self.client._action_name}: goal {request_id} got no answer in "
                                 f"{now - self._sent_at:.1f} s and its server does not list it (lost): sending it again")
                self._send()
                return
            ended = self.client.status_of(bytes(self.handle.goal_id.uuid)) in TERMINAL
            if not ended:
                self._ended_since = None
                return
            self._ended_since = self._ended_since or now
            wait = min(RESULT_WAIT_MAX, self.result_wait * 2 ** max(0, self._result_asks - 1))
            if now - max(self._ended_since, self._result_asked_at) > wait:
                renew = self.renew is not None and self._result_asks % RENEW_EVERY == 0
                self.log.warning(f"{self.client._action_name}: goal {self.request_id} ended "
                                 f"{now - self._ended_since:.1f} s ago but its result never arrived (lost): asking again"
                                 + (" through a new client" if renew else ""))
                if renew:
                    self._renew_client()
                self._ask_result()

    def abandon(self) -> None:
        """The caller stops waiting (cancelled, timed out): stop every attempt the server holds, now (adopted
        or listed) or once its acceptance arrives (_on_goal)."""
        with self._lock:
            self._finished = True
            for goal_id, _, _ in self.attempts:
                adopted = self.handle is not None and goal_id == self.handle.goal_id
                if adopted or self.client.status_of(bytes(goal_id.uuid)) != GoalStatus.STATUS_UNKNOWN:
                    self._stop(goal_id)

    def close(self) -> None:
        """Forget the attempts' status and feedback (the call is over)."""
        with self._lock:
            self._finished = True
            for goal_id, _, _ in self.attempts:
                self.client.forget(bytes(goal_id.uuid))
