"""How every node process starts and ends: ``main()``, command-line checks, ``--help``, executors.

Kept in one place so the nodes refuse a bad command line, print their usage and exit on
Ctrl-C, SIGTERM or SIGHUP, and with the process that started them (:mod:`.lifetime`), in
exactly the same way (rclpy alone does none of these reliably).
"""

from __future__ import annotations

import contextlib
import itertools
import os
import signal
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import rclpy
from rclpy.context import Context
from rclpy.executors import Executor, ExternalShutdownException, SingleThreadedExecutor
from rclpy.experimental import EventsExecutor
from rclpy.lifecycle import LifecycleNode
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions

from diffdrive_odom.settings.dependencies import missing_text
from diffdrive_odom.settings.errors import ParameterError
from diffdrive_odom.settings.params import EXAMPLE_PARAMS_FILE
from diffdrive_odom.settings.rcl import ParamSource
from diffdrive_odom.settings.shadowed import shadowed_overrides_line

from . import lifetime, lockstep


def run(node_factory: Callable[[], Node], args: Sequence[str] | None = None) -> int:
    """Init rclpy, build the node, spin until a stop signal; a bad start exits 2 with one line.

    Before rclpy sees the command line: ``--help`` prints :func:`usage` (exit 0);
    arguments outside ``--ros-args`` and a missing ``--params-file`` are named with
    the right form (exit 2), because rclpy would ignore the first and die with a
    traceback on the second; any other error of rcl's start is one line too.

    A stop signal ends the process within :data:`SPIN_TIMEOUT_S` plus teardown, exit 0,
    also when more follow during the stop, as under ``ros2 launch`` (see
    :class:`_StopSignals` for why rclpy alone does not guarantee that). This is the
    process's main: it leaves the stop signals ignored for the interpreter's exit.

    A process started with :data:`.lifetime.PARENT_ENV` (the demo's children, the launch
    files' nodes) stops the same way once that process has ended, however it ended
    (SIGKILL included), and exits 1 if the stop is not over :data:`PARENT_GRACE_S` later.
    """
    argv = list(args) if args is not None else list(sys.argv)
    problem = _check_command_line(argv)
    if problem == "--help":
        print(usage(node_factory, argv))
        return 0
    if problem is not None:
        print(f"[{_program()}] {problem}", file=sys.stderr)
        return 2
    stop = _StopSignals()
    try:
        watched = lifetime.named_parent()
    except ValueError as err:
        print(f"[{_program()}] {err}", file=sys.stderr)
        return 2
    if watched is not None:
        lifetime.watch(watched, lambda: _parent_ended(watched), PARENT_GRACE_S)
    try:
        # No rclpy signal handlers: theirs shut the context down from another thread,
        # under a callback still running (a timer's publish then failed: "[FATAL] ...
        # Exception in 'timers' callback: ... publisher's context is invalid", 4 of 10
        # Ctrl-C of base.launch.py with a 1 kHz sim). The stop is _StopSignals' alone:
        # the spin ends between callbacks, then the node and the context go, here.
        rclpy.init(args=argv, signal_handler_options=SignalHandlerOptions.NO)
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
        except ModuleNotFoundError as err:  # an optional dependency (tf2_msgs): one line
            line = missing_text(err.name, _program())
            if line is None:
                raise
            print(line, file=sys.stderr)
            return 2
        _report_shadowed(node, argv)
        executor.add_node(node)
        spin(lambda: stop.requested)
    except KeyboardInterrupt:  # a repeated signal ended a stuck spin
        pass
    finally:
        stop.tearing_down()
        if node is not None:
            node.destroy_node()
        shutdown_after_stop()
        stop.release()
    return 0


# Longest a node's stop may take once the process that started it has ended [s]: then it
# exits without finishing its teardown (SPIN_TIMEOUT_S plus a teardown is well under it).
PARENT_GRACE_S = 5.0


def _parent_ended(pid: int) -> None:
    """The watched parent has ended: stop as on SIGTERM (from the watching thread).

    The stop first: the output may be a pipe that the parent read (``ros2 launch``), and
    writing to it now fails (EPIPE).
    """
    os.kill(os.getpid(), signal.SIGTERM)
    with contextlib.suppress(OSError):
        print(f"[{_program()}] the process that started it (pid {pid}) has ended: stopping",
              file=sys.stderr, flush=True)


def shutdown_after_stop() -> None:
    """``rclpy.try_shutdown()``, with rclpy's signal handler shutting down too.

    On a stop signal rclpy shuts the default context down from its own thread;
    ``try_shutdown`` checks the context, then shuts it down, and that thread can come in
    between: rcl then refuses the second shutdown (RCLError "rcl_shutdown already
    called"), which ended a clean stop with exit 1 and a traceback (22 of 60 processes
    calling it right after the signal). Down either way is the stop asked for.
    """
    try:
        rclpy.try_shutdown()
    except Exception:
        if rclpy.ok():
            raise


# Longest a spin waits before looking at the context again: the bound on how late a
# stop signal ends the process (teardown comes on top).
SPIN_TIMEOUT_S = 0.1


class _StopSignals:
    """The stop signals as a stop request the spin loop sees, never an exception.

    They are SIGINT, SIGTERM and SIGHUP (:func:`.lifetime.stop_signals`). They only set
    this flag: the spin loop waits at most SPIN_TIMEOUT_S and checks it, so the node
    stops between two callbacks and its context is shut down after the spin, in this
    thread. rclpy's own handlers are not installed (:func:`run`): they shut the context
    down from another thread, under a callback still running; and Python's SIGINT
    handler raised KeyboardInterrupt anywhere, even inside the teardown (exit 1,
    traceback). SIGHUP's default action ended the node at once (the demo's parent
    included): here it is a stop like the others.

    Signals come in threes under ``ros2 launch``: Ctrl-C in its terminal reaches the
    whole process group, launch then sends its own SIGINT, and a second Ctrl-C (or
    launch's SIGTERM) follows while the node stops. A repeat within
    :data:`REPEAT_GRACE_S` of the first is part of that one stop and is ignored; a later
    one ends a stuck spin (KeyboardInterrupt) or a stuck teardown (exit 130) at once.
    After the teardown, :meth:`release` ignores them: Python's exit would
    otherwise restore the default action, and a repeat landing there ends the process
    by the signal (``exit code -2`` in launch's log) after a clean stop.
    """

    def __init__(self) -> None:
        self.requested = False
        self._first = 0.0  # monotonic time of the first signal
        self._teardown = False
        self._signals = lifetime.stop_signals()
        for sig in self._signals:
            signal.signal(sig, self._on_signal)

    def _on_signal(self, signum: int, frame: Any) -> None:
        now = time.monotonic()
        if not self.requested:
            self.requested, self._first = True, now
            return
        if now - self._first < REPEAT_GRACE_S:
            return
        if self._teardown:
            os._exit(128 + signum)  # stuck in the teardown: no exception can help there
        raise KeyboardInterrupt

    def tearing_down(self) -> None:
        """The spin is over: from here a repeated signal must not raise into the teardown."""
        self._teardown = True

    def release(self) -> None:
        """Ignore further stop signals: the node is gone, the interpreter is exiting."""
        for sig in self._signals:
            signal.signal(sig, signal.SIG_IGN)


# A repeated stop signal this soon [s] after the first belongs to the same stop (launch's
# own SIGINT after the terminal's, a double Ctrl-C); the stop takes SPIN_TIMEOUT_S plus
# teardown, well under this.
REPEAT_GRACE_S = 2.0


def _param_sources(argv: Sequence[str]) -> list[ParamSource]:
    """``--params-file`` and ``-p`` of the ROS arguments, in rcl's order."""
    kinds = {"--params-file": "file", "-p": "param", "--param": "param"}
    return [(kinds[flag], value) for flag, value in itertools.pairwise(_ros_args(argv))
            if flag in kinds]


def _report_shadowed(node: Node, argv: Sequence[str]) -> None:
    """Warn once about a ``-p`` that a params file's section overrides (rcl's order)."""
    try:
        line = shadowed_overrides_line(
            _param_sources(argv), node.get_name(), node.get_namespace())
    except (ParameterError, OSError):
        return  # rcl has read these already; a form this reading misses is no reason to stop
    if line:
        node.get_logger().warning(line)


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
        f"share/diffdrive_odom/config) and the package's page doc/nodes/{program}.md.",
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
                lockstep.settle(executor)  # a lockstep node answers what it took
        except ExternalShutdownException:  # shut down during the wait: the end, not a fault
            pass

    return executor, spin


def _program() -> str:
    return os.path.basename(sys.argv[0]) if sys.argv and sys.argv[0] else "diffdrive_odom"
