"""The thin rclpy layer every node shares: parameters, QoS, stamps, ``main()``.

Kept apart from the pure core so that the core never imports rclpy, and kept in one
place so the three nodes refuse bad parameters, log bad input and exit on Ctrl-C in
exactly the same way.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Callable, Iterable, Sequence
from typing import Any, Generic, TypeVar

import rclpy
from diagnostic_msgs.msg import (
    DiagnosticArray,
    DiagnosticStatus,
    KeyValue,
)
from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
from rclpy.clock import Clock
from rclpy.clock_type import ClockType
from rclpy.executors import Executor, ExternalShutdownException, SingleThreadedExecutor
from rclpy.experimental import EventsExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    QoSProfile,
    ReliabilityPolicy,
)

from diffdrive_odom.diagnostics import Report
from diffdrive_odom.odometry import stamp_to_ns as stamp_to_ns  # re-exported
from diffdrive_odom.params import ParameterError, ParamSpec, ParamValue

T = TypeVar("T")

def qos(depth: int, reliable: bool) -> QoSProfile:
    """Keep-last, volatile QoS: the only knobs our topics differ in are depth and reliability."""
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=depth,
        reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
        durability=DurabilityPolicy.VOLATILE,
    )


# A best-effort subscriber matches reliable *and* best-effort publishers, so encoder
# drivers of either kind connect; the deep queue absorbs bursts (bag replay).
SENSOR_IN_QOS = qos(100, reliable=False)
# What Nav2 and robot_localization expect of odometry.
RELIABLE_OUT_QOS = qos(10, reliable=True)
TF_QOS = qos(100, reliable=True)

WARN_THROTTLE_S = 5.0


def ns_to_stamp(ns: int, msg: Any) -> Any:
    """Fill a builtin_interfaces/Time from integer nanoseconds; returns it."""
    msg.sec, msg.nanosec = divmod(int(ns), 1_000_000_000)
    return msg


def _param_value(param: Parameter) -> ParamValue:
    value = param.value
    # Sequences come back as array.array or lists; normalise to lists.
    if value is not None and not isinstance(value, (str, bytes, bool, int, float)):
        return list(value)
    return value


def declare(node: Node, specs: Iterable[ParamSpec]) -> dict[str, ParamValue]:
    """Declare every spec (dynamically typed: the spec coerces) and return raw values."""
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
        node.add_on_set_parameters_callback(self._validate)
        node.add_post_set_parameters_callback(self._post_set)

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


def run(node_factory: Callable[[], Node], args: Sequence[str] | None = None) -> int:
    """Init rclpy, build the node, spin until Ctrl-C; a bad parameter exits 2 with one line."""
    rclpy.init(args=list(args) if args is not None else sys.argv)
    node: Node | None = None
    try:
        try:
            executor, spin = make_executor()
            node = node_factory()
        except ParameterError as err:
            print(f"[{_program()}] {err}", file=sys.stderr)
            return 2
        executor.add_node(node)
        try:
            spin()
        except RuntimeError:
            # rclpy can raise from a half-torn-down wait set when SIGINT lands mid-take;
            # after shutdown that is the end of the run, not a fault to report.
            if rclpy.ok():
                raise
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return 0


EXECUTOR_ENV = "DIFFDRIVE_ODOM_EXECUTOR"


def make_executor(kind: str | None = None) -> tuple[Executor, Callable[[], None]]:
    """The executor and its spin loop: ``single`` (default) or ``events`` (opt-in).

    ``kind`` defaults to ``$DIFFDRIVE_ODOM_EXECUTOR``. rclpy's EventsExecutor costs
    less CPU per message, but its ``spin()`` is broken in the PyPI wheels (busy loop,
    delivers nothing), so it is driven by ``spin_once`` until shutdown.
    """
    kind = os.environ.get(EXECUTOR_ENV, "single") if kind is None else kind
    if kind == "single":
        single = SingleThreadedExecutor()
        return single, single.spin
    if kind == "events":
        events = EventsExecutor()

        def spin() -> None:
            while rclpy.ok():
                events.spin_once(timeout_sec=0.1)

        return events, spin
    raise ParameterError(EXECUTOR_ENV, f"environment variable must be 'single' or 'events', "
                         f"got {kind!r}")


def _program() -> str:
    import os

    return os.path.basename(sys.argv[0]) if sys.argv and sys.argv[0] else "diffdrive_odom"


# --- /diagnostics --------------------------------------------------------------------
# As ROS 2's diagnostic_updater: an absolute topic (one per robot, whatever the node's
# namespace), keep-last 1, reliable, volatile (its create_publisher(..., 1)).
DIAGNOSTICS_TOPIC = "/diagnostics"
DIAGNOSTICS_QOS = qos(1, reliable=True)
DIAGNOSTICS_PERIOD_S = 1.0


def diagnostic_status_name(node: Node, task: str) -> str:
    """``"<node>: <task>"`` as diagnostic_updater names a status.

    At the root namespace that is the bare node name (its default); in a namespace
    the fully qualified one (its ``diagnostic_updater.use_fqn``), so that two robots'
    nodes do not share a status name on the aggregator.
    """
    base = node.get_name() if node.get_namespace() == "/" else node.get_fully_qualified_name()
    return f"{base}: {task}"


class DiagnosticsPublisher:
    """Publishes ``report()`` as a one-status DiagnosticArray on /diagnostics at 1 Hz.

    The timer runs on the steady clock, like the wheel-command heartbeat, so a paused
    /clock (use_sim_time) does not silence the health report; the array is stamped
    from the node's clock, as diagnostic_updater stamps it. ``hardware_id`` "none" is
    diagnostic_updater's advice for a status that belongs to no device.
    """

    def __init__(
        self,
        node: Node,
        task: str,
        report: Callable[[], Report],
        hardware_id: str = "none",
        period_s: float = DIAGNOSTICS_PERIOD_S,
    ) -> None:
        self._node = node
        self._report = report
        self.name = diagnostic_status_name(node, task)
        self.hardware_id = hardware_id
        self._pub = node.create_publisher(DiagnosticArray, DIAGNOSTICS_TOPIC, DIAGNOSTICS_QOS)
        self._timer = node.create_timer(
            period_s, self.publish, clock=Clock(clock_type=ClockType.STEADY_TIME))

    def publish(self) -> None:
        """Publish the current report now (the timer calls this once a period)."""
        report = self._report()
        status = DiagnosticStatus()
        status.level = bytes([int(report.level)])
        status.name = self.name
        status.message = report.message
        status.hardware_id = self.hardware_id
        status.values = [KeyValue(key=k, value=v) for k, v in report.values]
        msg = DiagnosticArray()
        msg.header.stamp = self._node.get_clock().now().to_msg()
        msg.status = [status]
        self._pub.publish(msg)
