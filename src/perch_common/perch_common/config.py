"""ROS-parameter YAML (`node_name: ros__parameters: ...`) into typed config dataclasses.

Fields are made with `param()`: a description, a unit, an inclusive range and the allowed choices.
`from_parameters` rejects values outside them (naming the parameter and what it accepts), and the
node adapters (perch_common.ros.params) declare one ROS parameter per field with the same range in
its descriptor, so a file, the command line and a running node are checked alike.
"""

from __future__ import annotations

import dataclasses
import math
import os
from pathlib import Path
from typing import Any, Generic, TypeVar

import yaml

T = TypeVar("T")

WILDCARD = "/**"


class ConfigError(ValueError):
    """A configuration file or value that cannot be used."""


def param(default: Any, description: str, unit: str | None = None, *, low: float | None = None,
          high: float | None = None, choices: tuple | list | None = None) -> Any:
    """A config dataclass field: description and unit, the inclusive range [low, high] of a number
    (either end may be left open) and the values a string may take; all become the ROS parameter's."""
    metadata: dict[str, Any] = {"description": description}
    if unit:
        metadata["unit"] = unit
    if low is not None or high is not None:
        metadata["range"] = (-math.inf if low is None else low, math.inf if high is None else high)
    if choices is not None:
        metadata["choices"] = tuple(choices)
    if isinstance(default, (list, dict)):
        return dataclasses.field(default_factory=lambda: type(default)(default), metadata=metadata)
    return dataclasses.field(default=default, metadata=metadata)


def field_specs(cls: type, prefix: str = "") -> dict[str, dict]:
    """Flat parameter name -> the field's metadata (description, unit, range, choices) of a config class."""
    out: dict[str, dict] = {}
    for f in dataclasses.fields(cls):
        default = _default_of(f)
        if dataclasses.is_dataclass(default):
            out.update(field_specs(type(default), prefix + f.name + "."))
        else:
            out[prefix + f.name] = dict(f.metadata)
    return out


def check_value(name: str, value: Any, spec: dict) -> None:
    """Raise ConfigError when `value` is outside the field's range or choices, saying what is allowed."""
    choices = spec.get("choices")
    if choices is not None and value not in choices:
        raise ConfigError(f"parameter {name}={value!r}: use one of {', '.join(map(repr, choices))}")
    bounds = spec.get("range")
    if bounds is not None and not isinstance(value, bool) and isinstance(value, (int, float)):
        low, high = bounds
        if not (low <= value <= high):  # NaN fails too
            raise ConfigError(f"parameter {name}={value!r}: must be in {describe_range(low, high)}")


def describe_range(low: float, high: float) -> str:
    """'[0, 10]', '>= 0' or '<= 5' for an inclusive range."""
    if math.isinf(low):
        return f"<= {high:g}"
    if math.isinf(high):
        return f">= {low:g}"
    return f"[{low:g}, {high:g}]"


def base_config(config: Any, cls: type[T]) -> T:
    """The `cls` part of a node config that extends it with node-only parameters."""
    return cls(**{f.name: getattr(config, f.name) for f in dataclasses.fields(cls)})


@dataclasses.dataclass
class StageNodeConfig(Generic[T]):
    """The parameters a stage node has besides its stage's settings.

    A node's config derives from its stage's config class and this one
    (`class SegmentationNodeConfig(SegmentationConfig, StageNodeConfig[SegmentationConfig])`), adds its
    own fields, and gives the stage its settings alone with `stage_config()`.
    """

    introspection: bool = param(True, "publish service introspection events (requests and replies) for the recorder")

    def stage_config(self) -> T:
        """The stage's settings alone, as the stage's config class (the dataclass this node config extends)."""
        stage = next(c for c in type(self).__mro__[1:]
                     if dataclasses.is_dataclass(c) and not issubclass(c, StageNodeConfig))
        return base_config(self, stage)


def default_config_path() -> Path:
    """config/perch.yaml of the workspace (PERCH_CONFIG overrides)."""
    if os.environ.get("PERCH_CONFIG"):
        return Path(os.environ["PERCH_CONFIG"])
    here = Path(__file__).resolve()
    for parent in here.parents:
        candidate = parent / "config" / "perch.yaml"
        if candidate.is_file():
            return candidate
    raise ConfigError("config/perch.yaml not found; set PERCH_CONFIG to your parameter file")


_SafeLoader = getattr(yaml, "CSafeLoader", yaml.SafeLoader)   # libyaml (~5x faster) when PyYAML has it


def load_yaml(path: str | Path) -> dict:
    """The mapping in a YAML parameter file (raises ConfigError naming the file)."""
    path = Path(path)
    try:
        data = yaml.load(path.read_text(), Loader=_SafeLoader) or {}
    except (OSError, yaml.YAMLError) as exc:
        raise ConfigError(f"{path}: cannot read parameters ({exc})") from exc
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: expected a mapping of node names to ros__parameters")
    return data


def node_names(path: str | Path | None = None) -> list[str]:
    """Node sections of a parameter file, in file order (the wildcard excluded)."""
    return [k.lstrip("/") for k in load_yaml(path or default_config_path()) if k != WILDCARD]


def node_parameters(node_name: str, path: str | Path | None = None) -> dict[str, Any]:
    """Flat parameters of one node: the `/**` wildcard section overlaid by the node's own.

    Nested mappings are flattened with dots, as ROS does (`camera.width`).
    """
    data = load_yaml(path or default_config_path())
    merged: dict[str, Any] = {}
    for key in (WILDCARD, node_name, "/" + node_name):
        section = data.get(key) or {}
        merged.update(flatten(section.get("ros__parameters") or {}))
    return merged


def load_node_config(cls: type[T], node_name: str, path: str | Path | None = None) -> T:
    """Config dataclass `cls` from `node_name`'s section of `path` (default: config/perch.yaml).

    Without a path and without a project config file, the dataclass defaults are used; a path
    that was given must be readable.
    """
    try:
        params = node_parameters(node_name, path or default_config_path())
    except ConfigError:
        if path:
            raise
        params = {}
    return from_parameters(cls, params)


def flatten(mapping: dict, prefix: str = "") -> dict[str, Any]:
    """Nested mappings as one flat mapping with dotted keys (as ROS names nested parameters)."""
    out: dict[str, Any] = {}
    for key, value in mapping.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            out.update(flatten(value, name + "."))
        else:
            out[name] = value
    return out


def from_parameters(cls: type[T], params: dict[str, Any], prefix: str = "", strict: bool = False) -> T:
    """Build dataclass `cls` from flat parameters; nested dataclass fields use `field.` prefixes.

    Values are coerced to the field's default type and checked against its range and choices
    (ConfigError); `strict` rejects unknown keys under `prefix`.
    """
    kwargs: dict[str, Any] = {}
    known: set[str] = set()
    for f in dataclasses.fields(cls):
        key = prefix + f.name
        default = _default_of(f)
        if dataclasses.is_dataclass(default):
            kwargs[f.name] = from_parameters(type(default), params, key + ".", strict)
            known.update(k for k in params if k.startswith(key + "."))
            continue
        known.add(key)
        if key in params:
            kwargs[f.name] = _coerce(params[key], default, key)
            check_value(key, kwargs[f.name], f.metadata)
    if strict:
        unknown = [k for k in params if k.startswith(prefix) and k not in known]
        if unknown:
            raise ConfigError(f"unknown parameter(s) for {cls.__name__}: {', '.join(sorted(unknown))}")
    return cls(**kwargs)


def to_parameters(obj: Any, prefix: str = "") -> dict[str, Any]:
    """Flat parameters of a config dataclass (inverse of from_parameters)."""
    out: dict[str, Any] = {}
    for f in dataclasses.fields(obj):
        value = getattr(obj, f.name)
        if dataclasses.is_dataclass(value):
            out.update(to_parameters(value, prefix + f.name + "."))
        else:
            out[prefix + f.name] = list(value) if isinstance(value, tuple) else value
    return out


def _default_of(f: dataclasses.Field) -> Any:
    if f.default is not dataclasses.MISSING:
        return f.default
    if f.default_factory is not dataclasses.MISSING:  # type: ignore[misc]
        return f.default_factory()  # type: ignore[misc]
    return None


def _coerce(value: Any, default: Any, key: str) -> Any:
    try:
        if isinstance(default, bool):
            if isinstance(value, str):
                return value.strip().lower() in ("1", "true", "yes", "on")
            return bool(value)
        if isinstance(default, int):
            if isinstance(value, float) and not value.is_integer():
                raise ValueError("not a whole number")
            return int(value)
        if isinstance(default, float):
            return float(value)
        if isinstance(default, (list, tuple)):
            return type(default)(value)
        if isinstance(default, str):
            return str(value)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"parameter {key}={value!r}: {exc}") from exc
    return value
