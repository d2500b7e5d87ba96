"""Declare a node's ROS parameters from a config dataclass, keep them valid, and read them back typed.

One convention for every Perch node: each field becomes a parameter whose descriptor carries its
description, unit, range (FloatingPointRange / IntegerRange) and choices; a bad start-up value
stops the node with one line naming the parameter (ConfigError, printed by run_node); a bad value
set while running is rejected with the reason and the node keeps its old value. A parameter the
node reads only at start-up (`param(..., read_only=True)`) is read-only in its descriptor, so
`ros2 param set` is refused ("parameter is read-only") instead of succeeding and changing nothing.
An integer given for a float parameter (`stage_timeout: 60` in a file, `-p ...:=60`) is taken as
that float, as a ROS user expects; rcl would refuse it as the wrong type.
"""

from __future__ import annotations

import re
from typing import Any, Callable, TypeVar

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, SetParametersResult
from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException
from rclpy.node import Node

from perch_common.config import ConfigError, describe_range, field_specs, from_parameters, to_parameters

T = TypeVar("T")

# The largest finite bound a descriptor range can hold (an open end of a `param` range).
_FLOAT_LIMIT = 1.0e308
_INT_LIMIT = 2 ** 63 - 1


def declare_config(node: Node, cls: type[T], prefix: str = "",
                   check: Callable[[T], Any] | None = None) -> T:
    """Declare one parameter per (nested) field of `cls` and return the configuration.

    Values given at start-up (--params-file, -p) override the defaults as usual in ROS. `check(config)`
    (e.g. the config's own validate) runs on the start-up values and on every later change; it raises
    ValueError naming what is wrong. Raises ConfigError (one line, naming the node) on a bad start-up value.
    """
    specs = field_specs(cls, prefix)
    for name, default in to_parameters(cls(), prefix).items():
        described = descriptor(specs.get(name, {}), default)
        try:
            _declare(node, name, default, described)
        except (InvalidParameterValueException, InvalidParameterTypeException) as exc:
            raise ConfigError(f"{node.get_name()}: {_rejection(name, specs.get(name, {}), exc)}") from None
    try:
        config = read_config(node, cls, prefix)
        if check is not None:
            check(config)
    except ValueError as exc:  # ConfigError included
        raise ConfigError(f"{node.get_name()}: {exc}") from None
    node.add_on_set_parameters_callback(lambda changed: _on_set(node, cls, prefix, check, changed))
    return config


def _declare(node: Node, name: str, default: Any, described: ParameterDescriptor) -> None:
    """declare_parameter, taking an integer override of a float parameter as that float."""
    from rcl_interfaces.msg import ParameterType
    from rclpy.parameter import Parameter

    override = node._parameter_overrides.get(name)   # rclpy keeps the start-up overrides here
    if (override is not None and isinstance(default, float) and override.type_ == Parameter.Type.INTEGER
            and described.type in (ParameterType.PARAMETER_NOT_SET, ParameterType.PARAMETER_DOUBLE)):
        node._parameter_overrides[name] = Parameter(name, Parameter.Type.DOUBLE, float(override.value))
    node.declare_parameter(name, default, described)


def read_config(node: Node, cls: type[T], prefix: str = "") -> T:
    """The current values of the parameters declared by `declare_config`."""
    names = to_parameters(cls(), prefix)
    values: dict[str, Any] = {n: node.get_parameter(n).value for n in names}
    return from_parameters(cls, values, prefix)


def descriptor(spec: dict, default: Any) -> ParameterDescriptor:
    """The ROS descriptor of a `param` field: description [unit], range and choices."""
    text = spec.get("description", "")
    out = ParameterDescriptor(description=f"{text} [{spec['unit']}]" if spec.get("unit") else text,
                              read_only=bool(spec.get("read_only")))
    bounds = spec.get("range")
    if bounds is not None and isinstance(default, int) and not isinstance(default, bool):
        low, high = (int(max(-_INT_LIMIT, min(_INT_LIMIT, b))) for b in bounds)
        out.integer_range = [IntegerRange(from_value=low, to_value=high, step=0)]
    elif bounds is not None and isinstance(default, float):
        low, high = (max(-_FLOAT_LIMIT, min(_FLOAT_LIMIT, float(b))) for b in bounds)
        out.floating_point_range = [FloatingPointRange(from_value=low, to_value=high, step=0.0)]
    constraints = []
    if bounds is not None:
        constraints.append(describe_range(*bounds))
    if spec.get("choices") is not None:
        constraints.append("one of: " + ", ".join(map(repr, spec["choices"])))
    out.additional_constraints = "; ".join(constraints)
    return out


def _on_set(node: Node, cls: type, prefix: str, check: Callable | None, changed: list) -> SetParametersResult:
    """Accept a change only if the whole configuration it leads to is valid (ranges are checked by rclpy)."""
    names = to_parameters(cls(), prefix)
    values = {n: node.get_parameter(n).value for n in names}
    values.update({p.name: p.value for p in changed if p.name in values})
    try:
        config = from_parameters(cls, values, prefix)
        if check is not None:
            check(config)
    except ValueError as exc:
        return SetParametersResult(successful=False, reason=str(exc))
    return SetParametersResult(successful=True)


def _rejection(name: str, spec: dict, exc: Exception) -> str:
    """What was wrong with a start-up value rclpy refused (out of its range, or of the wrong type)."""
    text = str(exc.args[0]) if exc.args else str(exc)
    text = text.removesuffix(f": {name}")  # rclpy appends the name
    given = re.match(r"Invalid parameter value \((.*)\) for parameter", text)
    if isinstance(exc, InvalidParameterValueException) and given and "range" in spec:
        return f"parameter {name}={given.group(1)}: must be in {describe_range(*spec['range'])}"
    return f"parameter {name}: {text}"
