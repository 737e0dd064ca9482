"""The closed loop: four nodes as child processes, and this process's recorder node.

``path_follower_node`` steers on the odometry (``odom`` in, ``cmd_vel`` out);
``cmd_vel_node`` turns the twist into wheel commands for ``sim_node``, a simulated
base whose TRUE geometry is a little off the nominal one; the simulated encoders feed
``odometry_node``, which closes the loop. They talk over DDS on loopback in a private
ROS domain, on simulated time driven by the sim (``/clock``), so the run is faster
than real time and a slow machine only slows it down. This process sends each
square's path on ``/path``, waits for the follower's ``~/done``, and records
everything into a rosbag2 (raw CDR as received, so every reader can decode it).

Every resource is held by an ExitStack: the child processes are stopped and the ROS
context and bag are closed when the demo ends, fails (a constructor included) or is
interrupted.
"""

from __future__ import annotations

import importlib
import json
import os
import random
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from contextlib import ExitStack
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import Any

import numpy as np
import rclpy
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Odometry
from nav_msgs.msg import Path as PathMsg
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.serialization import deserialize_message
from rclpy.signals import SignalHandlerOptions
from rosgraph_msgs.msg import Clock as ClockMsg
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool, Float64

from diffdrive_odom.core.conversions import quaternion_to_yaw, stamp_to_ns
from diffdrive_odom.core.paths import Point
from diffdrive_odom.ros.qos import DONE_QOS, RELIABLE_OUT_QOS, qos
from diffdrive_odom.settings.params import ParamValue
from diffdrive_odom.tools import bagio

from . import report
from .report import DemoResult, JointSample, PoseSeries, Recording, Square
from .settings import (
    BAG_TOPICS,
    FOLLOWER,
    SETTLE_S,
    STARTUP_TIMEOUT_S,
    DemoError,
    DemoOptions,
    Settings,
    check_options,
    follower_values,
    load_settings,
    square_path,
    write_run_params,
    yaml_value,
)

NODES = ("sim_node", "cmd_vel_node", "odometry_node", FOLLOWER)
RECORD_QOS = qos(1000, reliable=True)
LATEST_QOS = qos(1, reliable=False)  # only the newest /clock matters
ACK_RESEND_S = 1.0  # wall seconds before a path the follower did not take is sent again


# --- child processes --------------------------------------------------------------------


@dataclass
class Child:
    """A node started as its own process, its output going to a log file."""

    name: str
    proc: subprocess.Popen[bytes]
    log: Path

    def tail(self, lines: int = 12) -> str:
        """Last lines of its output (for error messages)."""
        try:
            text = self.log.read_text(encoding="utf-8", errors="replace")
        except OSError:
            return ""
        return "\n".join(f"  [{self.name}] {line}" for line in text.splitlines()[-lines:])


def _executable(name: str) -> str:
    path = Path(sys.executable).parent / name
    found = str(path) if path.exists() else shutil.which(name)
    if found is None:
        raise DemoError(f"{name} not found next to {sys.executable} or on PATH (make venv)")
    return found


class Children:
    """The nodes as child processes; leaving the ``with`` block stops every one started.

    SIGINT first (the nodes exit cleanly on it), then SIGKILL whatever is left.
    """

    def __init__(self, env: Mapping[str, str], logs: Path, grace: float = 5.0) -> None:
        self.env, self.logs, self.grace = dict(env), logs, grace
        self.started: list[Child] = []

    def start(self, name: str, args: Sequence[str]) -> Child:
        """Start a console script with ``--ros-args``."""
        exe = _executable(name)
        log = self.logs / f"{name}.log"
        with open(log, "wb") as out:
            proc = subprocess.Popen([exe, "--ros-args", *args], stdout=out,
                                    stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                    env=self.env)
        child = Child(name, proc, log)
        self.started.append(child)
        return child

    def check(self, what: str) -> None:
        """Raise DemoError if a child has exited."""
        for c in self.started:
            if c.proc.poll() is not None:
                raise DemoError(f"{c.name} exited with {c.proc.returncode} while {what}:\n"
                                f"{c.tail()}")

    def tails(self, lines: int = 5) -> str:
        """Each child's last log lines."""
        return "\n".join(c.tail(lines) for c in self.started)

    def __enter__(self) -> Children:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        for c in self.started:
            if c.proc.poll() is None:
                c.proc.send_signal(signal.SIGINT)
        deadline = time.monotonic() + self.grace
        for c in self.started:
            try:
                c.proc.wait(timeout=max(0.1, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                c.proc.kill()
                c.proc.wait()


# --- this process's node ---------------------------------------------------------------


def message_class(type_name: str) -> Any:
    """``pkg/msg/Name`` -> the rclpy message class (the topic table holds only names)."""
    pkg, _, name = type_name.split("/")
    return getattr(importlib.import_module(f"{pkg}.msg"), name)


def _pose_of(msg: Any) -> tuple[float, float, float]:
    p, q = msg.pose.pose.position, msg.pose.pose.orientation
    return float(p.x), float(p.y), quaternion_to_yaw(q)


class Recorder:
    """The demo's own node: records every topic into the bag and sends the paths.

    Messages are taken raw (the CDR bytes DDS delivered) and written to the bag as
    they are, so the bag holds exactly what the nodes sent; the few needed for the
    evaluation are decoded as well. A context manager: ``__enter__`` builds the ROS
    context, node and bag writer on an ExitStack, so a failure half-way undoes what
    was built, and ``__exit__`` closes them all.
    """

    def __init__(self, domain_id: int, bag_path: Path | None,
                 topics: Mapping[str, str] = BAG_TOPICS) -> None:
        self.domain_id, self.bag_path, self.topics = domain_id, bag_path, dict(topics)
        self.context = Context()
        self.writer: bagio.BagWriter | None = None
        self.now_ns: int | None = None
        self.odom, self.truth = PoseSeries(), PoseSeries()
        self.joint_states: list[JointSample] = []
        self.counts: dict[str, int] = dict.fromkeys(self.topics, 0)
        self.done_true = self.done_false = 0
        self.cross_track_max = 0.0
        self._stack = ExitStack()

    def __enter__(self) -> Recorder:
        with ExitStack() as stack:
            # No rclpy signal handlers: Ctrl-C stays a KeyboardInterrupt, so the caller
            # stops the child processes.
            rclpy.init(context=self.context, domain_id=self.domain_id,
                       signal_handler_options=SignalHandlerOptions.NO)
            stack.callback(rclpy.try_shutdown, context=self.context)
            self.node = Node("diffdrive_odom_demo", context=self.context)
            stack.callback(self.node.destroy_node)
            self.executor = SingleThreadedExecutor(context=self.context)
            stack.callback(self.executor.shutdown)
            self.executor.add_node(self.node)
            if self.bag_path is not None:
                self.writer = stack.enter_context(bagio.BagWriter(self.bag_path))
            for topic, type_name in self.topics.items():
                cls = message_class(type_name)
                if self.writer is not None:
                    self.writer.add_topic(topic, type_name)
                self.node.create_subscription(
                    cls, topic, lambda raw, t=topic: self._on_raw(t, raw), RECORD_QOS,
                    raw=True)
            self.node.create_subscription(ClockMsg, "/clock", self._on_clock, LATEST_QOS)
            self.node.create_subscription(Bool, f"/{FOLLOWER}/done", self._on_done, DONE_QOS)
            self.path_pub = self.node.create_publisher(
                PathMsg, "/path", RELIABLE_OUT_QOS)
            self._stack = stack.pop_all()
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self._stack.close()
        self.writer = None

    def spin_once(self, timeout: float) -> None:
        """Handle what arrived (or wait up to ``timeout`` seconds)."""
        self.executor.spin_once(timeout_sec=timeout)

    def _on_clock(self, msg: ClockMsg) -> None:
        self.now_ns = stamp_to_ns(msg.clock)

    def _on_done(self, msg: Bool) -> None:
        if msg.data:
            self.done_true += 1
        else:
            self.done_false += 1

    def _on_raw(self, topic: str, raw: bytes) -> None:
        log_ns = self.now_ns if self.now_ns is not None else time.time_ns()
        self.counts[topic] += 1
        if self.writer is not None:
            self.writer.write_cdr(topic, log_ns, bytes(raw))
        if topic == "/joint_states":
            js = deserialize_message(raw, JointState)
            self.joint_states.append(JointSample(
                stamp_to_ns(js.header.stamp), tuple(js.name),
                tuple(js.position), tuple(js.velocity)))
        elif topic in ("/odom", "/ground_truth/odom"):
            msg = deserialize_message(raw, Odometry)
            series = self.odom if topic == "/odom" else self.truth
            series.add(stamp_to_ns(msg.header.stamp), *_pose_of(msg))
        elif topic == f"/{FOLLOWER}/cross_track_error":
            e = float(deserialize_message(raw, Float64).data)
            self.cross_track_max = max(self.cross_track_max, abs(e))

    def send_path(self, points: Sequence[Point]) -> None:
        """Publish a path (odom frame) for the follower."""
        msg = PathMsg()
        msg.header.frame_id = "odom"
        for x, y in points:
            pose = PoseStamped()
            pose.header.frame_id = "odom"
            pose.pose.position.x, pose.pose.position.y = float(x), float(y)
            pose.pose.orientation.w = 1.0
            msg.poses.append(pose)
        self.path_pub.publish(msg)

    def _has(self, topic: str, node: str, publisher: bool) -> bool:
        infos = (self.node.get_publishers_info_by_topic(topic) if publisher
                 else self.node.get_subscriptions_info_by_topic(topic))
        return any(i.node_name == node for i in infos)

    def ready(self) -> bool:
        """Every link of the loop is up: clock, encoders, odometry, follower, cmd_vel -> sim."""
        c = self.counts
        return (self.now_ns is not None and self.done_false > 0
                and all(c[t] > 0 for t in ("/joint_states", "/odom", "/ground_truth/odom",
                                           "/tf"))
                and self._has("/path", FOLLOWER, publisher=False)
                and self._has("/odom", FOLLOWER, publisher=False)
                and self._has("/cmd_vel", "cmd_vel_node", publisher=False)
                and self._has("/wheel_commands", "sim_node", publisher=False)
                and self._has("/wheel_commands", "cmd_vel_node", publisher=True))

    def status(self) -> str:
        """Message counts so far, for error messages."""
        counts = ", ".join(f"{t}: {n}" for t, n in self.counts.items())
        clock = "no /clock yet" if self.now_ns is None else "/clock running"
        return f"{clock}; done {self.done_true}x; {counts}"

    def recording(self, squares: Sequence[Square]) -> Recording:
        """What was heard, for :mod:`.report`."""
        return Recording(tuple(self.joint_states), self.odom.trajectory(),
                         self.truth.trajectory(), tuple(squares), self.cross_track_max)


# --- the run ----------------------------------------------------------------------------


class _Waiter:
    """Spin the recorder until a condition holds, watching the children and a deadline."""

    def __init__(self, recorder: Recorder, children: Children) -> None:
        self.recorder, self.children = recorder, children

    def until(self, done: Callable[[], bool], deadline: float, what: str,
              fail: bool = True) -> bool:
        """True once ``done()``; at the deadline DemoError, or False if not ``fail``."""
        while not done():
            self.children.check(what)
            if time.monotonic() > deadline:
                if not fail:
                    return False
                raise DemoError(f"timed out {what} ({self.recorder.status()}):\n"
                                f"{self.children.tails()}")
            self.recorder.spin_once(0.05)
        return True

    def settle(self, deadline: float, what: str) -> int:
        """Wait ``SETTLE_S`` of simulated time; returns the simulated time then [ns]."""
        r = self.recorder
        assert r.now_ns is not None
        until = r.now_ns + round(SETTLE_S * 1e9)
        self.until(lambda: r.now_ns is not None and r.now_ns >= until, deadline, what)
        return until


def _run_params(opts: DemoOptions, s: Settings, output: Path) -> Path:
    """The params file for this run: sim time, the clock's rate, the follower's settings."""
    rtf = opts.real_time_factor
    sim_changes: dict[str, ParamValue] = {
        k: yaml_value(v) for k, v in opts.sim_overrides.items()}
    # The cmd_vel node's heartbeat runs on the wall clock, the sim's watchdog on
    # simulated time: scale the watchdog so a 0.5 s hiccup of a busy machine does not
    # stop the robot in the middle of the route.
    timeout = s.sim.config.command_timeout
    if timeout > 0.0 and "command_timeout" not in sim_changes:
        sim_changes["command_timeout"] = timeout * max(1.0, rtf)
    sim_changes.update(publish_clock=True, real_time_factor=float(rtf))
    # The cmd_vel heartbeat is on the wall clock: keep it at one command per sim step.
    cmd_rate = max(50.0, s.sim.publish_rate * rtf)
    return write_run_params(opts.params_file, {
        "sim_node": sim_changes,
        "cmd_vel_node": {"use_sim_time": True, "wheel_command_rate": float(cmd_rate)},
        "odometry_node": {"use_sim_time": True},
        FOLLOWER: follower_values(opts),
    }, output / "params.yaml")


def _drive(waiter: _Waiter, opts: DemoOptions, look_ahead: float,
           deadline: float) -> list[Square]:
    """Each square: send its path (again until the follower takes it), wait for done."""
    r = waiter.recorder
    squares: list[Square] = []
    waiter.settle(deadline, "waiting at the start")
    for cw in opts.squares:
        what = f"driving the {'CW' if cw else 'CCW'} square"
        points = square_path(opts.side, cw, look_ahead)
        assert r.now_ns is not None
        start, taken, done = r.now_ns, r.done_false, r.done_true

        def took(n: int = taken) -> bool:  # the follower says "not done" on a new path
            return r.done_false > n

        def finished(n: int = done) -> bool:
            return r.done_true > n

        r.send_path(points)
        while not waiter.until(took, time.monotonic() + ACK_RESEND_S, what, fail=False):
            if time.monotonic() > deadline:
                raise DemoError(f"timed out {what}: the follower never took the path")
            r.send_path(points)
        waiter.until(finished, deadline, what)
        end = waiter.settle(deadline, "letting the robot settle")
        squares.append(Square(cw, tuple(points), start, end))
    last = squares[-1].end_ns
    waiter.until(lambda: all(s.stamp_ns and max(s.stamp_ns) >= last
                             for s in (r.odom, r.truth)), deadline,
                 "waiting for the last odometry and ground truth")
    return squares


def run(opts: DemoOptions) -> DemoResult:
    """Start the nodes, drive the squares, record, calibrate, plot; everything released."""
    check_options(opts)
    settings = load_settings(opts)
    output = opts.output
    output.mkdir(parents=True, exist_ok=True)
    logs = output / "logs"
    logs.mkdir(exist_ok=True)
    bag_path = output / "bag" if opts.write_bag else None
    if bag_path is not None and bag_path.exists():
        if not (bag_path / "metadata.yaml").exists():
            raise DemoError(f"{bag_path} exists and is not a bag: remove it or choose --output")
        shutil.rmtree(bag_path)

    domain = opts.domain_id if opts.domain_id is not None else random.randint(1, 100)
    env = {**os.environ, "ROS_DOMAIN_ID": str(domain),
           "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}
    env.pop("ROS_LOCALHOST_ONLY", None)
    args = ["--params-file", str(_run_params(opts, settings, output))]

    wall0 = time.monotonic()
    with ExitStack() as stack:
        recorder = stack.enter_context(Recorder(domain, bag_path))
        children = stack.enter_context(Children(env, logs))
        for name in NODES:
            children.start(name, args)
        print(f"[{opts.route}] ROS_DOMAIN_ID={domain}; "
              + ", ".join(f"{c.name} pid {c.proc.pid}" for c in children.started)
              + f"; logs in {logs}", flush=True)
        waiter = _Waiter(recorder, children)
        waiter.until(recorder.ready, wall0 + STARTUP_TIMEOUT_S, "starting the nodes")
        squares = _drive(waiter, opts, settings.follower.gains.look_ahead,
                         wall0 + opts.timeout)
    wall = time.monotonic() - wall0
    return _evaluate(opts, settings, recorder, squares, wall, bag_path)


def _evaluate(opts: DemoOptions, s: Settings, recorder: Recorder, squares: Sequence[Square],
              wall: float, bag: Path | None) -> DemoResult:
    rec = recorder.recording(squares)
    rows, paths = report.calibrate_rows(rec, s.odometry, s.sim.config.geometry, opts.side)
    truth = rec.truth
    xy = np.column_stack((truth.x, truth.y))
    off_path = 0.0
    for sq in squares:
        inside = (truth.stamp_ns >= sq.start_ns) & (truth.stamp_ns <= sq.end_ns)
        if inside.any():
            off_path = max(off_path, float(report.distance_to_polyline(
                xy[inside], sq.points).max()))
    plot_path = opts.output / "trajectory.png"
    if opts.write_plot:
        from .plot import plot

        plot(plot_path, truth, paths, [sq.points for sq in squares],
             f"{opts.route}: the follower drives on odometry; the truth drifts")
    distance = float(truth.path_length()[-1]) if len(truth) else 0.0
    result = DemoResult(
        route=opts.route, side_m=opts.side, distance_m=distance,
        sim_seconds=(squares[-1].end_ns - squares[0].start_ns) * 1e-9 + SETTLE_S,
        wall_seconds=wall,
        truth_final_pose=(float(truth.x[-1]), float(truth.y[-1]), float(truth.yaw[-1])),
        rows=rows, cross_track_odom_m=rec.cross_track_odom_m,
        cross_track_truth_m=off_path, squares=tuple(squares),
        messages=dict(recorder.counts),
        bag=str(bag) if bag is not None else None,
        plot=str(plot_path) if opts.write_plot else None,
    )
    (opts.output / "results.json").write_text(
        json.dumps(result.as_dict(), indent=2) + "\n", encoding="utf-8")
    return result
