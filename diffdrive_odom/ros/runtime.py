"""The thin rclpy layer every node shares: parameters, QoS, stamps, ``main()``.

Kept apart from the pure core so that the core never imports rclpy, and kept in one
place so the three nodes refuse bad parameters, log bad input and exit on Ctrl-C in
exactly the same way.
"""

from __future__ import annotations

import itertools
import os
import signal
import sys
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Any, Generic, TypeVar, cast

import rclpy
from diagnostic_msgs.msg import (
    DiagnosticArray,
    DiagnosticStatus,
    KeyValue,
)
from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
from rclpy.clock import Clock
from rclpy.clock_type import ClockType
from rclpy.context import Context
from rclpy.executors import Executor, ExternalShutdownException, SingleThreadedExecutor
from rclpy.experimental import EventsExecutor
from rclpy.lifecycle import LifecycleNode
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.publisher import Publisher
from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    QoSProfile,
    ReliabilityPolicy,
)

from diffdrive_odom.core.conversions import stamp_to_ns as stamp_to_ns  # re-exported
from diffdrive_odom.core.diagnostics import Report
from diffdrive_odom.settings.params import (
    EXAMPLE_PARAMS_FILE,
    ParameterError,
    ParamSpec,
    ParamValue,
)
from diffdrive_odom.settings.registry import unknown_parameters_report

T = TypeVar("T")

def qos(depth: int, reliable: bool, latched: bool = False) -> QoSProfile:
    """Keep-last QoS: our topics differ only in depth, reliability and (``/tf_static``) latching.

    ``latched`` is transient-local durability: a late subscriber still gets the last
    messages, as ``/tf_static`` requires; every other topic is volatile.
    """
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=depth,
        reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
        durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE,
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


def create_publisher(node: Node, msg_type: Any, topic: str, qos_profile: QoSProfile) -> Publisher:
    """A publisher; on a managed node a lifecycle one, so it publishes only while active."""
    if isinstance(node, LifecycleNode):
        return cast(Publisher, node.create_lifecycle_publisher(msg_type, topic, qos_profile))
    return node.create_publisher(msg_type, topic, qos_profile)


def destroy_publisher(node: Node, publisher: Publisher) -> None:
    """Undo :func:`create_publisher` (a managed node also forgets the managed entity)."""
    if isinstance(node, LifecycleNode):
        node.destroy_lifecycle_publisher(publisher)
    else:
        node.destroy_publisher(publisher)


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


def run(node_factory: Callable[[], Node], args: Sequence[str] | None = None) -> int:
    """Init rclpy, build the node, spin until SIGINT/SIGTERM; a bad start exits 2 with one line.

    Before rclpy sees the command line: ``--help`` prints :func:`usage` (exit 0);
    arguments outside ``--ros-args`` and a missing ``--params-file`` are named with
    the right form (exit 2), because rclpy would ignore the first and die with a
    traceback on the second; any other error of rcl's start is one line too.

    A stop signal ends the process within :data:`SPIN_TIMEOUT_S` plus teardown, exit 0
    (see :class:`_StopSignals` for why rclpy alone does not guarantee that).
    """
    argv = list(args) if args is not None else list(sys.argv)
    problem = _check_command_line(argv)
    if problem == "--help":
        print(usage(node_factory, argv))
        return 0
    if problem is not None:
        print(f"[{_program()}] {problem}", file=sys.stderr)
        return 2
    stop = _StopSignals()  # before rclpy.init, so that rclpy's handlers chain to it
    try:
        rclpy.init(args=argv)
    except Exception as err:  # rclpy's RCLError: an unreadable params file, a bad remap
        print(f"[{_program()}] cannot start: {_first_line(err)}", file=sys.stderr)
        return 2
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
            spin(lambda: stop.requested)
        except RuntimeError:
            # rclpy can raise from a half-torn-down wait set when the signal lands
            # mid-take; after shutdown that is the end of the run, not a fault to report.
            if rclpy.ok() and not stop.requested:
                raise
    except KeyboardInterrupt:  # a second signal while stopping
        pass
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return 0


# Longest a spin waits before looking at the context again: the bound on how late a
# stop signal ends the process (teardown comes on top).
SPIN_TIMEOUT_S = 0.1


class _StopSignals:
    """SIGINT and SIGTERM as a stop request the spin loop sees, never an exception.

    rclpy's own handlers (installed by ``rclpy.init``) trigger the executors' signal
    guard condition and then shut the context down from another thread. A wait that
    took the guard's trigger just before the shutdown leaves the next wait with
    nothing to wake it, so a wait without a timeout blocks until some timer or
    message comes: the spin loop therefore waits at most SPIN_TIMEOUT_S and checks
    ``rclpy.ok()`` and this flag. rclpy then calls the handler found before it, which
    for SIGINT is Python's: its KeyboardInterrupt can land anywhere, even inside the
    teardown (exit 1, traceback); this handler replaces it. A second signal still
    ends a stuck process at once.
    """

    def __init__(self) -> None:
        self.requested = False
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, self._on_signal)

    def _on_signal(self, signum: int, frame: Any) -> None:
        if self.requested:
            raise KeyboardInterrupt
        self.requested = True


def _first_line(err: BaseException) -> str:
    """The message of an rcl error without its C source locations (", at parser.c:271")."""
    text = str(err).strip()
    line = text.splitlines()[0] if text else type(err).__name__
    return line.split(", at /")[0]


def _split_ros_args(argv: Sequence[str]) -> tuple[list[str], list[str]]:
    """(inside, outside) the ``--ros-args ... [--]`` blocks, program name excluded.

    rclpy's ``remove_ros_args`` would also drop a bare ``name:=value`` outside the
    blocks (rcl's deprecated remap syntax), hiding exactly the mistake of a parameter
    given without ``--ros-args``; so the split is done here, by rcl's block rule.
    """
    inside: list[str] = []
    outside: list[str] = []
    in_block = False
    for a in argv[1:]:
        if a == "--ros-args":
            in_block = True
        elif a == "--" and in_block:
            in_block = False
        else:
            (inside if in_block else outside).append(a)
    return inside, outside


def _ros_args(argv: Sequence[str]) -> list[str]:
    return _split_ros_args(argv)[0]


_ROS_FLAGS = ("-p", "--param", "-r", "--remap", "--params-file", "--log-level", "-e", "--enclave")


def _check_command_line(argv: Sequence[str]) -> str | None:
    """``"--help"``, a one-line reason the command line cannot work, or None."""
    program = _program()
    ros, rest = _split_ros_args(argv)
    for flag, value in itertools.pairwise(ros):
        if flag == "--params-file":
            path = Path(value)
            if not path.is_file():
                return f"--params-file {value}: no such file"
            if not os.access(path, os.R_OK):
                return f"--params-file {value}: not readable"
    if any(a in ("-h", "--help") for a in rest):
        return "--help"
    if not rest:
        return None
    given = " ".join(rest)
    if all(a.startswith(_ROS_FLAGS) or ":=" in a or (i and rest[i - 1] in _ROS_FLAGS)
           for i, a in enumerate(rest)):
        fixed = " ".join(f"-p {a}" if ":=" in a and (not i or rest[i - 1] not in _ROS_FLAGS)
                         else a for i, a in enumerate(rest))
        return (f"'{given}' must follow --ros-args: `{program} --ros-args {fixed}` "
                f"(see `{program} --help`)")
    return (f"unexpected argument(s) '{given}': {program} takes its settings as ROS "
            f"parameters after --ros-args, e.g. `{program} --ros-args --params-file FILE "
            f"-p NAME:=VALUE` (see `{program} --help`)")


def usage(node_factory: Callable[[], Node], argv: Sequence[str] = ()) -> str:
    """``--help`` text: what the node does, its topics and services, where parameters go.

    The topics come from building the node (demo parameters, then the user's own ROS
    arguments, so remaps and namespaces show) and asking it, never from a hand-kept
    list that could drift from the code.
    """
    program = _program()
    module = sys.modules.get(node_factory.__module__)
    summary = ((module.__doc__ if module else None) or "").strip().split("\n\n")[0]
    lines = [
        f"usage: {program} [--help] [--ros-args [--params-file FILE] [-p NAME:=VALUE ...] "
        "[-r FROM:=TO ...]]",
        "",
        " ".join(summary.replace("``", "").split()),
        "",
    ]
    endpoints = _endpoints(node_factory, argv)
    if endpoints:
        lines.append("topics and services (with the example parameters and your ROS arguments):")
        width = max(len(name) for _, name, _ in endpoints)
        lines += [f"  {kind:<11s} {name:<{width}s}  {kind_type}"
                  for kind, name, kind_type in endpoints]
        lines.append("")
    lines += [
        "Parameters, remaps and the namespace go after --ros-args, as for every ROS 2 node:",
        f"  {program} --ros-args --params-file my_robot.yaml -p wheel_radius:=0.033 "
        "-r __ns:=/robot1",
        "Every parameter, its default and meaning: config/diffdrive_odom.yaml (installed in",
        f"share/diffdrive_odom/config) and the '{program}' section of the package's README.md.",
    ]
    return "\n".join(lines)


def _type_name(cls: Any, kind: str) -> str:
    return f"{cls.__module__.split('.')[0]}/{kind}/{cls.__name__}"


def _endpoints(
    node_factory: Callable[[], Node], argv: Sequence[str]
) -> list[tuple[str, str, str]]:
    """(direction, name, type) of what the node creates; empty if it cannot be built.

    Uses the default context and shuts it down again: ``--help`` ends the process.
    """
    ros = ["--ros-args", "--log-level", "fatal", "--params-file", str(EXAMPLE_PARAMS_FILE)]
    try:
        rclpy.init(args=[_program(), *ros, *_ros_args(argv)])
    except Exception:
        return []
    try:
        node = node_factory()
    except Exception:  # a user's -p that cannot work: the usage text still helps
        rclpy.try_shutdown()
        return []
    try:
        if isinstance(node, LifecycleNode):  # a managed node creates its endpoints then
            node.trigger_configure()
        ours = [("subscribes", s.topic_name, _type_name(s.msg_type, "msg"))
                for s in node.subscriptions]
        ours += [("publishes", p.topic_name, _type_name(p.msg_type, "msg"))
                 for p in node.publishers]
        ours += [("service", node.resolve_service_name(s.srv_name),
                  _type_name(s.srv_type, "srv")) for s in node.services]
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    infrastructure = ("rcl_interfaces/", "type_description_interfaces/")
    return [e for e in ours if not e[2].startswith(infrastructure)]


EXECUTOR_ENV = "DIFFDRIVE_ODOM_EXECUTOR"


Spin = Callable[[Callable[[], bool]], None]


EXECUTOR_KINDS = ("events", "single")  # the default first


def make_executor(
    kind: str | None = None, context: Context | None = None
) -> tuple[Executor, Spin]:
    """The executor and its spin loop: ``events`` (default) or ``single``.

    ``kind`` defaults to ``$DIFFDRIVE_ODOM_EXECUTOR``. rclpy's EventsExecutor costs
    about half the CPU per message of the SingleThreadedExecutor, whose Python code
    rebuilds the wait set for every message (bench/bench_live.py measures both); the
    single one stays selectable as the conservative fallback. The EventsExecutor's
    ``spin()`` is broken in the PyPI wheels (busy loop, delivers nothing): both are
    driven by ``spin_once`` with a bounded wait until shutdown of ``context``
    (rclpy's default one if None) or until ``stop()`` is true (see
    :class:`_StopSignals` for why bounded).
    """
    kind = os.environ.get(EXECUTOR_ENV, "events") if kind is None else kind
    executor: Executor
    if kind == "single":
        executor = SingleThreadedExecutor(context=context)
    elif kind == "events":
        executor = EventsExecutor(context=context)
    else:
        raise ParameterError(EXECUTOR_ENV, f"environment variable must be 'single' or "
                             f"'events', got {kind!r}")

    def spin(stop: Callable[[], bool] = lambda: False) -> None:
        try:
            while rclpy.ok(context=context) and not stop():
                executor.spin_once(timeout_sec=SPIN_TIMEOUT_S)
        except ExternalShutdownException:  # shut down during the wait: the end, not a fault
            pass

    return executor, spin


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
        self._pub = create_publisher(node, DiagnosticArray, DIAGNOSTICS_TOPIC, DIAGNOSTICS_QOS)
        self._timer = node.create_timer(
            period_s, self.publish, clock=Clock(clock_type=ClockType.STEADY_TIME))

    def destroy(self) -> None:
        """Remove the publisher and its timer from the node."""
        self._node.destroy_timer(self._timer)
        destroy_publisher(self._node, self._pub)

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


class KeyedThrottle:
    """One throttle per key: the first line of each key at once, then one per period.

    rclpy's ``throttle_duration_sec`` is keyed by call site, so when every reason is
    logged from one place a frequent reason hides a rare one. Lines held back are
    counted and the count rides on the next line of that key.
    """

    def __init__(
        self,
        logger: Any,
        period_s: float = WARN_THROTTLE_S,
        clock: Callable[[], float] | None = None,
    ) -> None:
        import time

        self._logger = logger
        self._period = period_s
        self._clock = clock if clock is not None else time.monotonic
        self._last: dict[str, float] = {}
        self._held: dict[str, int] = {}

    def warning(self, key: str, text: str) -> bool:
        """Log ``text`` as a warning unless ``key`` was logged within the period."""
        line = self._admit(key, text)
        if line is not None:
            self._logger.warning(line)  # its own call site: see _admit
        return line is not None

    def info(self, key: str, text: str) -> bool:
        """Log ``text`` as info unless ``key`` was logged within the period."""
        line = self._admit(key, text)
        if line is not None:
            self._logger.info(line)
        return line is not None

    def _admit(self, key: str, text: str) -> str | None:
        """The line to log now, or None if held back.

        The caller logs it: rclpy's logger refuses a call site that logs at two
        severities ("Logger severity cannot be changed between calls", a ValueError
        that would end the node), so info and warning lines never share one.
        """
        now = self._clock()
        last = self._last.get(key)
        if last is not None and now - last < self._period:
            self._held[key] = self._held.get(key, 0) + 1
            return None
        self._last[key] = now
        held = self._held.pop(key, 0)
        return f"{text} ({held} more like this since the last report)" if held else text
