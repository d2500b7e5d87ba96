"""`perch bag play`: publish a bag's messages on the graph in time order (raw CDR, no re-encoding)."""

from __future__ import annotations

import sys
import time
from pathlib import Path

from perch_common.errors import PerchError
from perch_common.ros.msgdefs import message_class as installed_message_class
from perch_reconstruction.bag_read import bag_info, iter_raw, require_cdr

# A publisher sees its subscriber a moment before the subscriber's side of the match is complete;
# samples sent in between are lost even when reliable.
SETTLE_S = 1.0


def message_class(type_name: str):
    """The Python class of 'pkg/msg/Type' (must be installed)."""
    try:
        return installed_message_class(type_name)
    except (ValueError, ImportError, AttributeError) as exc:
        raise PerchError(f"message type '{type_name}' is not installed here; cannot publish it") from exc


def play_bag(path: str | Path, rate: float = 1.0, topics: list[str] | None = None,
             wait_subscribers: float = 0.0, log=print) -> dict:
    """Publish every message (optionally only `topics`) at `rate` x recorded speed (0: as fast as possible).

    wait_subscribers: wait up to this many seconds for each publisher to have a subscriber first.
    Returns per-topic counts."""
    import rclpy
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

    from perch_common.ros.node_main import ros_context

    if rate < 0:
        raise ValueError(f"rate must be >= 0 (0 = as fast as possible), got {rate}")
    info = bag_info(path)
    if info["damage"]:   # played as far as it goes, as reconstruct reads it: said, as `perch bag info` says it
        print(f"warning: damaged bag, played as far as it goes: {info['damage']}", file=sys.stderr)
    chosen = topics or list(info["topics"])
    unknown = [t for t in chosen if t not in info["topics"]]
    if unknown:
        raise PerchError(f"{path}: no topic(s) {', '.join(unknown)}; it has {', '.join(info['topics']) or 'none'}")
    # Other encodings' bytes would go out as if they were CDR: every subscriber would read garbage.
    require_cdr(info, chosen, ", or leave those topics out with --topics")
    counts = {t: 0 for t in chosen}
    with ros_context([]):
        node = rclpy.create_node("perch_bag_player")
        # Transient local: a subscriber asking for it also gets what was sent before its side of the
        # match completed (volatile subscribers, e.g. camera pipelines, still connect).
        qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
        publishers = {t: node.create_publisher(message_class(info["topics"][t]["type"]), t, qos) for t in chosen}
        deadline = time.monotonic() + wait_subscribers
        while wait_subscribers and time.monotonic() < deadline and any(
                p.get_subscription_count() == 0 for p in publishers.values()):
            time.sleep(0.05)
        if wait_subscribers:
            time.sleep(SETTLE_S)
        log(f"playing {path}: {sum(info['topics'][t]['count'] for t in chosen)} messages on {len(chosen)} topics"
            f" at rate {rate:g}")
        start_wall = time.monotonic()
        start_log = None
        for raw in iter_raw(path, chosen):
            if start_log is None:
                start_log = raw.log_time_ns
            if rate > 0:
                due = start_wall + (raw.log_time_ns - start_log) / 1e9 / rate
                delay = due - time.monotonic()
                if delay > 0:
                    time.sleep(delay)
            publishers[raw.topic].publish(raw.data)
            counts[raw.topic] += 1
        time.sleep(0.2)  # let the last reliable samples leave before the publishers go away
        node.destroy_node()
    return counts
