"""Declare a node's ROS parameters from a config dataclass and read them back typed."""

from __future__ import annotations

import dataclasses
from typing import Any, TypeVar

from rcl_interfaces.msg import ParameterDescriptor
from rclpy.node import Node

from perch_common.config import from_parameters, to_parameters

T = TypeVar("T")


def declare_config(node: Node, cls: type[T], prefix: str = "") -> T:
    """Declare one parameter per (nested) field of `cls`, defaults from the dataclass, and return it.

    Values given at start-up (--params-file, -p) override the defaults as usual in ROS.
    """
    descriptions = _descriptions(cls, prefix)
    for name, default in to_parameters(cls(), prefix).items():
        node.declare_parameter(name, default, ParameterDescriptor(description=descriptions.get(name, "")))
    return read_config(node, cls, prefix)


def read_config(node: Node, cls: type[T], prefix: str = "") -> T:
    """The current values of the parameters declared by `declare_config`."""
    names = to_parameters(cls(), prefix)
    values: dict[str, Any] = {n: node.get_parameter(n).value for n in names}
    return from_parameters(cls, values, prefix)


def _descriptions(cls: type, prefix: str) -> dict[str, str]:
    out: dict[str, str] = {}
    for f in dataclasses.fields(cls):
        name = prefix + f.name
        if dataclasses.is_dataclass(f.type) or (
                f.default_factory is not dataclasses.MISSING and dataclasses.is_dataclass(f.default_factory())):
            out.update(_descriptions(type(f.default_factory()), name + "."))
            continue
        text = f.metadata.get("description", "")
        unit = f.metadata.get("unit")
        out[name] = f"{text} [{unit}]" if unit else text
    return out
