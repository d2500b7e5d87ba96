"""Decode every message of an MCAP file with independent readers: rosbags and Foxglove's own decoders.

Used by the tests and by anyone checking that a recording is readable outside Perch:
`rosbags_counts(path)` (rosbags AnyReader, the file's own schemas) and `foxglove_counts(path)`
(tools/foxglove-decode: @mcap/core + @foxglove/rosmsg + @foxglove/rosmsg2-serialization under node).
Both return {topic: (messages, decoded)}.
"""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

from perch_common.data import repo_root


class DecoderUnavailable(RuntimeError):
    """The decoder cannot run here (node/npm missing, packages not installable)."""


def rosbags_counts(path: str | Path) -> dict[str, tuple[int, int]]:
    """Messages and successfully decoded messages per topic, read by rosbags' AnyReader.

    rosbags files every type under its normalized name (a service event `pkg/srv/Name_Event` as
    `pkg/srv/msg/Name_Event`; messages and action parts unchanged), so types are looked up that way.
    """
    from rosbags.highlevel import AnyReader
    from rosbags.typesys.msg import normalize_msgtype

    counts: dict[str, list[int]] = {}
    with AnyReader([Path(path)]) as reader:
        for connection, _, raw in reader.messages():
            entry = counts.setdefault(connection.topic, [0, 0])
            entry[0] += 1
            try:
                reader.deserialize(raw, normalize_msgtype(connection.msgtype))
                entry[1] += 1
            except Exception:  # a count, not a crash: the test reports which topic failed
                pass
    return {topic: (n, ok) for topic, (n, ok) in counts.items()}


def foxglove_tool() -> Path:
    """tools/foxglove-decode with its npm packages installed (`npm ci` from the lock file on first use)."""
    tool = repo_root() / "tools" / "foxglove-decode"
    if shutil.which("node") is None or shutil.which("npm") is None:
        raise DecoderUnavailable("node and npm are not installed")
    if not (tool / "node_modules" / "@mcap" / "core").is_dir():
        done = subprocess.run(["npm", "ci", "--no-audit", "--no-fund"], cwd=tool, capture_output=True, text=True,
                              timeout=300)
        if done.returncode != 0:
            raise DecoderUnavailable(f"npm ci in {tool} failed: {done.stderr.strip()[-400:]}")
    return tool


def foxglove_report(path: str | Path) -> dict:
    """The decode report of tools/foxglove-decode/decode.mjs for one file (see that script)."""
    tool = foxglove_tool()
    done = subprocess.run(["node", str(tool / "decode.mjs"), str(Path(path).resolve())], capture_output=True,
                          text=True, timeout=300)
    if done.returncode != 0:
        raise RuntimeError(f"foxglove decode of {path} failed: {done.stderr.strip()}")
    return json.loads(done.stdout)


def foxglove_counts(path: str | Path) -> dict[str, tuple[int, int]]:
    """Messages and successfully decoded messages per topic, read by Foxglove's decoders."""
    return {topic: (t["messages"], t["decoded"]) for topic, t in foxglove_report(path)["topics"].items()}
