"""A non-blocking Python API for Perch missions, in the style of nav2_simple_commander.

`PerchCommander` starts a mission on a running graph (`perch launch`) and returns at once; the
caller polls `isMissionComplete()`, reads `getFeedback()`, may `cancelMission()`, and finally
`getResult()` (a `MissionResult` like nav2's TaskResult) and `getMissionResult()` (the
PlanPerches result: placements, waypoints, scores). Proposals an operator must decide arrive
with `getProposals()` and are decided with `acceptProposal()` / `rejectProposal()`.

Two ways to drive it:

* its own node (`PerchCommander()`, after `rclpy.init()`): every call spins that node briefly, as
  nav2's BasicNavigator does, so a plain script needs no executor;
* a node of yours (`PerchCommander(node=my_node, spin=False)`): nothing here spins; your executor
  runs the callbacks (the commander's entities use their own reentrant callback group), and the
  calls only read state the callbacks keep. Never block your executor's thread waiting on it.

Method names follow nav2_simple_commander (camelCase) so its users find their way.
"""

from __future__ import annotations

import enum
import threading
import time
import uuid

import rclpy
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from unique_identifier_msgs.msg import UUID

from perch_common.conventions import CONFIRM_SERVICE, MISSION_ACTION
from perch_common.ros.spinning import destroyable_subscription
from perch_interfaces import msg as pm
from perch_interfaces import srv
from perch_interfaces.action import PlanPerches
from perch_operator.api.presence import ClientPresence
from perch_operator.coordinator.action_client import RegisteringActionClient

_SPIN_STEP = 0.05   # s: how long each call spins an own node


class MissionResult(enum.Enum):
    """How a mission ended (nav2_simple_commander's TaskResult)."""

    UNKNOWN = 0
    SUCCEEDED = 1
    CANCELED = 2
    FAILED = 3


class PerchCommander:
    """Start, follow, cancel and decide Perch missions without blocking."""

    def __init__(self, node: Node | None = None, spin: bool | None = None, node_name: str = "perch_commander"):
        self.node = node or rclpy.create_node(node_name)
        self._owns_node = node is None
        self.spin = self._owns_node if spin is None else spin
        self._group = ReentrantCallbackGroup()
        self._lock = threading.Lock()
        self._action = RegisteringActionClient(self.node, PlanPerches, MISSION_ACTION, callback_group=self._group)
        self._confirm = self.node.create_client(srv.Confirm, CONFIRM_SERVICE, callback_group=self._group)
        from perch_common.network_auth import networked
        from perch_operator.api.client import MissionCanceller

        # a networked graph refuses the action's unsigned cancel: cancelMission() sends the signed one
        self._signed = MissionCanceller(self.node, callback_group=self._group) if networked() else None
        latched = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
        # destroyable: `destroy` may come from any thread while the user's executor spins the node
        self._proposal_sub = destroyable_subscription(self.node, pm.Proposal, "perch/proposals", self._on_proposal,
                                                      latched, callback_group=self._group)
        self._proposals: dict[int, pm.Proposal] = {}
        self._mission_uuid: bytes | None = None   # the running mission's goal id: its proposals carry it
        self._goal_handle = None
        self._goal_future = None
        self._result_future = None
        self._feedback: PlanPerches.Feedback | None = None
        self._result: PlanPerches.Result | None = None
        self._status = MissionResult.UNKNOWN
        self._rejected = False
        self._presence = ClientPresence(self.node)   # the running goal's client, for the coordinator

    # --- missions -----------------------------------------------------------------------------------
    def waitUntilReady(self, timeout: float = 30.0) -> bool:
        """True once the mission coordinator is in the graph (own node: spins while waiting; with
        spin=False it only polls, so call it from a thread other than your executor's)."""
        deadline = time.monotonic() + timeout
        while not self._action.server_is_ready():
            if time.monotonic() > deadline:
                return False
            self._spin_or_sleep()
        return True

    def startMission(self, goal: PlanPerches.Goal | None = None, **fields) -> bool:
        """Send a mission goal (a PlanPerches.Goal, or its fields: mesh_path=, bag_path=, target=,
        num_cameras=, auto_accept=, ...) and return at once; False when no coordinator is there.
        Whether it was accepted shows in isMissionComplete()/getResult() (a rejected goal is FAILED)."""
        if self._goal_future is not None and not self.isMissionComplete():
            raise RuntimeError("a mission is still running: cancel it or wait until isMissionComplete()")
        if not self._action.server_is_ready():
            return False
        goal = goal or PlanPerches.Goal()
        for name, value in fields.items():
            if not hasattr(goal, name):
                raise ValueError(f"PlanPerches.Goal has no field '{name}'")
            setattr(goal, name, value)
        with self._lock:
            self._proposals.clear()
            self._feedback, self._result, self._status, self._rejected = None, None, MissionResult.UNKNOWN, False
            self._goal_handle = self._result_future = None
        goal_id = UUID(uuid=list(uuid.uuid4().bytes))
        with self._lock:
            self._mission_uuid = bytes(goal_id.uuid)
        self._presence.announce(goal_id.uuid)
        self._goal_future = self._action.send_goal_async(goal, feedback_callback=self._on_feedback,
                                                         goal_uuid=goal_id)
        self._goal_future.add_done_callback(self._on_goal_response)
        return True

    def isMissionComplete(self) -> bool:
        """True when the mission has ended (succeeded, failed, cancelled or was rejected)."""
        self._spin_or_sleep(0.0)
        with self._lock:
            return self._goal_future is not None and (self._rejected or self._status != MissionResult.UNKNOWN)

    def getFeedback(self) -> PlanPerches.Feedback | None:
        """The latest feedback (stage, mission fraction, stage_fraction, message), None before the first."""
        with self._lock:
            return self._feedback

    def cancelMission(self) -> None:
        """Ask the coordinator to cancel the running mission (it ends as CANCELED). Under --network
        (PERCH_NETWORK=1) the cancel is signed with the graph's key; an own node spins until the
        coordinator lists the mission as cancelling (10 s at most), with spin=False it is sent once."""
        with self._lock:
            handle = self._goal_handle
        if handle is not None and self._status == MissionResult.UNKNOWN and self._signed is not None:
            reason = "PerchCommander.cancelMission()"
            if self.spin:
                self._signed.cancel(handle.goal_id, reason, lambda: handle.status, wait=10.0, step=self._spin_or_sleep)
            else:
                self._signed.send(handle.goal_id, reason)
        elif handle is not None and self._status == MissionResult.UNKNOWN:
            future = handle.cancel_goal_async()
            if self.spin:
                rclpy.spin_until_future_complete(self.node, future, timeout_sec=10.0)

    def getResult(self) -> MissionResult:
        """How the mission ended (UNKNOWN while it runs)."""
        with self._lock:
            return MissionResult.FAILED if self._rejected else self._status

    def getMissionResult(self) -> PlanPerches.Result | None:
        """The mission's result message (placements, waypoints, scores, message), None while it runs."""
        with self._lock:
            return self._result

    # --- operator decisions ---------------------------------------------------------------------------
    def getProposals(self, pending_only: bool = True) -> list[pm.Proposal]:
        """This mission's proposals as last published (by id), only those awaiting a decision by default."""
        with self._lock:
            listed = sorted(self._proposals.values(), key=lambda p: p.id)
        return [p for p in listed if p.status == pm.Proposal.STATUS_PENDING] if pending_only else listed

    def acceptProposal(self, proposal_id: int, reason: str = ""):
        """Accept a proposal; returns the Confirm call's future (its result: success, message)."""
        return self._decide(proposal_id, srv.Confirm.Request.ACCEPT, reason)

    def rejectProposal(self, proposal_id: int, reason: str = ""):
        """Reject a proposal (the coordinator re-plans that camera); returns the Confirm call's future."""
        return self._decide(proposal_id, srv.Confirm.Request.REJECT, reason)

    def destroy(self) -> None:
        """Release the commander's clients (and its node when it made one)."""
        self._presence.close()
        self._action.destroy()
        if self._signed is not None:
            self._signed.destroy()
        self.node.destroy_client(self._confirm)
        self.node.destroy_subscription(self._proposal_sub)
        if self._owns_node:
            self.node.destroy_node()

    # --- internals ------------------------------------------------------------------------------------
    def _decide(self, proposal_id: int, decision: int, reason: str):
        from perch_common.network_auth import sign_if_networked

        request = srv.Confirm.Request(proposal_id=int(proposal_id), decision=decision, reason=reason)
        if hasattr(request, "auth"):   # a networked graph takes decisions signed with its key only
            request.auth = sign_if_networked("confirm", request.proposal_id, request.decision, request.reason)
        future = self._confirm.call_async(request)
        if self.spin:
            rclpy.spin_until_future_complete(self.node, future, timeout_sec=10.0)
        return future

    def _spin_or_sleep(self, seconds: float = _SPIN_STEP) -> None:
        if self.spin:
            rclpy.spin_once(self.node, timeout_sec=seconds)
        elif seconds:
            time.sleep(seconds)

    def _on_goal_response(self, future) -> None:
        handle = future.result()
        if not handle.accepted:
            self._presence.withdraw()   # before the mission shows as ended: a next startMission announces its own
            with self._lock:
                self._rejected = True
                self._result = PlanPerches.Result(success=False, message="the coordinator rejected the goal: "
                                                                         "another mission is running")
            return
        with self._lock:
            self._goal_handle = handle
        self._result_future = handle.get_result_async()
        self._result_future.add_done_callback(self._on_result)

    def _on_result(self, future) -> None:
        from action_msgs.msg import GoalStatus

        wrapped = future.result()
        status = {GoalStatus.STATUS_SUCCEEDED: MissionResult.SUCCEEDED,
                  GoalStatus.STATUS_CANCELED: MissionResult.CANCELED}.get(wrapped.status, MissionResult.FAILED)
        self._presence.withdraw()   # before the mission shows as ended: a next startMission announces its own
        with self._lock:
            self._result, self._status = wrapped.result, status

    def _on_feedback(self, message) -> None:
        with self._lock:
            self._feedback = message.feedback

    def _on_proposal(self, proposal: pm.Proposal) -> None:
        with self._lock:
            # Only this mission's: the topic keeps earlier missions' proposals for late joiners.
            if self._mission_uuid is not None and bytes(proposal.mission_id.uuid) == self._mission_uuid:
                self._proposals[proposal.id] = proposal
