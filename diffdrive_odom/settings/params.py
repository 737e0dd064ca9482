"""The parameter machinery every node's settings module builds on (no rclpy import).

Here: :class:`ParamSpec` (one row: name, type, default, one-line meaning, the
:class:`Range` that ``ros2 param describe`` shows, read-only), coercion, the type rule
of values given through ROS (:func:`as_declared_type`), params-file and ``-p``
resolution exactly as rcl does it, the report of unknown names and :func:`yaml_text`.
The tables themselves live with their node, one settings module each
(``geometry_settings``: the rows every node shares; ``odometry_settings``,
``cmd_vel_settings``, ``sim_settings``, ``follower_settings``). One table serves four
readers: the node (declare + validate), the offline tools (same params YAML),
``config/diffdrive_odom.yaml`` and the documentation's parameter tables. The nodes declare
every parameter with its type fixed, as generate_parameter_library does; the rule of
:func:`as_declared_type` turns what ROS hands over in another type but with the same
meaning (``-p wheel_radius:=1`` is an integer) into the declared type first.
"""

from __future__ import annotations

import dataclasses
import json
import math
import re
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

from diffdrive_odom.settings.errors import ParameterError, as_parameter_error

if TYPE_CHECKING:
    from _typeshed import DataclassInstance

ParamValue = Any

# Ships with the package: the example robot (the demo's), valid for every node, so the
# demo runs and `--help` can build a node without a file of the user's.
EXAMPLE_PARAMS_FILE = Path(__file__).resolve().parent.parent / "data" / "demo_params.yaml"


def _quoted(value: ParamValue) -> str:
    """The hint for a number or a list given as a string (``wheel_radius: "0.033"``), else ''."""
    if isinstance(value, str) and (_number_text(value) is not None
                                   or value.strip().startswith("[")):
        return f" (quoted, so a string: write {value} without quotes)"
    return ""


def _as_float(name: str, value: ParamValue) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ParameterError(name, f"must be a number, got {value!r}{_quoted(value)}")
    return float(value)


def _as_int(name: str, value: ParamValue) -> int:
    if isinstance(value, bool):
        raise ParameterError(name, f"must be an integer, got {value!r}")
    if isinstance(value, float) and value.is_integer():
        return int(value)
    if not isinstance(value, int):
        raise ParameterError(name, f"must be an integer, got {value!r}{_quoted(value)}")
    return value


def _as_bool(name: str, value: ParamValue) -> bool:
    if not isinstance(value, bool):
        raise ParameterError(name, f"must be true or false, got {value!r}")
    return value


def _as_str(name: str, value: ParamValue) -> str:
    if isinstance(value, bool):  # YAML 1.1 and ``-p`` read off/on/no/yes as a boolean
        raise ParameterError(name, f"must be a string, got {value!r} (off, on, no and yes "
                                   "are read as booleans: quote the value)")
    if not isinstance(value, str):
        raise ParameterError(name, f"must be a string, got {value!r}")
    return value


def _as_str_list(name: str, value: ParamValue) -> tuple[str, ...]:
    if isinstance(value, str) or not isinstance(value, Iterable):
        raise ParameterError(name, f"must be a list of strings, got {value!r}")
    items = tuple(value)
    if not all(isinstance(v, str) for v in items):
        raise ParameterError(name, f"must be a list of strings, got {value!r}")
    return items


def _as_float_list(name: str, value: ParamValue) -> tuple[float, ...]:
    if isinstance(value, str) or not isinstance(value, Iterable):
        raise ParameterError(name, f"must be a list of numbers, got {value!r}{_quoted(value)}")
    return tuple(_as_float(name, v) for v in value)


COERCE: dict[str, Callable[[str, ParamValue], ParamValue]] = {
    "double": _as_float,
    "integer": _as_int,
    "bool": _as_bool,
    "string": _as_str,
    "string_array": _as_str_list,
    "double_array": _as_float_list,
}


INT64_MAX = 2**63 - 1


@dataclass(frozen=True)
class Range:
    """The closed range ``[low, high]`` a value lies in, as ROS describes one.

    The node puts it in the parameter's descriptor (FloatingPointRange / IntegerRange):
    ``ros2 param describe`` shows it and rclpy refuses a value outside it before any
    callback runs. ROS ranges are closed and know no "finite", so where the rule is
    stricter (``> 0``, finite) ``rule`` says it in words (the descriptor's
    additional_constraints) and the settings validation enforces it. A range is only
    written where it is true: every value it excludes the validation refuses too.
    ``step`` is for integer ranges (2 with ``[-1, 1]``: -1 or 1).
    """

    low: float
    high: float
    rule: str = ""
    step: int = 0

    def holds(self, value: float) -> bool:
        """Tell whether ``value`` is in the closed range (and on a step); NaN is not."""
        if not self.low <= value <= self.high:
            return False
        return self.step == 0 or (value - self.low) % self.step == 0

    def text(self) -> str:
        """``[low, high]`` and the rule, for a message."""
        return f"in [{self.low:g}, {self.high:g}]" + (f" ({self.rule})" if self.rule else "")


INF = math.inf
POSITIVE = Range(0.0, INF, "> 0, finite")
POSITIVE_OR_INF = Range(0.0, INF, "> 0; .inf allowed")
NON_NEGATIVE = Range(0.0, INF, "finite")
SIGN = Range(-1, 1, "-1 or 1", step=2)
AT_LEAST_ONE = Range(1, INT64_MAX)
COUNTER_BITS = Range(0, 64)


@dataclass(frozen=True)
class ParamSpec:
    """One parameter: name, kind (a key of ``COERCE``), default and one-line meaning.

    ``range``: the closed range ROS is told about, where one is true; ``read_only``:
    a runtime change is not supported (the node would have to be rebuilt).
    """

    name: str
    kind: str
    default: ParamValue
    description: str
    read_only: bool = False
    range: Range | None = None

    def coerce(self, value: ParamValue) -> ParamValue:
        """The value in this parameter's Python type, or ParameterError."""
        return COERCE[self.kind](self.name, value)

    def admit(self, value: ParamValue) -> ParamValue:
        """A value given at start, as the node declares it, or ParameterError.

        Converted to the declared type (:func:`as_declared_type`, but a string stays a
        string: rcl typed the value, and a quoted number is refused as rclpy's
        ``declare_parameter`` refuses it), typed and inside :attr:`range`; else the error
        names the parameter (rclpy would raise a traceback).
        """
        typed = self.coerce(as_declared_type(self, value, strings=False))
        if self.range is not None and not self.range.holds(typed):
            raise ParameterError(self.name, f"must be {self.range.text()}, got {typed!r}")
        return list(typed) if isinstance(typed, tuple) else typed


def _number_text(text: str) -> float | None:
    """The number rcl's params-file reader makes of ``text``, else None."""
    try:
        value = _rcl_scalar(text.strip(), True)
    except ValueError:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    return float(value)


def _as_double(value: ParamValue) -> ParamValue:
    if isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    if isinstance(value, str):
        number = _number_text(value)
        return value if number is None else number
    return value


def as_declared_type(spec: ParamSpec, value: ParamValue, strings: bool = True) -> ParamValue:
    """``value`` in the type ``spec`` declares, when it came in another with the same meaning.

    Else ``value`` unchanged (rclpy then refuses the type, naming both).
    * An integer for a double, and integers in a double list: ``ros2 param set /node
      wheel_radius 1``, ``-p wheel_radius:=1`` and a YAML ``1`` all arrive as INTEGER.
    * An integral double for an integer (``16.0`` counter bits), as :meth:`ParamSpec.coerce`.
    * For a double or a double list, a string that is a number as rcl reads one
      (``1e-05``, ``nan``, ``-inf``): ``ros2 param load`` (rclpy's
      ``parameter_dict_from_yaml_file``) re-reads each value of the file as
      ``yaml.safe_load(str(value))``, and YAML 1.1 takes ``str(1e-05)`` = ``'1e-05'``
      (no dot) and ``'nan'`` for strings, so a node's own dump would not load back. A
      list with such an item arrives as one string, ``'[0.001, 1e-06]'``. Only at
      runtime: ``strings`` False (at start, where rcl typed what the user wrote) leaves
      a string as it is.
    * For a list, no value: an empty list (``-p left_wheel_names:=[]``, ``[]`` in a file)
      has no element type, so rcl gives it none and rclpy hands it over as None.
    """
    if value is None and spec.kind.endswith("_array"):
        return []
    if isinstance(value, str) and not strings:
        return value
    if spec.kind == "double":
        return _as_double(value)
    if spec.kind == "integer" and isinstance(value, float) and value.is_integer():
        return int(value)
    if spec.kind == "double_array":
        if isinstance(value, str):
            import yaml

            try:
                value = _rcl_value(_yaml_tree(value), spec.name)
            except (ParameterError, yaml.YAMLError):  # not a value rcl reads: left to rclpy
                return value
        if isinstance(value, (list, tuple)):
            items = [_as_double(v) for v in value]
            if all(isinstance(v, float) for v in items):
                return items
    return value


def defaults(specs: Iterable[ParamSpec]) -> dict[str, ParamValue]:
    """``{name: default}`` for a set of specs."""
    return {s.name: s.default for s in specs}


def coerce_all(specs: Iterable[ParamSpec], values: Mapping[str, ParamValue]) -> dict[str, Any]:
    """Every spec's value from ``values`` (default where absent), typed; ParameterError if not."""
    return {s.name: s.coerce(values.get(s.name, s.default)) for s in specs}


C = TypeVar("C", bound="DataclassInstance")


def from_fields(cls: type[C], v: Mapping[str, Any], prefix: str = "") -> C:
    """A core config whose every field is the parameter ``prefix + field``, from coerced values.

    For the configs named as their parameters (Geometry, the estimator's, the follower's
    gains); a ConfigError becomes the ParameterError naming that parameter.
    """
    with as_parameter_error(prefix):
        return cls(**{f.name: v[prefix + f.name] for f in dataclasses.fields(cls)})


# ------------------------------------------------------------------ rcl's rules
#
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


def _rcl_scalar(text: str, typed: bool) -> ParamValue:
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


def _yaml_tree(text: str) -> Any:
    """Compose YAML keeping each scalar's style, so rcl's typing can be applied."""
    import yaml

    class _Loader(yaml.BaseLoader):
        def resolve(self, kind: Any, value: Any, implicit: Any) -> Any:
            if kind is yaml.ScalarNode and implicit[0]:
                return _PLAIN
            return super().resolve(kind, value, implicit)  # type: ignore[no-untyped-call]

    return yaml.compose(text, Loader=_Loader)


def _rcl_value(node: Any, where: str) -> ParamValue:
    """A composed YAML node as an rcl parameter value (scalar or one-typed list)."""
    import yaml

    if isinstance(node, yaml.ScalarNode):
        typed = node.tag == _PLAIN or (node.tag == _STR_TAG and node.style in ("|", ">"))
        try:
            return _rcl_scalar(node.value, typed)
        except ValueError as err:
            raise ParameterError(where, str(err)) from None
    if isinstance(node, yaml.SequenceNode):
        items = [_rcl_value(item, where) for item in node.value]
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
            out[name] = _rcl_value(value, name)


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
        tree = _yaml_tree(value)
    except yaml.YAMLError as err:
        raise ParameterError(name, f"unreadable -p value {value!r}: {err}") from None
    if tree is None:
        raise ParameterError(name, "-p without a value")
    return name, _rcl_value(tree, name)


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
            tree = _yaml_tree(text)
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


def yaml_text(value: object) -> str:
    """YAML 1.1 text that both rcl's parser and PyYAML read back as the same type."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        if value != value:
            return ".nan"
        if value in (float("inf"), float("-inf")):
            return ".inf" if value > 0 else "-.inf"
        mantissa, _, exponent = repr(value).partition("e")
        if "." not in mantissa:
            mantissa += ".0"
        return mantissa + (f"e{exponent}" if exponent else "")
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(yaml_text(v) for v in value) + "]"
    return json.dumps(value)
