"""The parameter machinery every node's settings module builds on (no rclpy import).

Here: :class:`ParamSpec` (one row: name, type, default, one-line meaning, the
:class:`Range` that ``ros2 param describe`` shows, read-only), coercion, the type rule
of values given through ROS (:func:`as_declared_type`) and :func:`yaml_text`; how rcl
reads params files and ``-p`` is :mod:`~diffdrive_odom.settings.rcl`.
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
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

from diffdrive_odom.settings.errors import ParameterError, as_parameter_error
from diffdrive_odom.settings.rcl import ParamValue as ParamValue  # a parameter's value
from diffdrive_odom.settings.rcl import rcl_scalar, rcl_value, yaml_tree

if TYPE_CHECKING:
    from _typeshed import DataclassInstance


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
        value = rcl_scalar(text.strip(), True)
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
                value = rcl_value(yaml_tree(value), spec.name)
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
