"""`perch operator accept|reject|failed|cancel|list`, `perch replay RUN.mcap [--check]`, `perch view RUN.rrd`,
`perch record OUT.mcap`, `perch dispatch`."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from perch_common.cli_types import positive_float
from perch_common.conventions import CONFIRM_SERVICE, MISSION_STATUS_TOPIC
from perch_common.errors import PerchError
from perch_operator.outputs.text import evidence_text


def register(sub) -> None:
    """Add `perch operator`: decide on the running mission's proposals and surface reviews."""
    p = sub.add_parser("operator", help="decide on proposed perches of the running mission")
    actions = p.add_subparsers(dest="operator_action", metavar="ACTION")
    for name, help_text in (("accept", "accept a proposal"), ("reject", "reject a proposal (re-plans that drone)"),
                            ("failed", "report an accepted perch that failed in flight (re-plans it)")):
        a = actions.add_parser(name, help=help_text)
        a.add_argument("id", type=message_id, help="proposal id (see `perch operator list`)")
        a.add_argument("--reason", type=reason_text, default="",
                       help=f"why (recorded with the decision; one line, at most {MAX_REASON} characters)")
        a.set_defaults(func=_decide, decision=name)
    review = actions.add_parser("review", help="decide a surface review (missions with --review-surfaces N)")
    review.add_argument("id", type=message_id, help="review id (published on /perch/surface_review)")
    review.add_argument("--reject", default="", help="comma-separated surface ids to reject; none: approve all")
    review.add_argument("--reason", type=reason_text, default="",
                        help=f"why (one line, at most {MAX_REASON} characters)")
    review.add_argument("--crop", action="append", default=[], metavar="ID:CX,CY,CZ,SX,SY,SZ[,YAW_DEG]",
                        help="approve surface ID trimmed to the part inside this box (input frame, metres; "
                             "faces with their centroid inside are kept); repeat for several surfaces")
    review.set_defaults(func=_review)
    cancel = actions.add_parser("cancel", help="cancel the running mission (e.g. one whose client is stuck)")
    cancel.add_argument("--timeout", type=positive_float, default=10.0, help="seconds to wait for the coordinator")
    cancel.set_defaults(func=_cancel)
    lst = actions.add_parser("list", help="show the proposals of the current mission (those `accept`, `reject` "
                                          "and `failed` act on)")
    lst.add_argument("--wait", type=positive_float, default=2.0,
                     help="seconds to find the coordinator and collect the proposals")
    lst.set_defaults(func=_list)
    p.set_defaults(func=lambda args: p.print_help() or 2)


MAX_REASON = 500   # characters of a decision's --reason: a sentence or two, not a document
_LINE_BREAKING = {"\u2028", "\u2029", "\u202a", "\u202b", "\u202c", "\u202d", "\u202e",
                  "\u2066", "\u2067", "\u2068", "\u2069"}   # line/paragraph separators, bidi overrides


def reason_text(text: str) -> str:
    """A decision's reason (argparse type): one line of at most MAX_REASON characters, no control
    characters (a newline or a terminal escape would garble every `perch operator list`)."""
    import argparse
    import unicodedata

    bad = next((c for c in text if unicodedata.category(c) == "Cc" or c in _LINE_BREAKING), None)
    if bad is not None:
        raise argparse.ArgumentTypeError(f"holds the control character {bad!r}; give the reason as one line of "
                                         "plain text (no newlines, tabs or terminal escapes)")
    if len(text) > MAX_REASON:
        raise argparse.ArgumentTypeError(f"is {len(text)} characters long; give at most {MAX_REASON} "
                                         "(a sentence or two)")
    return text


def message_id(text: str) -> int:
    """A proposal or review id (argparse type): a whole number 0 .. 2^32-1, as the messages carry."""
    import argparse

    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number; give the id `perch operator list` "
                                         "shows") from None
    if not 0 <= value < 2 ** 32:
        raise argparse.ArgumentTypeError(f"{text} is out of range; ids are whole numbers from 0 to {2 ** 32 - 1}")
    return value


def printable(text: str, limit: int | None = None) -> str:
    """Text received from the graph, safe for a terminal line: control characters (newlines, ANSI
    escapes, bidi overrides) shown escaped (\\n, \\x1b, \\u202e), and cut after `limit` characters."""
    shown = text if limit is None or len(text) <= limit else text[:limit]
    safe = "".join(c if c.isprintable() else c.encode("unicode_escape").decode("ascii") for c in shown)
    return safe + (f"... ({len(text) - limit} more characters)" if shown is not text else "")


def _with_node(name: str, body):
    import rclpy

    from perch_operator.cli.runner import client_context

    with client_context():
        return body(rclpy.create_node(name))


def _decide(args) -> int:
    from perch_interfaces.srv import Confirm

    code = {"accept": Confirm.Request.ACCEPT, "reject": Confirm.Request.REJECT,
            "failed": Confirm.Request.FAILED_IN_FLIGHT}[args.decision]
    from perch_common.network_auth import sign_if_networked

    request = Confirm.Request(proposal_id=args.id, decision=code, reason=args.reason)
    if hasattr(request, "auth"):   # a networked graph takes decisions signed with its key only
        request.auth = sign_if_networked("confirm", request.proposal_id, request.decision, request.reason)
    reply = _call_and_report(Confirm, CONFIRM_SERVICE, request, timeout=60)
    if reply.replacement.id:
        print(_proposal_line(reply.replacement))
    return 0


def _review(args) -> int:
    from perch_interfaces.srv import ReviewSurfaces

    try:
        rejected = [int(t) for t in args.reject.replace(" ", "").split(",") if t]
    except ValueError:
        raise PerchError(f"--reject '{args.reject}': give surface ids like 3,5") from None
    request = ReviewSurfaces.Request(review_id=args.id, rejected_surface_ids=rejected, reason=args.reason)
    for spec in args.crop:
        surface_id, box = parse_crop(spec)
        request.cropped_surface_ids.append(surface_id)
        request.crop_boxes.append(box)
    _call_and_report(ReviewSurfaces, "perch/review_surfaces", request, timeout=30)
    return 0


def parse_crop(spec: str):
    """(surface id, OrientedBox) of a `--crop ID:CX,CY,CZ,SX,SY,SZ[,YAW_DEG]` (yaw about z, degrees)."""
    import math

    import numpy as np

    from perch_common.ros.conversions import pose_msg, vector_msg
    from perch_interfaces import msg as pm

    head, _, numbers = spec.partition(":")
    try:
        surface_id = int(head)
        values = [float(v) for v in numbers.split(",")]
    except ValueError:
        raise PerchError(f"--crop '{spec}': give ID:CX,CY,CZ,SX,SY,SZ[,YAW_DEG], e.g. 3:1.0,0.0,1.2,2.0,0.3,1.5") \
            from None
    if len(values) not in (6, 7) or min(values[3:6]) <= 0 or not all(map(math.isfinite, values)):
        raise PerchError(f"--crop '{spec}': give the centre, three positive sizes and optionally a yaw "
                         "(ID:CX,CY,CZ,SX,SY,SZ[,YAW_DEG])")
    yaw = math.radians(values[6]) if len(values) == 7 else 0.0
    pose = np.eye(4)
    pose[:3, :3] = [[math.cos(yaw), -math.sin(yaw), 0], [math.sin(yaw), math.cos(yaw), 0], [0, 0, 1]]
    pose[:3, 3] = values[:3]
    return surface_id, pm.OrientedBox(pose=pose_msg(pose), size=vector_msg(values[3:6]))


def _cancel(args) -> int:
    """Cancel every running mission through the action's standard cancel service (zero goal id: all);
    under --network (PERCH_NETWORK=1) with the signed cancel of each mission the coordinator lists."""
    from action_msgs.srv import CancelGoal

    from perch_common.network_auth import networked

    if networked():   # the coordinator refuses the standard cancel: it carries no token
        return _with_node("perch_operator_cancel", lambda node: _cancel_signed(node, args.timeout))

    from perch_common.ros.testing import call_service
    from perch_operator.api.client import ACTION

    def body(node) -> int:
        try:
            reply = call_service(node, CancelGoal, f"{ACTION}/_action/cancel_goal", CancelGoal.Request(),
                                 timeout=args.timeout, wait=args.timeout)
        except TimeoutError as exc:
            raise PerchError(f"{exc}; is the graph running (`perch launch`)?") from None
        if reply.return_code == CancelGoal.Response.ERROR_NONE and reply.goals_canceling:
            print(f"cancelling {len(reply.goals_canceling)} mission(s); the coordinator stops the stage "
                  "work in progress and is free for the next goal")
            return 0
        if reply.return_code in (CancelGoal.Response.ERROR_NONE, CancelGoal.Response.ERROR_UNKNOWN_GOAL_ID):
            print("no mission is running")
            return 0
        raise PerchError(f"the coordinator refused to cancel (return code {reply.return_code})")

    return _with_node("perch_operator_cancel", body)


STATUS_SETTLE = 2.0   # s after the coordinator is listed for its latched goal list to arrive (none: no goal yet)


def _cancel_signed(node, timeout: float) -> int:
    """The networked graph's cancel: the coordinator's goal list (latched) names the running missions,
    and each gets the signed cancel (perch_operator.api.client.MissionCanceller)."""
    import rclpy
    from action_msgs.msg import GoalStatus
    from unique_identifier_msgs.msg import UUID

    from perch_operator.api.client import GoalStatusWatch, MissionCanceller

    statuses, signed = GoalStatusWatch(node), MissionCanceller(node)
    try:
        deadline, listed = time.monotonic() + timeout, None
        while not statuses.status and (listed is None or time.monotonic() - listed < STATUS_SETTLE):
            if time.monotonic() > deadline:
                raise PerchError(f"no mission coordinator answered within {timeout:g} s; is the graph running "
                                 "(`perch launch --network`), and is this host on its network?")
            if listed is None and GoalStatusWatch.writers_of(node):
                listed = time.monotonic()
            rclpy.spin_once(node, timeout_sec=0.1)
        running = [goal for goal, status in statuses.status.items()
                   if status in (GoalStatus.STATUS_ACCEPTED, GoalStatus.STATUS_EXECUTING)]
        if not running:
            print("no mission is running")
            return 0
        for goal in running:
            if not signed.cancel(UUID(uuid=list(goal)), "perch operator cancel", lambda g=goal: statuses.status[g],
                                 wait=timeout):
                raise PerchError(f"the coordinator did not take the signed cancel of mission {goal.hex()} within "
                                 f"{timeout:g} s: its log says why (another key than PERCH_KEY_FILE's, clocks "
                                 "further apart than the token window)")
        print(f"cancelling {len(running)} mission(s) (signed); the coordinator stops the stage work in "
              "progress and is free for the next goal")
        return 0
    finally:
        signed.destroy()
        statuses.destroy()


def _call_and_report(srv_type, name: str, request, timeout: float):
    """Call an operator service of the running graph, print its message and return the reply.

    No graph or a refused request becomes a PerchError (the CLI's clear-error path)."""
    from perch_common.ros.testing import call_service

    def body(node):
        try:
            reply = call_service(node, srv_type, name, request, timeout=timeout, wait=10)
        except TimeoutError as exc:
            raise PerchError(f"{exc}; is the graph running (`perch launch`)?") from None
        if not reply.success:
            raise PerchError(printable(reply.message))
        print(printable(reply.message))
        return reply

    return _with_node("perch_operator_cli", body)


def _proposal_line(p) -> str:
    from perch_operator.coordinator.proposals import Status

    pos = p.placement.drone_pose.position
    return (f"proposal {p.id:>4}  drone {p.placement.drone_index}  {Status(p.status).name.lower():<8} "
            f"at ({pos.x:.2f}, {pos.y:.2f}, {pos.z:.2f}) m  gain {p.placement.marginal_gain:.4f}  "
            f"{evidence_text(p.evidence)}" + (f"  ({printable(p.reason, MAX_REASON)})" if p.reason else ""))


_STATES = {1: "running", 2: "running", 3: "cancelling", 4: "succeeded", 5: "cancelled", 6: "failed"}  # GoalStatus


def _list(args) -> int:
    """The current mission's proposals: what `accept`, `reject` and `failed` act on.

    perch/proposals keeps a history (transient local, 100 deep) of every mission's proposals, each
    tagged with its mission's goal id: the current mission is the one the coordinator's latched
    waypoint set names (else its latest goal), and its state comes from the goal status list. No
    coordinator within --wait s is an error, as for `accept`."""
    from action_msgs.msg import GoalStatusArray
    from rclpy.qos import qos_profile_action_status_default

    from perch_interfaces.msg import PerchWaypointSet, Proposal
    from perch_operator.api.client import GoalStatusWatch
    from perch_operator.cli.runner import spin_for
    from perch_operator.coordinator.node import LATCHED, LATCHED_LAST

    def body(node) -> int:
        latest: dict[int, Proposal] = {}
        goals: dict[bytes, tuple[int, int]] = {}    # goal id -> (accepted at, ns; status)
        sets: list[PerchWaypointSet] = []

        def on_status(msg) -> None:
            goals.clear()
            goals.update({bytes(s.goal_info.goal_id.uuid): (s.goal_info.stamp.sec * 10 ** 9 + s.goal_info.stamp.nanosec,
                                                            s.status) for s in msg.status_list})

        node.create_subscription(Proposal, "perch/proposals", lambda m: latest.__setitem__(m.id, m), LATCHED)
        node.create_subscription(GoalStatusArray, MISSION_STATUS_TOPIC, on_status, qos_profile_action_status_default)
        node.create_subscription(PerchWaypointSet, "perch/mission_waypoints", sets.append, LATCHED_LAST)
        deadline, seen = time.monotonic() + args.wait, False
        while time.monotonic() < deadline:
            seen = seen or bool(GoalStatusWatch.writers_of(node))
            spin_for(node, min(0.1, max(0.0, deadline - time.monotonic())))
        if not seen:
            raise PerchError(f"no mission coordinator in the graph within {args.wait:g} s (nothing serves "
                             f"{node.resolve_topic_name(MISSION_STATUS_TOPIC)}); is the graph running "
                             "(`perch launch`)? On a slow network give it longer (--wait)")
        mission = bytes(sets[-1].mission_id.uuid) if sets and any(sets[-1].mission_id.uuid) else \
            max(goals, key=lambda g: goals[g][0], default=None)
        if mission is None:
            print("no proposals: no mission has run on this graph yet (`perch plan ... --no-launch`)")
            return 0
        name = mission.hex()   # as the dispatcher and the waypoint files show it
        state = _STATES.get(goals[mission][1], "unknown") if mission in goals else "ended"
        shown = [latest[i] for i in sorted(latest) if bytes(latest[i].mission_id.uuid) == mission]
        if state in ("cancelled", "failed", "cancelling"):
            print(f"no proposals to decide: mission {name} {'is being cancelled' if state == 'cancelling' else state}; "
                  "decisions on its proposals are refused (they were never dispatched); run a new mission")
            return 0
        if not shown:
            print(f"no proposals yet: mission {name} is {state}" + (
                  " (it proposes perches once its optimise stage has run)" if state == "running" else ""))
            return 0
        print(f"mission {name} ({state}): {len(shown)} proposal(s)" + (
              "; it has ended: `perch operator failed ID` reports an accepted perch that failed in flight, and "
              "the replacement it proposes can be decided" if state != "running" else ""))
        for proposal in shown:
            print(_proposal_line(proposal))
        return 0

    return _with_node("perch_operator_list", body)


def register_replay(sub) -> None:
    """Add `perch replay`: re-send a recorded mission's stage requests and compare the replies."""
    p = sub.add_parser("replay", help="re-send a recorded mission's stage requests to the live graph")
    p.add_argument("recording", type=Path, help="run.mcap written by perch plan / perch demo")
    p.add_argument("--check", action="store_true", help="compare every reply with the recorded one; "
                                                        "exit 1 on any difference, 3 when a damaged recording "
                                                        "left calls unchecked")
    p.add_argument("--stages", help="comma-separated subset (clean,crop,segment,filter,optimise,reconstruct)")
    p.add_argument("--rtol", type=float, default=1e-4, help="relative tolerance for numbers")
    p.add_argument("--atol", type=float, default=1e-5, help="absolute tolerance for numbers")
    p.add_argument("--launch", action="store_true", help="start the graph for the replay (else use the running one)")
    p.add_argument("--config", type=Path, help="parameter file for --launch")
    p.add_argument("-p", "--param", action="append", default=[], metavar="NODE:PARAM:=VALUE",
                   help="parameter override for --launch (repeatable)")
    p.set_defaults(func=_replay)


def check_exit_code(summary: str) -> int:
    """`perch replay --check`'s exit code for its summary line: 1 on a difference, 3 when a damaged
    recording left calls unchecked (what survived matched), else 0."""
    if "FAILED" in summary:
        return 1
    return 3 if "INCOMPLETE" in summary else 0


def _replay(args) -> int:
    from perch_operator.cli.diff import Tolerance
    from perch_operator.cli.replay import replay, summary_line
    from perch_operator.cli.runner import ensure_graph

    if not args.recording.is_file():
        raise FileNotFoundError(f"{args.recording}: no such recording")

    def body(node) -> int:
        logs = Path(tempfile.mkdtemp(prefix="perch_replay_logs_"))
        graph = ensure_graph(node, args.config, args.param, logs) if args.launch else None
        try:
            outcomes = replay(node, args.recording, check=args.check, tol=Tolerance(args.rtol, args.atol),
                              stages=args.stages.split(",") if args.stages else None)
        finally:
            if graph is not None:
                graph.stop()
        line = summary_line(outcomes, args.check)
        print(line)
        return check_exit_code(line) if args.check else 0

    return _with_node("perch_replay", body)


def register_dispatch(sub) -> None:
    """Add `perch dispatch`: receive accepted perch waypoints, as a drone dispatcher would."""
    p = sub.add_parser("dispatch", help="receive accepted perch waypoints (a minimal drone dispatcher)")
    p.add_argument("--output", type=Path, help="keep this YAML file of the latest waypoint per drone")
    p.set_defaults(func=_dispatch)


def _dispatch(args) -> int:
    from perch_operator.cli.dispatcher import main

    return main(args.output)


def register_record(sub) -> None:
    """Add `perch record`: record every perch topic and stage call until Ctrl-C."""
    p = sub.add_parser("record", help="record every /perch topic and stage call to an MCAP file until Ctrl-C "
                                      "(for missions started by another client)")
    p.add_argument("output", type=Path, help="MCAP file to write")
    p.add_argument("--duration", type=float, default=0.0, help="stop after this many seconds (0: at Ctrl-C)")
    p.set_defaults(func=_record)


def _record(args) -> int:
    from perch_common.outputs import check_writable_file
    from perch_operator.cli.runner import spin_for
    from perch_operator.outputs.recorder import MissionRecorder

    if not args.duration >= 0:   # NaN too
        raise ValueError(f"--duration must be >= 0 s (0: until Ctrl-C), got {args.duration}")
    check_writable_file(args.output, "perch record", "run.mcap")
    if args.output.exists():   # as ros2 bag record: a recording never replaces a file
        raise PerchError(f"perch record {args.output}: the file exists; give a new path (a recording never "
                         "replaces a file)")

    def body(node) -> int:
        recorder = MissionRecorder(node, args.output, latched=True)  # the latched state, as ros2 bag record
        started = time.monotonic()
        print(f"perch record: recording /perch to {args.output} (Ctrl-C stops)", file=sys.stderr)
        try:
            while not args.duration or time.monotonic() - started < args.duration:
                recorder.refresh()  # topics and services that appeared since
                spin_for(node, 1.0)
        except KeyboardInterrupt:
            pass
        recorder.close()
        print(f"perch record: {sum(recorder.counts.values())} messages on {len(recorder.counts)} topic(s)",
              file=sys.stderr)
        return 0

    return _with_node("perch_record", body)


def register_view(sub) -> None:
    """Add `perch view`: open a mission's rerun recording."""
    p = sub.add_parser("view", help="open a mission's rerun recording (run.rrd) in the rerun viewer")
    p.add_argument("recording", type=Path, help="run.rrd (or run.mcap) written by perch plan / perch demo")
    p.add_argument("--web", action="store_true", help="serve the web viewer (open the printed URL in a browser)")
    p.add_argument("--host", default="127.0.0.1",
                   help="address the viewer's servers listen on (default loopback only, as perch console; "
                        "0.0.0.0 exposes them, with no token)")
    p.set_defaults(func=_view)


RRD_MAGIC = b"RRF"   # every rerun .rrd starts with RRF0/RRF1/RRF2 (its encoding version)


def check_viewable(recording: Path) -> None:
    """Refuse what is not a recording before the viewer starts (rerun logged an error and kept serving)."""
    from perch_operator.outputs.runfile import MCAP_MAGIC

    if not recording.is_file():
        raise FileNotFoundError(f"{recording}: no such recording")
    with open(recording, "rb") as handle:
        head = handle.read(len(MCAP_MAGIC))
    if not head.startswith(RRD_MAGIC) and head != MCAP_MAGIC:
        raise PerchError(f"{recording}: not a recording ({'empty' if not head else 'neither .rrd nor MCAP'}); "
                         "give the run.rrd (or run.mcap) that perch plan or perch demo wrote")


def viewer_command(recording: Path, web: bool, host: str = "127.0.0.1") -> list[str] | None:
    """The rerun viewer command for a recording (web viewer without a display), its servers bound to
    `host` (rerun's own default is every interface); None without rerun."""
    exe = shutil.which("rerun") or (str(Path(sys.executable).with_name("rerun"))
                                    if Path(sys.executable).with_name("rerun").exists() else None)
    if exe is None:
        return None
    return [exe, *(["--web-viewer"] if web else []), "--bind", host, str(recording)]


def has_display() -> bool:
    """Whether a graphical display is available."""
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")) or sys.platform in ("darwin", "win32")


def _view(args) -> int:
    check_viewable(args.recording)
    cmd = viewer_command(args.recording, args.web, args.host)
    if cmd is None:
        raise PerchError("the rerun viewer is not installed here (pip install rerun-sdk); or copy "
                         f"{args.recording} to a machine that has it and run `rerun {args.recording.name}`")
    if not args.web and not has_display():
        print(f"perch view: no display here (DISPLAY/WAYLAND_DISPLAY unset), so the desktop viewer cannot open.\n"
              f"  - serve it to a browser:  perch view {args.recording} --web   (then open the printed URL)\n"
              f"  - or copy {args.recording} to a machine with a display and run:  rerun {args.recording.name}\n"
              f"  - the static report beside it needs only a browser: {args.recording.with_name('report.html')}")
        return 1
    print(f"perch view: {' '.join(cmd)}")
    started = time.monotonic()
    code = subprocess.call(cmd)
    if code and time.monotonic() - started < 3:
        raise PerchError(f"the viewer exited at once (code {code}); try `perch view {args.recording} --web`")
    return code
