"""Parameter glue between rclpy and the settings layer: declare, read back, guard changes.

One place, so every node declares its table, reports stray overrides and refuses a bad
``ros2 param set`` in exactly the same way. Parameters are what ROS users know from
generate_parameter_library: each declared with a descriptor holding its description,
its type fixed (a set cannot change it), its range where one is true (``ros2 param
describe`` shows it) and read-only where a runtime change is not supported.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from typing import Any, Generic, TypeVar, cast

from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    SetParametersResult,
)
from rclpy.exceptions import ParameterNotDeclaredException
from rclpy.node import Node
from rclpy.parameter import Parameter

from diffdrive_odom.settings.errors import ParameterError
from diffdrive_odom.settings.params import (
    ParamSpec,
    ParamValue,
    as_declared_type,
)
from diffdrive_odom.settings.registry import unknown_name_hint, unknown_parameters_report

T = TypeVar("T")

ROS_TYPE = {
    "double": Parameter.Type.DOUBLE,
    "integer": Parameter.Type.INTEGER,
    "bool": Parameter.Type.BOOL,
    "string": Parameter.Type.STRING,
    "string_array": Parameter.Type.STRING_ARRAY,
    "double_array": Parameter.Type.DOUBLE_ARRAY,
}


def _param_value(param: Parameter) -> ParamValue:
    value = param.value
    # Sequences come back as array.array or lists; normalise to lists.
    if value is not None and not isinstance(value, (str, bytes, bool, int, float)):
        return list(value)
    return value


def descriptor(spec: ParamSpec) -> ParameterDescriptor:
    """What ``ros2 param describe`` shows: meaning, fixed type, range and its rule, read-only."""
    d = ParameterDescriptor(
        description=spec.description,
        type=ROS_TYPE[spec.kind].value,
        dynamic_typing=False,
        read_only=spec.read_only,
    )
    r = spec.range
    if r is not None:
        d.additional_constraints = r.rule
        if spec.kind == "double":
            d.floating_point_range = [FloatingPointRange(
                from_value=float(r.low), to_value=float(r.high), step=0.0)]
        elif spec.kind == "integer":
            d.integer_range = [IntegerRange(
                from_value=int(r.low), to_value=int(r.high), step=r.step)]
    return d


class UnknownParameter(ParameterNotDeclaredException):
    """A set of a name the node does not have: the reason names the closest real one.

    rclpy's own message is ``Invalid access to undeclared parameter(s): []`` (7.1 lists
    the names from a generator it has already used up). A subclass, so rclpy's
    parameter service still turns it into the refused set's reason.
    """

    def __init__(self, node_name: str, names: Sequence[str], declared: Iterable[str]) -> None:
        known = list(declared)
        parts = []
        for name in names:
            hint = unknown_name_hint(name, known)
            parts.append(f"'{name}'" + (f" ({hint})" if hint else ""))
        Exception.__init__(self, f"{node_name} has no parameter " + ", ".join(parts))


def declare(
    node: Node,
    specs: Iterable[ParamSpec],
    refused: dict[str, ParameterError] | None = None,
) -> dict[str, ParamValue]:
    """Declare every spec (its type fixed, see :func:`descriptor`) and return the values.

    A value given at start (params file, ``-p``) is converted to the declared type
    first (``-p wheel_radius:=1``, see ``as_declared_type``); rclpy does not, and would
    raise a traceback out of ``declare_parameter``. One that cannot be held (a string for
    a number, outside the range) raises ParameterError (the node stops with one line),
    or, with ``refused`` (a managed node: it must start so that the value can be
    fixed), is recorded there and the parameter keeps its default.

    Registers the node's one pre-set callback (:func:`convert_on_set`) and reports,
    once, the names given to this node that no node of this package knows.
    """
    # rclpy 7.1 has no public accessor for the overrides; the public alternative,
    # automatically_declare_parameters_from_overrides, would declare every stray name
    # as a parameter of the node (and collide with declare_parameter below).
    overrides = getattr(node, "_parameter_overrides", None) or {}
    report_unknown_overrides(node, overrides)
    specs = tuple(specs)
    values: dict[str, ParamValue] = {}
    for spec in specs:
        value = spec.default
        if spec.name in overrides:
            try:
                value = spec.admit(overrides[spec.name].value)
            except ParameterError as err:
                if refused is None:
                    raise
                refused[spec.name] = err
        param = node.declare_parameter(spec.name, value, descriptor(spec), ignore_override=True)
        values[spec.name] = _param_value(param)
    node.add_pre_set_parameters_callback(convert_on_set(node, specs))
    return values


def convert_on_set(node: Node, specs: Iterable[ParamSpec]) -> Callable[
        [list[Parameter]], list[Parameter]]:
    """The node's pre-set callback: types converted, unknown names refused with a hint.

    A value in another type with the same meaning becomes the declared one (``ros2 param
    set /odometry_node wheel_radius 1``, the strings of ``ros2 param load``); a name the
    node does not have raises :class:`UnknownParameter`.

    rclpy calls it before it checks names, types and ranges (a node has only one: rclpy
    concatenates what several return).
    """
    by_name = {s.name: s for s in specs}

    def convert(params: list[Parameter]) -> list[Parameter]:
        unknown = [p.name for p in params if not node.has_parameter(p.name)]
        if unknown:
            declared = node.list_parameters([], 0).names  # depth 0: every name
            raise UnknownParameter(node.get_name(), unknown, declared)
        out = []
        for p in params:
            spec = by_name.get(p.name)
            if spec is not None and p.type_ != Parameter.Type.NOT_SET:
                value = as_declared_type(spec, _param_value(p))
                if ROS_TYPE[spec.kind].check(value):
                    p = Parameter(p.name, ROS_TYPE[spec.kind], value)
            out.append(p)
        return out

    return convert


def parameter_values(node: Node, specs: Iterable[ParamSpec]) -> dict[str, ParamValue]:
    """The raw values of parameters already declared (a managed node reads them at configure)."""
    return {spec.name: _param_value(node.get_parameter(spec.name)) for spec in specs}


def report_unknown_overrides(node: Node, overrides: Iterable[str]) -> None:
    """Log unknown ``overrides`` (one warning) and ignored diff_drive_controller ones (one info).

    Typos get the closest real name.
    """
    warning, info = unknown_parameters_report(list(overrides))
    log: Any = cast(Any, node).get_logger()
    if warning:
        log.warning(warning)
    if info:
        log.info(info)


class ParameterGuard(Generic[T]):
    """Validates parameter changes at runtime and applies the accepted ones.

    ``build`` turns the full set of raw values into validated settings (raising
    ParameterError); ``apply`` installs them. A refused change leaves the node as it
    was and tells the caller why, as ``ros2 param set`` prints.
    """

    def __init__(
        self,
        node: Node,
        values: dict[str, ParamValue],
        build: Callable[[dict[str, ParamValue]], T],
        apply: Callable[[T], None],
    ) -> None:
        self._values = dict(values)
        self._build = build
        self._apply = apply
        self._pending: tuple[dict[str, ParamValue], T] | None = None
        self._node = node
        node.add_on_set_parameters_callback(self._validate)
        node.add_post_set_parameters_callback(self._post_set)

    def close(self) -> None:
        """Stop guarding (a managed node's cleanup: unconfigured, any value is taken)."""
        self._node.remove_on_set_parameters_callback(self._validate)
        self._node.remove_post_set_parameters_callback(self._post_set)

    def _validate(self, params: Sequence[Parameter]) -> SetParametersResult:
        candidate = dict(self._values)
        for p in params:
            if p.name in candidate:
                candidate[p.name] = _param_value(p)
        try:
            settings = self._build(candidate)
        except ParameterError as err:
            self._pending = None
            return SetParametersResult(successful=False, reason=str(err))
        self._pending = (candidate, settings)
        return SetParametersResult(successful=True)

    def _post_set(self, params: Sequence[Parameter]) -> None:
        if self._pending is not None:
            self._values, settings = self._pending
            self._pending = None
            self._apply(settings)
