"""rcl's rules: how rclpy (Jazzy) reads ``--params-file`` and ``-p`` (no rclpy import).

So that the offline tools read a file exactly as the node does, and the settings' type
rule reads a string as rcl would (:func:`rcl_scalar`). Apart from
:mod:`~diffdrive_odom.settings.params` (the rows and their types), which imports it.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from diffdrive_odom.settings.errors import ParameterError

ParamValue = Any  # a parameter's value, typed as rcl types it

# What rclpy (Jazzy) does with ``--params-file`` and ``-p``, so that the offline tools
# read a file exactly as the node does:
#
# * every ``--params-file`` and every ``-p`` feeds ONE table of node entries, in
#   command-line order; ``-p name:=value`` is an entry of the node name ``/**``;
#   an entry keeps the place where its node name first appeared, and a later value
#   for the same entry and parameter overwrites the earlier one;
# * a node takes every entry whose name matches its fully qualified name, where a
#   leading ``/`` is implied, ``/*`` stands for one path element and ``/**`` for any
#   number of them (``/**``, ``/**/odometry_node``, ``/robot1/*``, ``odometry_node``);
# * the matching entries are merged in table order, later ones winning. So a node's
#   own section that comes after ``/**`` beats a ``-p`` (that is ``/**`` too), and a
#   ``/**`` section written after the node's section beats that section.
#
# Values are typed as rcl_yaml_param_parser types them (not as YAML 1.1 does): quoted
# or ``!!str`` = string; else y/yes/true/on (and capitalised forms) = true, ...;
# then a C integer (``0x1F``, ``017`` octal), then a C double (``5e-2``, ``.nan``);
# else a string. A list must hold one type; nested maps become dotted names.

ParamSource = tuple[str, str]
"""One ``--ros-args`` item that carries parameters: ``("file", path)`` or
``("param", "name:=value")``."""

_TRUE = {"Y", "y", "yes", "Yes", "YES", "true", "True", "TRUE", "on", "On", "ON"}
_FALSE = {"N", "n", "no", "No", "NO", "false", "False", "FALSE", "off", "Off", "OFF"}
_C_INT = re.compile(r"[+-]?(0[xX][0-9a-fA-F]+|0[0-7]*|[1-9][0-9]*)")
_C_DOUBLE = re.compile(
    r"[+-]?((\d+\.?\d*|\.\d+)([eE][+-]?\d+)?|(?i:inf|infinity|nan)|\.(nan|NaN|NAN|inf|Inf|INF))")
_STR_TAG = "tag:yaml.org,2002:str"
_PLAIN = "!diffdrive_odom/plain"


def rcl_scalar(text: str, typed: bool) -> ParamValue:
    """One scalar as rcl types it; ``typed`` is False for quoted / ``!!str`` ones."""
    if not typed:
        return text
    if not text:
        raise ValueError("no value")
    if text in _TRUE:
        return True
    if text in _FALSE:
        return False
    if _C_INT.fullmatch(text):
        number = int(text, 16) if text.lstrip("+-")[:2] in ("0x", "0X") else (
            int(text, 8) if text.lstrip("+-").startswith("0") else int(text))
        if -(2**63) <= number < 2**63:
            return number
    if _C_DOUBLE.fullmatch(text):
        return float(text.replace(".", "", 1) if text.lstrip("+-").startswith(".")
                     and text.lstrip("+-")[1:2].isalpha() else text)
    return text


def yaml_tree(text: str) -> Any:
    """Compose YAML keeping each scalar's style, so rcl's typing can be applied."""
    import yaml

    class _Loader(yaml.BaseLoader):
        def resolve(self, kind: Any, value: Any, implicit: Any) -> Any:
            if kind is yaml.ScalarNode and implicit[0]:
                return _PLAIN
            return super().resolve(kind, value, implicit)  # type: ignore[no-untyped-call]

    return yaml.compose(text, Loader=_Loader)


def rcl_value(node: Any, where: str) -> ParamValue:
    """A composed YAML node as an rcl parameter value (scalar or one-typed list)."""
    import yaml

    if isinstance(node, yaml.ScalarNode):
        typed = node.tag == _PLAIN or (node.tag == _STR_TAG and node.style in ("|", ">"))
        try:
            return rcl_scalar(node.value, typed)
        except ValueError as err:
            raise ParameterError(where, str(err)) from None
    if isinstance(node, yaml.SequenceNode):
        items = [rcl_value(item, where) for item in node.value]
        if any(isinstance(i, list) for i in items):
            raise ParameterError(where, "nested lists are not parameter values")
        if len({type(i) for i in items}) > 1:
            raise ParameterError(where, f"a list must hold one type (rcl), got {items!r}")
        return items
    raise ParameterError(where, "is a map where a value was expected")


def _collect_params(node: Any, prefix: str, out: dict[str, ParamValue]) -> None:
    import yaml

    for key, value in node.value:
        name = f"{prefix}{key.value}"
        if isinstance(value, yaml.MappingNode):
            _collect_params(value, name + ".", out)
        else:
            out[name] = rcl_value(value, name)


def _collect_nodes(node: Any, path: str, entries: dict[str, dict[str, ParamValue]]) -> None:
    import yaml

    for key, value in node.value:
        if not isinstance(value, yaml.MappingNode):
            continue
        if key.value == "ros__parameters":
            _collect_params(value, "", entries.setdefault(path, {}))
        else:
            _collect_nodes(value, f"{path}/{key.value}" if path else str(key.value), entries)


def parse_override(text: str) -> tuple[str, ParamValue]:
    """``name:=value`` of a ``-p`` as rcl reads it (the value is YAML, typed as above)."""
    import yaml

    name, sep, value = text.partition(":=")
    if not sep or not name:
        raise ParameterError("-p", f"expects NAME:=VALUE, got {text!r}")
    try:
        tree = yaml_tree(value)
    except yaml.YAMLError as err:
        raise ParameterError(name, f"unreadable -p value {value!r}: {_one_line(err)}") from None
    if tree is None:
        raise ParameterError(name, "-p without a value")
    return name, rcl_value(tree, name)


def _one_line(err: Exception) -> str:
    """PyYAML's multi-line message as one line: what it found, and where."""
    import yaml

    if isinstance(err, yaml.MarkedYAMLError) and err.problem_mark is not None:
        mark = err.problem_mark
        return f"{err.problem} (line {mark.line + 1}, column {mark.column + 1})"
    return " ".join(str(err).split())


def rcl_entries(sources: Sequence[ParamSource]) -> dict[str, dict[str, ParamValue]]:
    """The table rcl builds: node name -> parameters, in rcl's order."""
    import yaml

    entries: dict[str, dict[str, ParamValue]] = {}
    for kind, item in sources:
        if kind == "param":
            name, value = parse_override(item)
            entries.setdefault("/**", {})[name] = value
            continue
        with open(item, encoding="utf-8") as f:
            text = f.read()
        try:
            tree = yaml_tree(text)
        except yaml.YAMLError as err:
            raise ParameterError("--params-file", f"{item} is not YAML: {_one_line(err)}",
                                 ) from None
        if tree is None:
            continue
        if not isinstance(tree, yaml.MappingNode):
            raise ParameterError("--params-file", f"{item} is not a mapping")
        _collect_nodes(tree, "", entries)
    return entries


def node_matches(pattern: str, fqn: str) -> bool:
    """Tell whether an entry applies: leading ``/`` implied, ``/*`` = one element, ``/**`` = any."""
    name = pattern if pattern.startswith("/") else "/" + pattern
    try:
        return re.fullmatch(name.replace("/*", r"(/\w+)"), fqn) is not None
    except re.error:
        return False


def fully_qualified_name(node_name: str, namespace: str = "/") -> str:
    """``/ns/name`` as rcl forms it from a node name and a namespace."""
    ns = namespace.strip("/")
    return f"/{ns}/{node_name}" if ns else f"/{node_name}"


def resolve_parameters(
    sources: Sequence[ParamSource], node_name: str, namespace: str = "/"
) -> dict[str, ParamValue]:
    """The overrides rclpy gives the node ``namespace/node_name`` for these sources."""
    fqn = fully_qualified_name(node_name, namespace)
    merged: dict[str, ParamValue] = {}
    for pattern, values in rcl_entries(sources).items():
        if node_matches(pattern, fqn):
            merged.update(values)
    return merged


def load_params_file(
    path: str | Path, node_name: str, namespace: str = "/"
) -> dict[str, ParamValue]:
    """Parameters for ``node_name`` from one params YAML, as ``--params-file`` gives them."""
    return resolve_parameters([("file", str(path))], node_name, namespace)
