"""ROS 2 message definitions (ros2msg text with dependencies) for MCAP schemas.

Standard MCAP tools decode a ros2 channel from its schema: the type's .msg text followed by
every type it uses, each after a `MSG: pkg/msg/Name` separator (as rosbag2 writes them).
Service event types (pkg/srv/Name_Event) are composed from the .srv file's two halves.
"""

from __future__ import annotations

import os
import re
import sys
from functools import lru_cache
from pathlib import Path

SEPARATOR = "=" * 80
PRIMITIVES = {"bool", "byte", "char", "float32", "float64", "int8", "uint8", "int16", "uint16", "int32",
              "uint32", "int64", "uint64", "string", "wstring"}


@lru_cache(maxsize=None)
def _share(package: str) -> Path:
    """share/<package> under AMENT_PREFIX_PATH, else under this Python's prefix (the venv)."""
    prefixes = [p for p in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p] + [sys.prefix]
    for prefix in prefixes:
        candidate = Path(prefix) / "share" / package
        if candidate.is_dir():
            return candidate
    raise FileNotFoundError(f"message definitions of {package} not found under {', '.join(prefixes)}")


@lru_cache(maxsize=None)
def _srv_halves(package: str, name: str) -> tuple[str, str]:
    text = (_share(package) / "srv" / f"{name}.srv").read_text()
    parts = re.split(r"^---[ \t]*$", text, maxsplit=1, flags=re.M)
    if len(parts) != 2:
        raise ValueError(f"{package}/srv/{name}: no --- between request and response")
    return parts[0], parts[1]


@lru_cache(maxsize=None)
def _action_parts(package: str, name: str) -> list[str]:
    text = (_share(package) / "action" / f"{name}.action").read_text()
    parts = re.split(r"^---[ \t]*$", text, flags=re.M)
    if len(parts) != 3:
        raise ValueError(f"{package}/action/{name}: expected goal --- result --- feedback")
    return parts


@lru_cache(maxsize=None)
def definition_text(type_name: str) -> str:
    """The bare .msg text of `pkg/msg/Name`, `pkg/srv/Name_Request|_Response|_Event`."""
    package, kind, name = split_type(type_name)
    if kind == "msg":
        return (_share(package) / "msg" / f"{name}.msg").read_text()
    if kind == "srv":
        base, _, part = name.rpartition("_")
        request, response = _srv_halves(package, base)
        if part == "Request":
            return request
        if part == "Response":
            return response
        if part == "Event":
            return (f"service_msgs/ServiceEventInfo info\n{package}/{base}_Request[<=1] request\n"
                    f"{package}/{base}_Response[<=1] response\n")
    if kind == "action":
        base, _, part = name.rpartition("_")
        parts = dict(zip(("Goal", "Result", "Feedback"), _action_parts(package, base)))
        if part in parts:
            return parts[part]
        if part == "FeedbackMessage":
            return f"unique_identifier_msgs/UUID goal_id\n{package}/{base}_Feedback feedback\n"
    raise ValueError(f"no message definition for {type_name}")


def message_class(type_name: str) -> type:
    """The Python class of a message type name (msg, service Request/Response/Event, action parts)."""
    import importlib

    package, kind, name = split_type(type_name)
    module = importlib.import_module(f"{package}.{kind}")
    if kind == "msg":
        return getattr(module, name)
    base, _, part = name.rpartition("_")
    owner = getattr(module, base)
    return getattr(owner, part) if kind == "srv" else getattr(owner.Impl, part)


def split_type(type_name: str) -> tuple[str, str, str]:
    """`pkg/kind/Name` or `pkg/Name` -> (pkg, kind, Name); kind is msg, srv or action."""
    parts = type_name.split("/")
    if len(parts) == 3:
        return parts[0], parts[1], parts[2]
    if len(parts) == 2:
        kind = "srv" if re.search(r"_(Request|Response|Event)$", parts[1]) else "msg"
        if re.search(r"_(Goal|Result|Feedback|FeedbackMessage)$", parts[1]):
            kind = "action"
        return parts[0], kind, parts[1]
    raise ValueError(f"not a ROS type name: {type_name}")


def dependencies(type_name: str) -> list[str]:
    """Non-primitive field types of `type_name`, as full `pkg/kind/Name` names, in order."""
    package, _, _ = split_type(type_name)
    out: list[str] = []
    for line in definition_text(type_name).splitlines():
        fields = line.split("#", 1)[0].split()
        if len(fields) < 2 or "=" in fields[1]:  # blank, comment or constant
            continue
        base = re.sub(r"\[.*\]$", "", fields[0])
        base = re.sub(r"<=\d+$", "", base)
        if base in PRIMITIVES:
            continue
        if base == "Header":
            base = "std_msgs/Header"
        if "/" not in base:
            base = f"{package}/{base}"
        pkg, kind, name = split_type(base)
        full = f"{pkg}/{kind}/{name}"
        if full not in out:
            out.append(full)
    return out


@lru_cache(maxsize=None)
def full_definition(type_name: str) -> str:
    """The ros2msg schema text: the type's definition, then each dependency once (depth first)."""
    package, kind, name = split_type(type_name)
    root = f"{package}/{kind}/{name}"
    seen: list[str] = []
    stack = list(reversed(dependencies(root)))
    while stack:
        dep = stack.pop()
        if dep in seen:
            continue
        seen.append(dep)
        stack.extend(reversed([d for d in dependencies(dep) if d not in seen]))
    parts = [definition_text(root).rstrip("\n")]
    for dep in seen:
        parts.append(f"{SEPARATOR}\nMSG: {dep}\n{definition_text(dep).rstrip(chr(10))}")
    return "\n".join(parts) + "\n"
