"""ROS-parameter YAML (`node_name: ros__parameters: ...`) into typed config dataclasses.

Fields are made with `param()`: a description, a unit, an inclusive range and the allowed choices.
`from_parameters` rejects values outside them (naming the parameter and what it accepts), and the
node adapters (perch_common.ros.params) declare one ROS parameter per field with the same range in
its descriptor, so a file, the command line and a running node are checked alike.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import os
import re
from pathlib import Path
from typing import Any, Generic, Iterable, TypeVar

import yaml

T = TypeVar("T")

WILDCARD = "/**"


class ConfigError(ValueError):
    """A configuration file or value that cannot be used."""


def param(default: Any, description: str, unit: str | None = None, *, low: float | None = None,
          high: float | None = None, choices: tuple | list | None = None, read_only: bool = False) -> Any:
    """A config dataclass field: description and unit, the inclusive range [low, high] of a number
    (either end may be left open) and the values a string may take; all become the ROS parameter's.

    read_only: the node uses the value only at start-up (a subscription's topic, a service's
    introspection, a timer's period): its descriptor says so and a change while running is refused,
    instead of being accepted and changing nothing."""
    metadata: dict[str, Any] = {"description": description}
    if read_only:
        metadata["read_only"] = True
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

    introspection: bool = param(True, "publish service introspection events (requests and replies) for the recorder",
                                read_only=True)
    # nav2's name for rclpy's result_timeout. rclpy keeps a finished goal 900 s; a stage's result can be
    # big (the segmentation's face labels) and clients ask for it as the goal is accepted.
    action_server_result_timeout: float = param(60.0, "seconds a finished goal's result stays with the stage's "
                                                "action server for a late get_result (whole seconds)", "s", low=1.0, high=86400.0,
                                                read_only=True)
    # Work budget (perch_common.work): a call may work base + rate x (input faces / 1000) CPU seconds, then it
    # is refused naming the budget. Time is not proportional to faces alone (the filter: 0.01-0.02 s per 1000
    # faces on the apartment and multi_storey, 0.4 s on a 38k-face generated room, which took over 38 s
    # on the loaded test machine): the defaults guard against runaway input with several times a loaded
    # normal run's time; a triangle soup (~2 s per 1000 faces) of 122k faces is refused at 181 s.
    work_budget_base: float = param(120.0, "work budget: seconds any call may take whatever its input", "s",
                                    low=0.001, high=86400.0)
    work_budget_rate: float = param(0.5, "work budget: seconds added per 1000 faces of the call's input mesh "
                                    "(reconstruct: per bag frame, see work_budget_per_frame)", "s",
                                    low=0.0, high=3600.0)

    def stage_config(self) -> T:
        """The stage's settings alone, as the stage's config class (the dataclass this node config extends)."""
        stage = next(c for c in type(self).__mro__[1:]
                     if dataclasses.is_dataclass(c) and not issubclass(c, StageNodeConfig))
        return base_config(self, stage)


CONFIG_PACKAGE = "perch_operator"   # installs config/ into share/perch_operator/config (its setup.cfg)


def installed_config_file(name: str, prefixes: list[str] | None = None) -> Path | None:
    """share/perch_operator/config/NAME of an installation (`colcon build` install space, a venv):
    the prefixes of AMENT_PREFIX_PATH, then this Python's prefix; None when none has it."""
    import sys

    if prefixes is None:
        prefixes = [p for p in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p] + [sys.prefix]
    for prefix in prefixes:
        candidate = Path(prefix) / "share" / CONFIG_PACKAGE / "config" / name
        if candidate.is_file():
            return candidate
    return None


def config_file(name: str) -> Path | None:
    """config/NAME of the source tree this code runs from, else of the installation; None when neither."""
    for parent in Path(__file__).resolve().parents:
        candidate = parent / "config" / name
        if candidate.is_file() and (parent / "src").is_dir():
            return candidate
    return installed_config_file(name)


def default_config_path() -> Path:
    """config/perch.yaml of the workspace, or of the installation's share directory (PERCH_CONFIG overrides)."""
    if os.environ.get("PERCH_CONFIG"):
        return Path(os.environ["PERCH_CONFIG"])
    found = config_file("perch.yaml")
    if found is None:
        raise ConfigError(f"config/perch.yaml not found in the source tree nor in share/{CONFIG_PACKAGE}/config of "
                          "the installation (AMENT_PREFIX_PATH); set PERCH_CONFIG to your parameter file")
    return found


_SafeLoader = getattr(yaml, "CSafeLoader", yaml.SafeLoader)   # libyaml (~5x faster) when PyYAML has it


def load_yaml(path: str | Path) -> dict:
    """The mapping in a YAML parameter file (raises ConfigError naming the file)."""
    path = Path(path)
    try:
        data = yaml.load(path.read_text(), Loader=_SafeLoader) or {}
    except (OSError, yaml.YAMLError) as exc:
        raise ConfigError(f"{path}: cannot read parameters ({exc})") from exc
    except UnicodeDecodeError:   # an image or binary file given as --config: the decoder named no file
        raise ConfigError(f"{path}: not a YAML parameter file (not text); give a file like config/perch.yaml") from None
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: expected a mapping of node names to ros__parameters")
    return data


def _key_pattern(key: str) -> re.Pattern:
    """The node names a parameter-file key applies to, as rcl matches them: `/**` any namespaces
    (or none), `*` one token; a key without a leading `/` is absolute too."""
    parts = []
    for token in key.strip("/").split("/"):
        if token == "**":
            parts.append(r"(?:/[^/]+)*")
        else:
            parts.append("/" + re.escape(token).replace(r"\*", "[^/]*"))
    return re.compile("".join(parts))


def node_keys(data: dict, node_name: str, namespace: str = "") -> list[str]:
    """The keys of a parameter file that apply to node `namespace/node_name`, in file order."""
    full = f"{namespace.rstrip('/')}/{node_name}" if namespace else f"/{node_name}"
    return [key for key in data if isinstance(key, str) and _key_pattern(key).fullmatch(full)]


def node_names(path: str | Path | None = None) -> list[str]:
    """Nodes a parameter file names, in file order: the last token of each key that names one
    (`perch_placement`, `/site_a/perch_placement`, `/**/perch_segmentation`); wildcard-only keys
    (`/**`, `/site_a/*`) name none."""
    names: list[str] = []
    for key in load_yaml(path or default_config_path()):
        last = str(key).strip("/").rsplit("/", 1)[-1]
        if last and "*" not in last and last not in names:
            names.append(last)
    return names


def node_parameters(node_name: str, path: str | Path | None = None, namespace: str | None = None) -> dict[str, Any]:
    """Flat parameters of one node as rcl gives them to it: every key that matches the node's full
    name (`/**`, `/**/NAME`, `/NS/NAME`, `NAME`, ... in file order, later ones winning), read with
    rclpy's parameter-file parser (nested mappings become dotted names, `camera.width`).

    namespace: the node's (default: PERCH_NAMESPACE, where Perch's graph runs).
    """
    from perch_common import namespace as ros_namespace

    path = Path(path or default_config_path())
    data = load_yaml(path)
    keys = node_keys(data, node_name, ros_namespace.current() if namespace is None else namespace)
    for key in keys:
        if not isinstance(data[key], dict) or "ros__parameters" not in data[key]:
            raise ConfigError(f"{path}: section '{key}' has no ros__parameters mapping")
    if not keys:
        return {}
    from rclpy.parameter import parameter_dict_from_yaml_file, parameter_value_to_python

    try:
        parsed = parameter_dict_from_yaml_file(str(path), target_nodes=keys)
    except (RuntimeError, yaml.YAMLError) as exc:
        raise ConfigError(f"{path}: {exc}") from None
    return {name: _plain(parameter_value_to_python(msg.value)) for name, msg in parsed.items()}


def _plain(value: Any) -> Any:
    """rclpy's array values (array.array, numpy) as lists, as YAML gave them."""
    if isinstance(value, (str, bytes, bool, int, float)) or value is None:
        return value
    return list(value)


# Node name -> its parameters' config class ("module:Class"), for checking values before a node starts.
NODE_CONFIGS = {
    "perch_reconstruction": "perch_reconstruction.config:ReconstructionNodeConfig",
    "perch_operator": "perch_operator.coordinator.config:OperatorConfig",
    "perch_segmentation": "perch_segmentation.config:SegmentationNodeConfig",
    "perch_filtering": "perch_filtering.config:FilterNodeConfig",
    "perch_placement": "perch_placement.config:PlacementNodeConfig",
    "perch_mesh_tools": "perch_common.mesh_node:MeshToolsConfig",
}


def node_config_class(node_name: str) -> type | None:
    """The config dataclass whose fields are `node_name`'s parameters (None for an unknown node)."""
    import importlib

    target = NODE_CONFIGS.get(node_name)
    if target is None:
        return None
    module, _, name = target.partition(":")
    return getattr(importlib.import_module(module), name)


_TYPE_NAMES = {bool: "a bool (true/false)", int: "an integer", float: "a float (double)", str: "a string",
               list: "a list"}


def override_value(name: str, text: str, default: Any) -> Any:
    """The value of `-p ...:name:=text` as the node declaring `name` with `default` receives it.

    rcl reads the text as YAML. An integer for a float parameter is taken as that float (ROS would
    refuse `60` for a double with "wrong parameter type", which surprises ROS users); a number for
    a string parameter is taken as its text. Anything else of the wrong type is a ConfigError."""
    try:
        value = yaml.safe_load(text) if text.strip() else ""
    except yaml.YAMLError:
        value = text
    kind = type(default)
    if isinstance(default, bool):
        ok = isinstance(value, bool)
    elif isinstance(default, int):
        ok = isinstance(value, int) and not isinstance(value, bool)
    elif isinstance(default, float):
        ok = isinstance(value, (int, float)) and not isinstance(value, bool)
        value = float(value) if ok else value
    elif isinstance(default, str):
        ok = not isinstance(value, (list, dict)) and value is not None
        value = text if ok and not isinstance(value, str) else value
    elif isinstance(default, (list, tuple)):
        kind = list
        ok = isinstance(value, list)
        if ok and default and isinstance(default[0], float):
            ok = all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value)
            value = [float(v) for v in value] if ok else value
    else:
        ok = True
    if not ok:
        raise ConfigError(f"parameter {name}:={text}: expects {_TYPE_NAMES.get(kind, kind.__name__)}, "
                          f"got {type(value).__name__} {value!r}")
    return value


def override_text(value: Any) -> str:
    """The `-p` text (YAML, as rcl parses it) that gives a node exactly `value`."""
    return yaml.safe_dump(value, default_flow_style=True, width=1 << 20).strip().removesuffix("...").strip()


def check_overrides(per_node: dict[str, list[str]], nodes: list[str], path: str | Path | None = None,
                    namespace: str | None = None) -> dict[str, list[str]]:
    """Check `-p` overrides (perch_common.launch.parse_overrides' `{node or '*': ['name:=text']}`)
    against what `nodes` declare, before anything starts; returns them as the nodes should get them.

    An unknown node or parameter name, a value of the wrong type or outside its range, or a
    configuration (file + overrides) the node's own validation refuses is a ConfigError naming
    the override and what exists or is accepted.
    """
    if not per_node:
        return {}   # nothing to check: no node's config classes imported (launching stays quick)
    classes = {n: node_config_class(n) for n in nodes}
    unknown = [n for n in per_node if n != "*" and n not in classes]
    if unknown:
        raise ConfigError(f"-p {unknown[0]}:...: no node '{unknown[0]}' in this graph; its nodes: "
                          f"{', '.join(nodes)}")
    out: dict[str, list[str]] = {}
    values: dict[str, dict[str, Any]] = {n: {} for n in nodes}
    for node, items in per_node.items():
        targets = [n for n in nodes if classes[n] is not None] if node == "*" else [node]
        for item in items:
            name, _, text = item.partition(":=")
            users = [n for n in targets if classes[n] is not None
                     and name in to_parameters(classes[n](), "")]
            if not users:
                where = f"node {node} declares no" if node != "*" else "no node declares a"
                declared = sorted(to_parameters(classes[targets[0]](), "")) if node != "*" and classes[node] else []
                close = difflib.get_close_matches(name, declared, n=3)
                hint = f"; did you mean {', '.join(close)}?" if close else ""
                listing = f"; its parameters: {', '.join(declared)}" if declared else ""
                raise ConfigError(f"-p {'' if node == '*' else node + ':'}{item}: {where} parameter "
                                  f"'{name}'{hint}{listing}")
            for user in users:
                default = to_parameters(classes[user](), "")[name]
                label = f"{user}:{name}"
                value = override_value(label, text, default)
                check_value(label, value, field_specs(classes[user]).get(name, {}))
                values[user][name] = value
            out.setdefault(node, []).append(f"{name}:={override_text(value)}")
    for node, given in values.items():
        cls = classes[node]
        if cls is None or not given:
            continue
        try:
            params = dict(node_parameters(node, path, namespace), **given)
            config = from_parameters(cls, params)
            if hasattr(config, "validate"):
                config.validate()
        except ValueError as exc:
            shown = " ".join(f"-p {node}:{k}:={override_text(v)}" for k, v in given.items())
            raise ConfigError(f"{node}: {exc} (with {shown})") from None
    return out


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


TRUE_WORDS = ("1", "true", "yes", "on")
FALSE_WORDS = ("0", "false", "no", "off")


def apply_overrides(params: dict[str, Any], overrides: Iterable[str], known: Iterable[str], node: str) -> dict[str, Any]:
    """`params` with a command's `-p NAME:=VALUE` overrides (ROS's form; NAME=VALUE is taken too), each value
    read as YAML as ROS reads it; ConfigError naming the parameters there are for an unknown one."""
    known = set(known)
    for item in overrides:
        name, sep, value = item.partition(":=")
        if not sep:
            name, sep, value = item.partition("=")
        name = name.strip()
        if not sep or not name:
            raise ConfigError(f"-p {item!r}: use NAME:=VALUE")
        if name not in known:
            raise ConfigError(f"-p {item!r}: {node} has no parameter '{name}' (known: {', '.join(sorted(known))})")
        try:
            params[name] = yaml.safe_load(value.strip()) if value.strip() else ""
        except yaml.YAMLError:
            params[name] = value.strip()
    return params


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
                word = value.strip().lower()
                if word not in TRUE_WORDS + FALSE_WORDS:   # 'banana' was taken as false without a word
                    raise ValueError("give true or false")
                return word in TRUE_WORDS
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
