"""Parameter glue between rclpy and the settings layer: declare, read back, guard changes.

One place, so every node declares its table, reports stray overrides and refuses a bad
``ros2 param set`` in exactly the same way.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from typing import Any, Generic, TypeVar, cast

from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
from rclpy.node import Node
from rclpy.parameter import Parameter

from diffdrive_odom.settings.params import ParameterError, ParamSpec, ParamValue
from diffdrive_odom.settings.registry import unknown_parameters_report

T = TypeVar("T")


def _param_value(param: Parameter) -> ParamValue:
    value = param.value
    # Sequences come back as array.array or lists; normalise to lists.
    if value is not None and not isinstance(value, (str, bytes, bool, int, float)):
        return list(value)
    return value


def declare(node: Node, specs: Iterable[ParamSpec]) -> dict[str, ParamValue]:
    """Declare every spec (dynamically typed: the spec coerces) and return raw values.

    Also reports, once, the names given to this node (params files, ``-p``) that no
    node of this package knows: rclpy keeps such overrides silently.
    """
    report_unknown_overrides(node)
    values: dict[str, ParamValue] = {}
    for spec in specs:
        descriptor = ParameterDescriptor(
            description=spec.description,
            dynamic_typing=True,
            read_only=spec.read_only,
        )
        param = node.declare_parameter(spec.name, spec.default, descriptor)
        values[spec.name] = _param_value(param)
    return values


def parameter_values(node: Node, specs: Iterable[ParamSpec]) -> dict[str, ParamValue]:
    """The raw values of parameters already declared (a managed node reads them at configure)."""
    return {spec.name: _param_value(node.get_parameter(spec.name)) for spec in specs}


def report_unknown_overrides(node: Node) -> None:
    """Log unknown overrides (one warning) and ignored diff_drive_controller ones (one info).

    Typos get the closest real name.
    """
    # rclpy 7.1 has no public accessor for the overrides; the public alternative,
    # automatically_declare_parameters_from_overrides, would declare every stray name
    # as a parameter of the node (and collide with declare_parameter below).
    overrides = getattr(node, "_parameter_overrides", None) or {}
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
