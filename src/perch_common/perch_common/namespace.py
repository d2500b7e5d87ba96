"""The graph's ROS namespace: every node and client resolves Perch's relative names (`perch/...`) in it.

Set by `perch --namespace N ...` / `perch launch --namespace N` (exported as PERCH_NAMESPACE so
that node processes and clients started from the command inherit it). Empty = the root namespace,
where the names resolve to `/perch/...`.
"""

from __future__ import annotations

import os
import re

NAMESPACE_ENV = "PERCH_NAMESPACE"
_VALID = re.compile(r"^(/[A-Za-z][A-Za-z0-9_]*)+$")


def normalise(namespace: str | None) -> str:
    """`N`, `/N` or `/a/b` -> `/N` (absolute); '' or '/' -> ''; raises ValueError on an invalid name."""
    text = (namespace or "").strip()
    if text in ("", "/"):
        return ""
    text = "/" + text.strip("/")
    if not _VALID.match(text):
        raise ValueError(f"namespace '{namespace}': use letters, digits and '_' per token, each starting "
                         "with a letter (e.g. 'site_a' or '/lab/site_a')")
    return text


def current(environ: dict | None = None) -> str:
    """The namespace in force: PERCH_NAMESPACE (normalised), '' when unset."""
    return normalise((os.environ if environ is None else environ).get(NAMESPACE_ENV, ""))


def ros_arguments(namespace: str) -> list[str]:
    """ROS arguments (after `--ros-args`) that put every node of a process into `namespace`."""
    namespace = normalise(namespace)
    return ["-r", f"__ns:={namespace}"] if namespace else []
