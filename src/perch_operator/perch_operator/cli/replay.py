"""`perch replay RUN.mcap [--check]`: re-send a recorded mission's stage requests to a live graph.

With --check, each live reply is compared with the recorded one (numbers within tolerance,
everything else equal); any difference is printed and makes the check fail. This is how a
changed parameter or a regression in a stage shows up.

A damaged recording (a recorder killed, a corrupt chunk) is replayed as far as it goes, and the
replay says what it could not check: calls lost with the damaged part (counted from the rosbag2
record when the file has one), and requests whose reply was lost are reported as unchecked, not as
differences. A check of a damaged recording never ends in a plain "passed".
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

from perch_common.errors import PerchError
from perch_operator.cli.diff import Tolerance, diff_messages
from perch_operator.coordinator.stages import STAGES
from perch_operator.outputs.runfile import StageCall, resolve_mesh_ids, stage_calls


@dataclass
class CallOutcome:
    """One replayed stage call: its reply, the time it took and how it differs from the recording."""

    call: StageCall
    index: int
    seconds: float
    differences: list[str] = field(default_factory=list)
    error: str = ""
    unchecked: str = ""   # why the reply could not be compared (its recorded reply lost to damage)

    @property
    def ok(self) -> bool:
        """Whether the call succeeded and matched the recording (or could not be compared: see unchecked)."""
        return not self.error and not self.differences


@dataclass
class RecordingDamage:
    """What a damaged recording lost, for the replay's verdict."""

    text: str                          # scan_mcap(...).damage()
    lost_calls: dict[str, int] | None  # stage -> calls lost (None: unknown, the recording was never closed)

    def lost_line(self) -> str:
        """The stage calls lost, in words."""
        if self.lost_calls is None:
            return "an unknown number of stage calls may be lost with the damaged part (the recording was never closed)"
        if not self.lost_calls:
            return "no stage call was lost"
        listed = ", ".join(f"{stage} x{n}" if n > 1 else stage for stage, n in self.lost_calls.items())
        return f"{sum(self.lost_calls.values())} stage call(s) lost to the damage ({listed})"


class ReplayOutcomes(list):
    """The replayed calls (CallOutcome), and what a damaged recording lost (None when intact)."""

    damage: RecordingDamage | None = None


def recording_damage(path: str | Path, calls: list[StageCall]) -> RecordingDamage | None:
    """What `path` lost to damage, or None when it is intact; `calls` are those read from it."""
    from perch_common.mcap_read import scan_mcap
    from perch_common.ros.bag_format import lost_message_counts
    from perch_operator.outputs.recorder import EVENT_SUFFIX
    from perch_operator.outputs.runfile import SERVICE_TO_STAGE

    scan = scan_mcap(path)
    if not scan.damage():
        return None
    lost_events = lost_message_counts(scan)
    lost_calls = None
    if lost_events is not None:
        # A call is recorded as a request event and a reply event: the events lost beyond the replies of
        # the calls read without one are whole calls lost.
        lost_calls = {}
        for service, stage in SERVICE_TO_STAGE.items():
            replyless = sum(1 for c in calls if c.stage == stage and c.request is not None and c.response is None)
            whole = -(-(lost_events.get("/" + service + EVENT_SUFFIX, 0) - replyless) // 2)
            if whole > 0:
                lost_calls[stage] = whole
    return RecordingDamage(scan.damage(), lost_calls)


def replay(node, path: str | Path, check: bool = True, tol: Tolerance = Tolerance(),
           stages: list[str] | None = None, timeout: float = 300.0, wait: float = 10.0,
           out=None) -> list[CallOutcome]:
    """Re-send every recorded stage request (in order) and compare the replies when `check`."""
    from perch_common.ros.testing import call_service

    out = out or sys.stdout
    recorded = stage_calls(path)
    damage = recording_damage(path, recorded) if Path(path).is_file() else None
    if damage:   # a recording cut short (its recorder killed) or with corrupt chunks: replay what is there
        if damage.lost_calls and stages is not None:
            damage.lost_calls = {s: n for s, n in damage.lost_calls.items() if s in stages}
        out.write(f"perch: warning: damaged recording, replaying what could be read: {damage.text}; "
                  f"{damage.lost_line()}\n")
    calls = [c for c in recorded if c.request is not None and (stages is None or c.stage in stages)
             and not _mesh_resend(c)]
    if not calls and damage and damage.lost_calls != {}:
        # The damage comes first: the introspection hint below would point at the wrong cause.
        raise PerchError(f"{damage.text}: no stage request survived the damage, so nothing to replay (a recorder "
                         "killed with SIGKILL loses the chunk it had open)")
    if not calls:
        raise PerchError(f"{path}: no stage requests recorded (were the stage services' introspection "
                         "parameters on when it was recorded?)")
    outcomes = ReplayOutcomes()
    outcomes.damage = damage
    seen: dict[str, int] = {}
    for call in calls:
        seen[call.stage] = seen.get(call.stage, 0) + 1
        started = time.monotonic()
        outcome = CallOutcome(call, seen[call.stage], 0.0)
        call.request.request_id = ""   # the recorded call's id is that mission's, not this replay's
        try:
            reply = call_service(node, STAGES[call.stage].srv_type, call.service, call.request,
                                 timeout=timeout, wait=wait)
        except TimeoutError as exc:
            outcome.error = f"{exc} (is the graph running? `perch launch`)"
            reply = None
        outcome.seconds = time.monotonic() - started
        if reply is not None:   # a reply naming the request's mesh by id compares as that mesh
            resolve_mesh_ids([StageCall(call.stage, call.service, call.request, reply)])
        if reply is not None and check:
            if call.response is None and damage:
                outcome.unchecked = ("its reply is not in the damaged recording (lost with the damaged part, "
                                     "or cut off before it was sent): not compared")
            elif call.response is None:
                outcome.error = "no recorded reply to compare with"
            else:
                outcome.differences = diff_messages(call.response, reply, tol)
        outcomes.append(outcome)
        _print_outcome(outcome, check, out)
    return outcomes


def _mesh_resend(call: StageCall) -> bool:
    """A call answered "mesh not cached" (the coordinator sent the arrays next): nothing to replay."""
    from perch_common.mesh_cache import is_mesh_not_cached

    return call.response is not None and not call.response.success and is_mesh_not_cached(call.response.message)


def _print_outcome(o: CallOutcome, check: bool, out) -> None:
    recorded = getattr(o.call.response, "seconds", float("nan")) if o.call.response is not None else float("nan")
    name = f"{o.call.stage} #{o.index}"
    if o.error:
        out.write(f"FAIL  {name:<14} {o.error}\n")
    elif o.unchecked:
        out.write(f"LOST  {name:<14} replied in {o.seconds:.2f} s; {o.unchecked}\n")
    elif not check:
        out.write(f"sent  {name:<14} {o.seconds:6.2f} s (recorded {recorded:.2f} s)\n")
    elif o.ok:
        out.write(f"ok    {name:<14} reply matches the recording ({o.seconds:.2f} s, recorded {recorded:.2f} s)\n")
    else:
        out.write(f"DIFF  {name:<14} {len(o.differences)} difference(s) from the recording:\n")
        for line in o.differences:
            out.write(f"        {line}\n")
    out.flush()


def summary_line(outcomes: list[CallOutcome], check: bool) -> str:
    """One line summing up a replay (and its comparison when checked)."""
    bad = [o for o in outcomes if not o.ok]
    damage = getattr(outcomes, "damage", None)
    if not check:
        return f"replayed {len(outcomes)} stage call(s)" + (f"; {damage.lost_line()}" if damage else "")
    unchecked = [o for o in outcomes if o.ok and o.unchecked]
    matched = len(outcomes) - len(bad) - len(unchecked)
    if bad:
        names = ", ".join(f"{o.call.stage} #{o.index}" for o in bad)
        line = f"replay check FAILED: {len(bad)} of {len(outcomes)} stage call(s) differ or failed ({names})"
        return line + (f"; the recording is damaged: {damage.lost_line()}" if damage else "")
    if not damage or (damage.lost_calls == {} and not unchecked):   # e.g. only the index lost: all was checked
        told = f" (damaged recording: {damage.lost_line()})" if damage else ""
        return f"replay check passed: {len(outcomes)} stage call(s) match the recording{told}"
    # Not a plain pass: what the damage took could not be checked.
    told = f"replay check INCOMPLETE, damaged recording: passed for the {matched} stage call(s) that survived"
    if unchecked:
        names = ", ".join(f"{o.call.stage} #{o.index}" for o in unchecked)
        told += f"; {len(unchecked)} not compared, their recorded replies lost ({names})"
    return f"{told}; {damage.lost_line()}: those were not checked"
