"""One PlanPerches mission: (reconstruct | clean) -> crop -> segment -> filter -> optimise -> confirm.

Each stage is called through its action or service (StageCaller), so stages can live in other processes
or hosts. The operator part (proposals, decisions, re-optimising one slot) lives in `Operator`,
which outlives the mission so that a perch failing in flight can still be re-planned.
"""

from __future__ import annotations

import copy
import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from perch_common.conventions import FILTER_NAMES
from perch_common.frames import Alignment
from perch_common.mesh import Mesh, MeshError, far_problem, feet_problem, load_mesh, scale_problem, validate_mesh
from perch_common.request_validation import validate_request
from perch_common.ros.conversions import (
    exclusion_to_msg,
    mesh_from_msg,
    mesh_from_request,
    mesh_to_msg,
    placement_from_msg,
    placement_to_msg,
    target_from_msg,
    vector_msg,
)
from perch_common.ros.static_transforms import alignment_from_msg, alignment_to_msg
from perch_common.up_axis import choose_up, file_convention
from perch_interfaces import srv
from perch_interfaces.action import PlanPerches
from perch_operator.coordinator.messages import (
    boxes_to_aligned,
    classed_surfaces,
    placement_msg,
    surface_to_input,
    target_to_aligned,
)
from perch_operator.coordinator.proposals import Decision, Proposal, ProposalBook, ProposalError, Status
from perch_operator.coordinator.review import ReviewDecision, cropped_surfaces
from perch_operator.coordinator.stages import MissionCancelled, StageCaller, StageError
from perch_operator.outputs.report_robustness import ROBUSTNESS_FIELDS

# Rough share of a mission's time per stage, for the feedback fraction.
STAGE_WEIGHTS = {"reconstruct": 0.30, "clean": 0.05, "crop": 0.02, "segment": 0.20, "review": 0.0,
                 "filter": 0.25, "optimise": 0.40, "confirm": 0.05}

WAITING_FEEDBACK_PERIOD = 3.0  # s between repeated "waiting for decisions" feedback


AS_IT_IS = (". A goal's mesh_path is read as it is (a goal has no scale or shift): send the mesh scaled or moved "
            "in the goal's mesh field, or plan the file with `perch plan`, which takes --scale and --shift")


def goal_mesh_file(path: str) -> Mesh:
    """A goal's mesh_path, loaded as it is: a goal has no scale or shift, so a file in millimetres or in
    georeferenced coordinates is refused here, with what an action client can do beside the command-line
    flag the unit check names (a millimetre file would otherwise be refused only by the clean stage)."""
    mesh = load_mesh(path, validate=False)
    lo, hi = mesh.bounds()
    units = far_problem(lo, hi) or scale_problem(float(np.max(hi - lo)))
    if units:
        raise MeshError(f"{path}: {units}{AS_IT_IS}")
    return validate_mesh(mesh, path)


@dataclass
class MissionOptions:
    """What a mission needs besides the goal: the node's operator, crop and frame settings."""

    auto_accept: bool
    exclusion_radius: float
    clean_given_mesh: bool
    optimise_on_full_mesh: bool
    confirm_timeout: float
    up: np.ndarray               # up in the frame the stages work in (the gravity-aligned one: +z)
    frame_id: str                # input frame of a mesh whose header names none
    input_up: str = "auto"       # up of a given mesh when the goal leaves up_axis empty


@dataclass
class Operator:
    """What deciding on proposals needs once optimise has run; kept by the node after the mission."""

    book: ProposalBook
    optimise_request: srv.Optimise.Request
    auto_accept: bool
    alignment: Alignment        # the book's placements are gravity-aligned; messages go out in the input frame
    scores: tuple[float, float, float] = (0.0, 0.0, 0.0)   # fitness, coverage, mean uncertainty
    robustness: object = None   # the optimise reply (the last re-plan's) whose ROBUSTNESS_FIELDS the result reports
    replan_seconds: list[float] = field(default_factory=list)
    surfaces: list = field(default_factory=list)   # the filter's surfaces and removals, for viewers
    removals: list = field(default_factory=list)
    unit_unconfirmed: str = ""  # why the mesh's unit is in doubt ('' when it is not), for every proposal

    def caution(self) -> str:
        """What every proposal of the mission says: an up axis or a unit that was not confirmed ('')."""
        return "; ".join(note for note in (self.alignment.up_unconfirmed, self.unit_unconfirmed) if note)


def _refuse_target_outside(target, mesh: Mesh, aligned: Mesh, alignment: Alignment) -> None:
    """A goal's target whose centre lies outside the given mesh, refused in the mesh's own frame (the one
    the user gave it in). Judged as the filter judges it, on the gravity-aligned mesh's bounds (the
    same refusals), but said with the numbers the user knows, not the aligned frame's."""
    volume = target_from_msg(target)
    if volume is None:
        return
    if target_from_msg(target_to_aligned(target, alignment)).centre_outside(*aligned.bounds()):
        lo, hi = mesh.bounds()
        raise ValueError(f"invalid goal: the target's centre {np.round(volume.centroid(), 3).tolist()} lies outside "
                         f"the scanned room (the mesh spans {np.round(lo, 3).tolist()} .. {np.round(hi, 3).tolist()} "
                         "in its own frame, where the target is given): check the target's coordinates and units")


UP_SENSITIVE_STAGES = ("crop", "segment", "filter", "optimise")   # their "nothing found" may be a wrong up axis


class Mission:
    """Runs one goal; `publish` hooks let the node publish proposals and waypoints as they happen."""

    def __init__(self, caller: StageCaller, options: MissionOptions, first_proposal_id: int,
                 feedback: Callable[[str, float, str], None], cancelled: Callable[[], bool],
                 on_proposal: Callable[..., None], on_operator: Callable[[Operator], None],
                 review: Callable[[list], ReviewDecision | set[int]] | None = None,
                 on_alignment: Callable[[Alignment], None] | None = None,
                 on_input_frame: Callable[[str], None] | None = None):
        self.caller = caller
        self.options = options
        self.first_proposal_id = first_proposal_id
        self.feedback = feedback
        self.cancelled = cancelled
        self.on_proposal = on_proposal  # publishes proposal events, in order, given together when made together
        self.on_operator = on_operator
        # review(surfaces, opened): publishes the surfaces for review, tells opened(review_id) once
        # they are out, returns the decision (rejected, crops)
        self.review = review
        self.on_alignment = on_alignment  # told the input frame -> gravity-aligned frame once known
        # told a given mesh's input frame once its up axis is settled, before it is cleaned: the view
        # thread draws the given scan while the clean stage runs (alone on a core) instead of beside
        # segmentation and the filter, which take both
        self.on_input_frame = on_input_frame
        self.alignment = Alignment(options.frame_id, np.eye(3), "none", 0.0)
        self.notes: list[str] = []  # warnings for the result message (e.g. an up axis from the file's convention)
        self.clean_warnings: list[str] = []  # what the clean stage warned of, for a failure's message
        self.unit_unconfirmed = ""  # a given mesh whose unit looks wrong (feet_problem), reviewed
        self.stage_names: list[str] = []
        self.stage_seconds: list[float] = []
        self._planned = [s for s in STAGE_WEIGHTS]
        self._done_weight = 0.0
        self.running_stage = ""   # the stage whose call is in flight ('' between calls)
        self._last_progress: tuple[str, str] = ("", "")

    def up_hint(self, error: Exception) -> str:
        """What to add to a failure a wrong up axis would explain (a stage after the alignment found no
        floor, surface, region or perch) when the up axis was estimated from the mesh: it and --up."""
        stage = getattr(error, "stage", None)
        found_nothing = stage in UP_SENSITIVE_STAGES if stage else isinstance(error, ValueError) and \
            "filter" in self.stage_names
        note = self.alignment.up_estimated if found_nothing else ""
        return f"; {note}" if note else ""

    def clean_hint(self) -> str:
        """What to add to a failure: the clean stage's warnings (a mesh falling apart into fragments
        explains a segmentation or filter that found little)."""
        return "; the clean stage warned: " + "; ".join(self.clean_warnings) if self.clean_warnings else ""

    def _call(self, stage: str, request):
        self.feedback(stage, self._fraction(), f"running {stage}")
        self.running_stage = stage
        try:
            # Reconstruction's frame counters (perch/reconstruct/progress) say more than its feedback.
            progress = None if stage == "reconstruct" else self.stage_progress
            reply = self.caller.call(stage, request, self.cancelled, progress)
        finally:
            self.running_stage = ""
        self._finish(stage, float(reply.seconds))
        return reply

    def stage_progress(self, stage: str, within: float, message: str) -> None:
        """Feedback from inside the running stage (reconstruction frames; segment, filter and optimise
        phases from their actions' feedback): the mission's fraction moves by the stage's share, and
        `stage_fraction` says how far the stage is. Ignored for any stage but the running one."""
        if stage != self.running_stage or (stage, message) == self._last_progress:
            return   # the progress topic repeats itself every period; feedback only says what changed
        self._last_progress = (stage, message)
        within = min(1.0, max(0.0, float(within)))
        total = sum(STAGE_WEIGHTS[s] for s in self._planned)
        self.feedback(stage, min(1.0, (self._done_weight + STAGE_WEIGHTS[stage] * within) / total), message, within)

    def _fraction(self) -> float:
        total = sum(STAGE_WEIGHTS[s] for s in self._planned)
        return min(1.0, self._done_weight / total)

    def _finish(self, stage: str, seconds: float) -> None:
        self.stage_names.append(stage)
        self.stage_seconds.append(seconds)
        self._done_weight += STAGE_WEIGHTS[stage]

    def run(self, goal: PlanPerches.Goal) -> PlanPerches.Result:
        """Run the goal through every stage and the operator's decisions; the action's result, in the input's own frame."""
        started = time.monotonic()
        try:   # the very checks every stage request gets (perch_common.request_validation)
            validate_request(goal)
        except ValueError as exc:
            raise ValueError(f"invalid goal: {exc}") from None
        mesh_msg = self._acquire_mesh(goal)
        if self.on_alignment is not None:
            self.on_alignment(self.alignment)
        # The stages work in the gravity-aligned frame; boxes and target come in the input's frame.
        crop = self._call("crop", srv.Crop.Request(
            mesh=mesh_msg, keep_boxes=boxes_to_aligned(goal.keep_boxes, self.alignment),
            remove_boxes=boxes_to_aligned(goal.remove_boxes, self.alignment),
            target=target_to_aligned(goal.target, self.alignment)))
        segment = self._call("segment", srv.Segment.Request(mesh=crop.mesh))
        surfaces = self._reviewed(list(segment.surfaces), goal.review_surfaces, crop.mesh)
        filtered = self._call("filter", srv.Filter.Request(mesh=crop.mesh, surfaces=surfaces,
                                                           target=crop.target, up=vector_msg(self.options.up)))
        if not filtered.regions:
            raise ValueError(f"filter left no perch regions on {len(segment.surfaces)} surface(s); nothing to "
                             f"optimise. Area removed by each filter: {removal_summary(filtered.removals)}")
        request = srv.Optimise.Request(
            mesh=mesh_msg if self.options.optimise_on_full_mesh else crop.mesh, regions=filtered.regions,
            target=crop.target, num_cameras=goal.num_cameras, method="", seed=goal.seed)
        optimised = self._call("optimise", request)
        if not optimised.placements:
            raise ValueError(f"optimise placed no camera: {optimised.message}")
        if not optimised.message.startswith("placed "):  # the reply opens with its shortfall sentence
            self.notes.append(optimised.message.split(". placed ")[0])
        operator = Operator(ProposalBook(self.options.exclusion_radius, self.first_proposal_id), request,
                            self.options.auto_accept or goal.auto_accept, self.alignment,
                            (optimised.fitness, optimised.coverage, optimised.mean_uncertainty),
                            surfaces=classed_surfaces(surfaces, filtered.removals), removals=list(filtered.removals),
                            unit_unconfirmed=self.unit_unconfirmed)
        operator.robustness = optimised
        self.on_operator(operator)
        confirmed = self._confirm(operator, optimised.placements)
        self._finish("confirm", confirmed)
        result = self._result(operator)
        result.stage_names.append("total")
        result.stage_seconds.append(time.monotonic() - started)
        return result

    def _acquire_mesh(self, goal: PlanPerches.Goal):
        given = [bool(goal.mesh_path), bool(goal.bag_path), len(goal.mesh.triangles) > 0]
        if sum(given) != 1:
            raise ValueError("a mission needs exactly one of mesh_path, bag_path or mesh "
                             f"(got {sum(given)})")
        if goal.bag_path:
            self._planned.remove("clean")
            try:
                reply = self._call("reconstruct", srv.Reconstruct.Request(bag_path=goal.bag_path, use_poses=True))
            except StageError as exc:
                if "use_poses=false" not in str(exc):
                    raise
                # The bag records no poses: track the camera instead (RGB-D odometry).
                self.feedback("reconstruct", self._fraction(), "no poses in the bag: reconstructing with odometry")
                reply = self._call("reconstruct", srv.Reconstruct.Request(bag_path=goal.bag_path, use_poses=False))
            if "damaged bag" in reply.message:   # what the bag lost: in the result and on the terminal, not only the log
                self.notes.append(reply.message[reply.message.index("damaged bag"):])
                self.feedback("reconstruct", self._fraction(), self.notes[-1])
            # The reconstruction is gravity-aligned; outputs go back to the frame of the bag's poses.
            self.alignment = alignment_from_msg(reply.alignment, reply.up_source, reply.up_confidence)
            return reply.mesh
        self._planned.remove("reconstruct")
        mesh_msg = goal.mesh if len(goal.mesh.triangles) else mesh_to_msg(goal_mesh_file(goal.mesh_path))
        if not mesh_msg.header.frame_id:
            mesh_msg.header.frame_id = self.options.frame_id
        given = mesh_from_msg(mesh_msg, "mission mesh")   # decoded once: for the up axis and to align it
        self.alignment = self._given_mesh_alignment(goal, mesh_msg.header.frame_id, given)
        aligned = given.transformed(self.alignment.to_aligned())
        _refuse_target_outside(goal.target, given, aligned, self.alignment)
        if self.on_input_frame is not None:
            self.on_input_frame(self.alignment.input_frame)
        aligned.frame_id = self.alignment.aligned_frame
        aligned_msg = mesh_to_msg(aligned, stamp=mesh_msg.header.stamp)
        if not self.options.clean_given_mesh:
            self._planned.remove("clean")
            return aligned_msg
        # Cleaned after aligning: its vertex welding then works in the room's own frame, so the same
        # room in any orientation is cleaned alike. Its (near-identity) correction joins the alignment.
        reply = self._call("clean", srv.CleanMesh.Request(mesh=aligned_msg, gravity=vector_msg([0.0, 0.0, -1.0])))
        # Its warnings (a mesh falling apart into fragments, repairs) may explain a "nothing found".
        self.clean_warnings = list(reply.warnings)
        correction = alignment_from_msg(reply.alignment).rotation
        self.alignment = Alignment(self.alignment.input_frame, correction @ self.alignment.rotation,
                                   self.alignment.up_source, self.alignment.up_confidence)
        return reply.mesh

    def _given_mesh_alignment(self, goal: PlanPerches.Goal, frame_id: str, mesh) -> Alignment:
        """Up from the goal's up_axis (or the node's input_up): estimated, given, or the file's convention.

        A given axis the mesh contradicts fails the mission (UpAxisError) with the axis to pass instead.
        """
        text = goal.up_axis or self.options.input_up
        convention = goal.up_convention or file_convention(goal.mesh_path or None)
        # Auto-accepted, nobody checks the up axis: an unsure estimate stops the mission (UnsureUpError).
        auto_accept = self.options.auto_accept or goal.auto_accept
        choice = choose_up(text, mesh, convention, require_confident=auto_accept)
        feet = feet_problem(mesh, choice.up, "the mesh")
        if feet and auto_accept:   # a guess at the unit, as at the up axis: nobody reviews the result
            raise MeshError(f"{feet}. An auto-accepted mission does not place drones in a guessed unit: pass "
                            "--scale 0.3048 if it is in feet, or run without --auto-accept to review every proposal")
        self.unit_unconfirmed = f"unit unconfirmed: {feet}" if feet else ""
        for warning in choice.warnings + ([self.unit_unconfirmed] if feet else []):
            self.notes.append(warning)
            self.feedback("clean", self._fraction(), warning)
        return Alignment(frame_id, choice.estimate.aligned_rotation(choice.up), choice.source,
                         choice.estimate.confidence)

    def _reviewed(self, surfaces: list, count: int, mesh_msg) -> list:
        """With count > 0, the operator reviews the `count` largest surfaces; rejected ones are dropped,
        cropped ones trimmed to their box (given in the input's frame) on `mesh_msg`, the mesh they were
        segmented from."""
        if count <= 0 or not surfaces:
            return surfaces
        if self.review is None:
            raise ValueError("this coordinator cannot run surface reviews")
        started = time.monotonic()
        largest = sorted(surfaces, key=lambda s: -s.area)[:count]

        def opened(review_id: int) -> None:   # the feedback names the review the operator is to decide
            self.feedback("review", self._fraction(), f"waiting for surface review {review_id} of surfaces "
                          f"{[s.id for s in largest]} (perch operator review {review_id} [--reject ...])")

        decision = self.review([surface_to_input(s, self.alignment) for s in largest], opened)  # the input's frame
        if not isinstance(decision, ReviewDecision):   # a plain set: the rejected ids
            decision = ReviewDecision(set(decision))
        if decision.crops:
            surfaces = cropped_surfaces(surfaces, decision.crops, mesh_from_request(mesh_msg, "segmented mesh"),
                                        self.alignment.to_aligned())
        self._finish("review", time.monotonic() - started)
        return [s for s in surfaces if s.id not in decision.rejected]

    def _confirm(self, operator: Operator, placements) -> float:
        """Propose every placement and wait until each slot is accepted; returns the seconds spent."""
        started = time.monotonic()
        self.feedback("confirm", self._fraction(), f"proposing {len(placements)} perch(es)"
                      + (" (auto_accept)" if operator.auto_accept else ""))
        events = []
        for slot, placement in enumerate(placements):
            proposal = operator.book.propose(slot, placement_from_msg(placement))
            proposal.reason = operator.caution()   # '' unless the up axis is a fallback or the unit in doubt
            events.append(copy.copy(proposal))   # as proposed: deciding changes the book's own
            if operator.auto_accept:
                events.append(operator.book.decide(proposal.id, Decision.ACCEPT, "auto_accept policy"))
        # Together: a viewer's picture (markers, accepted poses, the mission's waypoint set) is
        # published once for the whole set instead of after each of its events.
        self.on_proposal(*events)
        timeout = self.options.confirm_timeout
        # Feedback only when the open proposals change, or every few seconds: a steady 4 Hz stream
        # tells a waiting client nothing new and crowds its short feedback queue.
        last_open, last_sent = None, 0.0
        while not operator.book.wait_settled(0.25):
            waited = time.monotonic() - started
            if self.cancelled():
                raise MissionCancelled("mission cancelled while waiting for operator decisions")
            if timeout > 0 and waited > timeout:
                raise TimeoutError(f"no operator decision on proposal(s) {self._open_ids(operator)} within "
                                   f"{timeout:g} s (parameter confirm_timeout)")
            open_ids = self._open_ids(operator)
            if open_ids != last_open or time.monotonic() - last_sent > WAITING_FEEDBACK_PERIOD:
                self.feedback("confirm", self._fraction(),
                              f"waiting for decisions on proposal(s) {open_ids} (perch operator accept|reject ID)")
                last_open, last_sent = open_ids, time.monotonic()
        return time.monotonic() - started

    @staticmethod
    def _open_ids(operator: Operator) -> list[int]:
        return [p.id for p in operator.book.current() if p.slot in operator.book.open_slots()]

    def _result(self, operator: Operator) -> PlanPerches.Result:
        accepted = operator.book.accepted()
        result = PlanPerches.Result(success=True, stage_names=list(self.stage_names),
                                    stage_seconds=list(self.stage_seconds))
        result.placements = [placement_msg(p, operator.alignment) for p in accepted]
        result.alignment = alignment_to_msg(operator.alignment)
        result.fitness, result.coverage, result.mean_uncertainty = operator.scores
        for name in ROBUSTNESS_FIELDS if operator.robustness is not None else ():
            setattr(result, name, float(getattr(operator.robustness, name)))
        result.message = f"{len(accepted)} perch(es) accepted" + "".join(f"; {n}" for n in self.notes)
        return result


def removal_summary(removals) -> str:
    """'orientation 12.3 m^2, recovery_height 4.0 m^2, ...' over all surfaces (non-zero filters only)."""
    totals = {n: sum(float(getattr(r, n)) for r in removals) for n in FILTER_NAMES}
    text = ", ".join(f"{n} {a:.1f} m^2" for n, a in totals.items() if a > 0)
    return text or "none (no surfaces reached the filter)"


def replan_slot(caller: StageCaller, operator: Operator, slot: int) -> Proposal | None:
    """Re-optimise one camera slot keeping every other slot's placement; None when nothing fits."""
    base = operator.optimise_request
    request = srv.Optimise.Request(
        mesh=base.mesh, regions=base.regions, target=base.target, camera=base.camera, drone=base.drone,
        num_cameras=1, method=base.method, seed=base.seed,
        fixed=[placement_to_msg(p) for p in operator.book.fixed_for(slot)],
        exclusions=[exclusion_to_msg(z) for z in operator.book.exclusions()])
    started = time.monotonic()
    reply = caller.call("optimise", request)
    operator.replan_seconds.append(time.monotonic() - started)
    if not reply.placements:
        operator.book.leave_empty(slot)
        return None
    operator.scores = (reply.fitness, reply.coverage, reply.mean_uncertainty)
    operator.robustness = reply
    proposal = operator.book.propose(slot, placement_from_msg(reply.placements[0]))
    proposal.reason = operator.caution()   # '' unless the up axis is a fallback or the unit in doubt
    return proposal


@dataclass
class DecisionOutcome:
    """A recorded operator decision and, for a rejected or failed perch, its replacement."""

    decided: Proposal
    replacement: Proposal | None
    message: str


def decide(caller: StageCaller, operator: Operator | None, proposal_id: int, decision: Decision, reason: str,
           publish: Callable[[Proposal], None]) -> DecisionOutcome:
    """Record a decision on a proposal; a rejected or failed perch is re-planned at once, and the
    replacement accepted when the mission runs under the auto_accept policy. Every changed proposal
    goes to `publish`. Raises ProposalError for an unknown or already decided proposal."""
    if operator is None:
        raise ProposalError("no mission has proposed anything yet")
    decided = operator.book.decide(proposal_id, decision, reason)
    publish(decided)
    message = f"proposal {decided.id} {decided.status.name.lower()}"
    if decided.status == Status.ACCEPTED:
        return DecisionOutcome(decided, None, message)
    replacement = replan_slot(caller, operator, decided.slot)
    if replacement is None:
        return DecisionOutcome(decided, None, message + "; no alternative perch found, the slot stays empty")
    publish(replacement)
    if operator.auto_accept:
        replacement = operator.book.decide(replacement.id, Decision.ACCEPT, "auto_accept policy")
        publish(replacement)
    message += (f"; replacement proposal {replacement.id} for drone {replacement.slot} "
                f"in {operator.replan_seconds[-1]:.2f} s")
    return DecisionOutcome(decided, replacement, message)
