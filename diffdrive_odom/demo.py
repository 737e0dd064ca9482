"""``diffdrive-odom demo`` (``make demo``): the whole product in one closed loop.

A scripted route is published as ``cmd_vel``; ``cmd_vel_node`` turns it into wheel
commands for ``sim_node``, a simulated base whose TRUE geometry is a little off the
nominal one; the simulated encoders feed ``odometry_node``. Three separate processes
talk over DDS on loopback in a private ROS domain, on simulated time driven by the
sim (``/clock``), so the run is faster than real time and a slow machine only slows
it down. This process records everything into a rosbag2 (raw CDR as received, so
every reader can decode it), then prints how far the odometry drifted from the truth,
next to what a perfectly calibrated odometry makes of the very same encoder readings
(the node's estimator re-run offline with the true geometry), and plots both.

Every child process is stopped when the demo ends, fails or is interrupted.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import random
import shutil
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from types import FrameType
from typing import Any

import rclpy
import yaml
from geometry_msgs.msg import Twist
from nav_msgs.msg import Odometry
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.serialization import deserialize_message
from rclpy.signals import SignalHandlerOptions
from rosgraph_msgs.msg import Clock as ClockMsg
from sensor_msgs.msg import JointState
from tf2_msgs.msg import TFMessage

from diffdrive_odom import bagio, evaluate, ros_common, routes
from diffdrive_odom.cli import HelpFormatter
from diffdrive_odom.conversions import quaternion_to_yaw
from diffdrive_odom.odometry_settings import OdometrySettings, odometry_settings
from diffdrive_odom.params import (
    EXAMPLE_PARAMS_FILE,
    ParameterError,
    ParamValue,
    load_params_file,
)
from diffdrive_odom.pipeline import ReadingPipeline
from diffdrive_odom.routes import Route
from diffdrive_odom.sim_settings import SimSettings, sim_settings

DEFAULT_PARAMS = EXAMPLE_PARAMS_FILE
PROGRAM = "diffdrive-odom demo"
# Bag topic -> message type; what the other tools (eval, replay, play) read.
BAG_TOPICS: dict[str, str] = {
    "/joint_states": "sensor_msgs/msg/JointState",
    "/odom": "nav_msgs/msg/Odometry",
    "/ground_truth/odom": "nav_msgs/msg/Odometry",
    "/tf": "tf2_msgs/msg/TFMessage",
    "/cmd_vel": "geometry_msgs/msg/Twist",
}
SETTLE_S = 1.0  # simulated time at rest before the route starts and after it ends
STARTUP_TIMEOUT_S = 45.0


class DemoError(RuntimeError):
    """The demo cannot go on; the message says why (and which process failed)."""


@dataclass(frozen=True)
class DemoOptions:
    """What to run and where to write it."""

    route: Route
    output: Path
    params_file: Path = DEFAULT_PARAMS
    real_time_factor: float = 4.0
    sim_overrides: dict[str, str] = field(default_factory=dict)
    timeout: float = 110.0  # wall seconds for the whole run
    write_bag: bool = True
    write_plot: bool = True
    domain_id: int | None = None


@dataclass
class PoseSeries:
    """Poses by stamp as received (odometry or ground truth)."""

    stamp_ns: list[int] = field(default_factory=list)
    x: list[float] = field(default_factory=list)
    y: list[float] = field(default_factory=list)
    yaw: list[float] = field(default_factory=list)

    def add(self, stamp_ns: int, x: float, y: float, yaw: float) -> None:
        """Append one pose."""
        self.stamp_ns.append(stamp_ns)
        self.x.append(x)
        self.y.append(y)
        self.yaw.append(yaw)

    def trajectory(self) -> evaluate.Trajectory:
        """As the evaluation module's trajectory (sorted, unwrapped)."""
        return evaluate.Trajectory.from_arrays(self.stamp_ns, self.x, self.y, self.yaw)


@dataclass(frozen=True)
class ErrorFigures:
    """Final error of one odometry against the ground truth."""

    position_m: float
    heading_rad: float
    final_pose: tuple[float, float, float]

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready."""
        return {"final_position_error_m": self.position_m,
                "final_heading_error_rad": self.heading_rad,
                "final_pose": list(self.final_pose)}


@dataclass(frozen=True)
class DemoResult:
    """What the demo measured; ``as_dict`` is written to ``results.json``."""

    route: str
    distance_m: float
    sim_seconds: float
    wall_seconds: float
    truth_final_pose: tuple[float, float, float]
    odometry: ErrorFigures
    calibrated: ErrorFigures
    nominal: dict[str, float]
    true: dict[str, float]
    messages: dict[str, int]
    bag: str | None
    plot: str | None

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready."""
        return {
            "route": self.route, "distance_m": self.distance_m,
            "sim_seconds": self.sim_seconds, "wall_seconds": self.wall_seconds,
            "truth_final_pose": list(self.truth_final_pose),
            "odometry": self.odometry.as_dict(), "calibrated": self.calibrated.as_dict(),
            "nominal_geometry": self.nominal, "true_geometry": self.true,
            "messages": self.messages, "bag": self.bag, "plot": self.plot,
        }

    def table(self) -> str:
        """The short table the demo prints."""
        n, t = self.nominal, self.true

        def pct(a: float, b: float) -> str:
            return f"{100.0 * (a / b - 1.0):+.1f} %"

        lines = [
            f"route {self.route}: {self.distance_m:.2f} m driven in {self.sim_seconds:.0f} s "
            f"of simulated time ({self.wall_seconds:.0f} s wall)",
            f"robot: nominal r = {n['left_radius']:.4f} m, b = {n['separation']:.4f} m; "
            f"true r_left = {t['left_radius']:.4f} m ({pct(t['left_radius'], n['left_radius'])}),"
            f" r_right = {t['right_radius']:.4f} m ({pct(t['right_radius'], n['right_radius'])}),"
            f" b = {t['separation']:.4f} m ({pct(t['separation'], n['separation'])})",
            "",
            f"{'odometry vs ground truth':<36} {'distance':>9} {'final position error':>22} "
            f"{'final heading error':>20}",
        ]
        for label, fig in (("odometry_node (nominal geometry)", self.odometry),
                           ("perfectly calibrated (true geometry)", self.calibrated)):
            share = 100.0 * fig.position_m / self.distance_m if self.distance_m > 0 else math.nan
            lines.append(
                f"{label:<36} {self.distance_m:>7.2f} m {fig.position_m:>8.3f} m "
                f"({share:5.2f} %) {math.degrees(fig.heading_rad):>15.2f} deg")
        if self.plot or self.bag:
            lines.append("")
        if self.plot:
            lines.append(f"plot: {self.plot}")
        if self.bag:
            lines.append(f"bag:  {self.bag}  (try: diffdrive-odom eval {self.bag} "
                         "--ground-truth /ground_truth/odom)")
        return "\n".join(lines)


# --- settings ---------------------------------------------------------------------------


def _parse_override(text: str) -> tuple[str, str]:
    name, sep, value = text.partition(":=")
    if not sep or not name:
        raise DemoError(f"--sim-param takes NAME:=VALUE, got {text!r}")
    return name, value


def _yaml_value(text: str) -> ParamValue:
    """A ``-p name:=value`` value as ROS reads it (YAML)."""
    return yaml.safe_load(text) if text.strip() else text


def load_settings(opts: DemoOptions) -> tuple[OdometrySettings, SimSettings]:
    """The odometry node's and the sim's settings from the params file and overrides."""
    try:
        odo = odometry_settings(load_params_file(opts.params_file, "odometry_node"))
        sim_values = load_params_file(opts.params_file, "sim_node")
        sim_values.update({k: _yaml_value(v) for k, v in opts.sim_overrides.items()})
        sim = sim_settings(sim_values)
    except (ParameterError, OSError, yaml.YAMLError) as err:
        raise DemoError(f"{opts.params_file}: {err}") from err
    return odo, sim


def write_run_params(source: Path, changes: dict[str, dict[str, ParamValue]],
                     path: Path) -> Path:
    """Write the params file with this run's settings in the nodes' own sections.

    In a params file a node's own section wins over ``-p`` on the command line, so
    the run's values go into the file rather than onto the command line.
    """
    try:
        doc = yaml.safe_load(source.read_text(encoding="utf-8")) or {}
    except (OSError, yaml.YAMLError) as err:
        raise DemoError(f"{source}: {err}") from err
    if not isinstance(doc, dict):
        raise DemoError(f"{source} is not a ROS 2 params file")
    for node, values in changes.items():
        section = doc.setdefault(node, {}).setdefault("ros__parameters", {})
        section.update(values)
    path.write_text("# Written by diffdrive-odom demo for this run: " + str(source)
                    + " with the run's settings applied.\n"
                    + yaml.safe_dump(doc, default_flow_style=None, sort_keys=False),
                    encoding="utf-8")
    return path


def calibrated_geometry(odo: OdometrySettings, sim: SimSettings) -> OdometrySettings:
    """The odometry settings with multipliers that make its geometry the sim's true one."""
    g, true = odo.geometry, sim.config.geometry
    return replace(odo, geometry=replace(
        g,
        left_wheel_radius_multiplier=true.left_radius / g.wheel_radius,
        right_wheel_radius_multiplier=true.right_radius / g.wheel_radius,
        wheel_separation_multiplier=true.separation / g.wheel_separation,
    ))


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


def start_child(name: str, args: Sequence[str], env: dict[str, str], logs: Path) -> Child:
    """Start a console script with ``--ros-args``."""
    log = logs / f"{name}.log"
    with open(log, "wb") as out:
        proc = subprocess.Popen(
            [_executable(name), "--ros-args", *args],
            stdout=out, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, env=env,
        )
    return Child(name, proc, log)


def stop_children(children: Sequence[Child], grace: float = 5.0) -> None:
    """SIGINT (the nodes exit cleanly on it), then SIGKILL whatever is left."""
    for c in children:
        if c.proc.poll() is None:
            c.proc.send_signal(signal.SIGINT)
    deadline = time.monotonic() + grace
    for c in children:
        try:
            c.proc.wait(timeout=max(0.1, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            c.proc.kill()
            c.proc.wait()


# --- recording and driving (this process's own node) -----------------------------------

RECORD_QOS = ros_common.qos(1000, reliable=True)
# Only the newest /clock matters to the driver.
LATEST_QOS = ros_common.qos(1, reliable=False)
_TYPES: dict[str, Any] = {
    "/joint_states": JointState, "/odom": Odometry, "/ground_truth/odom": Odometry,
    "/tf": TFMessage, "/cmd_vel": Twist,
}


def _pose_of(msg: Any) -> tuple[float, float, float]:
    p, q = msg.pose.pose.position, msg.pose.pose.orientation
    return float(p.x), float(p.y), quaternion_to_yaw(q)


class Driver:
    """Publishes the route on ``cmd_vel`` against the simulated clock, in its own thread.

    Kept apart from the recorder (own context, own executor, newest /clock only) so
    that however far the recorder falls behind on a busy machine, commands go out
    within a step of the simulated time they belong to.
    """

    def __init__(self, domain_id: int, route: Route) -> None:
        self.route = route
        self.context = Context()
        rclpy.init(context=self.context, domain_id=domain_id,
                   signal_handler_options=SignalHandlerOptions.NO)
        self.node = Node("diffdrive_odom_demo_driver", context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.now_ns: int | None = None
        self.t0_ns: int | None = None
        self.end_ns: int | None = None
        self.node.create_subscription(ClockMsg, "/clock", self._on_clock, LATEST_QOS)
        self.cmd_pub = self.node.create_publisher(Twist, "/cmd_vel", ros_common.RELIABLE_OUT_QOS)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._spin, name="demo-driver", daemon=True)
        self._thread.start()

    def _spin(self) -> None:
        while not self._stop.is_set():
            try:
                self.executor.spin_once(timeout_sec=0.05)
            except Exception:  # the context is going away: stop quietly
                if not self._stop.is_set():
                    raise
                return

    def _on_clock(self, msg: ClockMsg) -> None:
        self.now_ns = ros_common.stamp_to_ns(msg.clock)
        if self.t0_ns is not None:
            v, w = self.route.command_at((self.now_ns - self.t0_ns) * 1e-9)
            twist = Twist()
            twist.linear.x, twist.angular.z = float(v), float(w)
            self.cmd_pub.publish(twist)

    def start_route(self, settle_s: float) -> None:
        """Start the route ``settle_s`` of simulated time from now."""
        assert self.now_ns is not None
        t0 = self.now_ns + round(settle_s * 1e9)
        self.end_ns = t0 + round(self.route.duration * 1e9)
        self.t0_ns = t0

    def close(self) -> None:
        """Stop the thread and the context."""
        self._stop.set()
        self._thread.join(timeout=2.0)
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


class Recorder:
    """The demo's recording node: everything that flows goes into the bag.

    Messages are taken raw (the CDR bytes DDS delivered) and written to the bag as
    they are, so the bag holds exactly what the nodes sent; the few needed for the
    evaluation are decoded as well.
    """

    def __init__(self, domain_id: int, route: Route, bag_path: Path | None) -> None:
        self.context = Context()
        # No rclpy signal handlers: Ctrl-C stays a KeyboardInterrupt, so the caller
        # stops the child processes.
        rclpy.init(context=self.context, domain_id=domain_id,
                   signal_handler_options=SignalHandlerOptions.NO)
        self.node = Node("diffdrive_odom_demo", context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.writer: bagio.BagWriter | None = None
        if bag_path is not None:
            self.writer = bagio.BagWriter(bag_path).__enter__()
            for topic, msgtype in BAG_TOPICS.items():
                self.writer.add_topic(topic, msgtype)
        self.odom = PoseSeries()
        self.truth = PoseSeries()
        self.joint_states: list[tuple[int, tuple[str, ...], tuple[float, ...],
                                      tuple[float, ...]]] = []
        self.counts: dict[str, int] = dict.fromkeys(BAG_TOPICS, 0)
        for topic, msg_type in _TYPES.items():
            self.node.create_subscription(
                msg_type, topic, lambda raw, t=topic: self._on_raw(t, raw), RECORD_QOS,
                raw=True)
        self.driver = Driver(domain_id, route)

    def spin_once(self, timeout: float) -> None:
        """Handle what arrived (or wait up to ``timeout`` seconds)."""
        self.executor.spin_once(timeout_sec=timeout)

    def _on_raw(self, topic: str, raw: bytes) -> None:
        now = self.driver.now_ns
        log_ns = now if now is not None else time.time_ns()
        self.counts[topic] += 1
        if self.writer is not None:
            self.writer.write_cdr(topic, log_ns, bytes(raw))
        if topic == "/joint_states":
            js = deserialize_message(raw, JointState)
            self.joint_states.append((ros_common.stamp_to_ns(js.header.stamp), tuple(js.name),
                                      tuple(js.position), tuple(js.velocity)))
        elif topic in ("/odom", "/ground_truth/odom"):
            msg = deserialize_message(raw, Odometry)
            series = self.odom if topic == "/odom" else self.truth
            series.add(ros_common.stamp_to_ns(msg.header.stamp), *_pose_of(msg))

    def ready(self) -> bool:
        """Every link of the loop is up: clock, encoders, odometry, cmd_vel -> sim."""
        n = self.node
        return (self.driver.now_ns is not None and self.counts["/joint_states"] > 0
                and self.counts["/odom"] > 0 and self.counts["/ground_truth/odom"] > 0
                and self.counts["/tf"] > 0
                and self.driver.cmd_pub.get_subscription_count() > 0
                and n.count_publishers("/wheel_commands") > 0
                and n.count_subscribers("/wheel_commands") > 0)

    def finished(self, settle_s: float) -> bool:
        """The route is over, the robot has settled and the odometry has caught up."""
        end = self.driver.end_ns
        if end is None or not self.odom.stamp_ns:
            return False
        return max(self.odom.stamp_ns) >= end + round(settle_s * 1e9)

    def status(self) -> str:
        """Message counts so far, for error messages."""
        counts = ", ".join(f"{t}: {c}" for t, c in self.counts.items())
        clock = "no /clock yet" if self.driver.now_ns is None else "/clock running"
        return f"{clock}; {counts}"

    def close(self) -> None:
        """Close the bag and this process's ROS context."""
        self.driver.close()
        if self.writer is not None:
            self.writer.__exit__(None, None, None)
            self.writer = None
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


# --- the run ----------------------------------------------------------------------------


def run(opts: DemoOptions) -> DemoResult:
    """Start the nodes, drive the route, record, evaluate, plot; children always stopped."""
    odo, sim = load_settings(opts)
    if not (math.isfinite(opts.real_time_factor) and 0.0 < opts.real_time_factor <= 20.0):
        raise DemoError(f"--real-time-factor must be > 0 and <= 20, got {opts.real_time_factor}")
    output = opts.output
    output.mkdir(parents=True, exist_ok=True)
    logs = output / "logs"
    logs.mkdir(exist_ok=True)
    bag_path = output / "bag"
    if opts.write_bag and bag_path.exists():
        if not (bag_path / "metadata.yaml").exists():
            raise DemoError(f"{bag_path} exists and is not a bag: remove it or choose --output")
        shutil.rmtree(bag_path)

    domain = opts.domain_id if opts.domain_id is not None else random.randint(1, 100)
    env = {**os.environ, "ROS_DOMAIN_ID": str(domain),
           "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}
    env.pop("ROS_LOCALHOST_ONLY", None)
    rtf = opts.real_time_factor
    sim_changes: dict[str, ParamValue] = {
        k: _yaml_value(v) for k, v in opts.sim_overrides.items()}
    # The cmd_vel node's heartbeat runs on the wall clock, the sim's watchdog on
    # simulated time: scale the watchdog so a 0.5 s hiccup of a busy machine does not
    # stop the robot in the middle of the route.
    timeout = sim.config.command_timeout
    if timeout > 0.0 and "command_timeout" not in sim_changes:
        sim_changes["command_timeout"] = timeout * max(1.0, rtf)
    sim_changes.update(publish_clock=True, real_time_factor=float(rtf))
    # The cmd_vel heartbeat is on the wall clock: keep it at one command per sim step.
    cmd_rate = max(50.0, sim.publish_rate * rtf)
    params = str(write_run_params(opts.params_file, {
        "sim_node": sim_changes,
        "cmd_vel_node": {"use_sim_time": True, "wheel_command_rate": float(cmd_rate)},
        "odometry_node": {"use_sim_time": True},
    }, output / "params.yaml"))
    args = ["--params-file", params]

    wall0 = time.monotonic()
    children: list[Child] = []
    recorder = Recorder(domain, opts.route, bag_path if opts.write_bag else None)
    try:
        for name in ("sim_node", "cmd_vel_node", "odometry_node"):
            children.append(start_child(name, args, env, logs))
        print(f"[{PROGRAM}] ROS_DOMAIN_ID={domain}; "
              + ", ".join(f"{c.name} pid {c.proc.pid}" for c in children)
              + f"; logs in {logs}", flush=True)
        _wait(recorder, children, wall0 + STARTUP_TIMEOUT_S, "starting the nodes",
              recorder.ready)
        recorder.driver.start_route(SETTLE_S)
        _wait(recorder, children, wall0 + opts.timeout, f"driving {opts.route.name}",
              lambda: recorder.finished(SETTLE_S))
    finally:
        stop_children(children)
        recorder.close()
    wall = time.monotonic() - wall0
    return _evaluate(opts, odo, sim, recorder, wall, bag_path if opts.write_bag else None)


def _wait(recorder: Recorder, children: Sequence[Child], deadline: float, what: str,
          done: Callable[[], bool]) -> None:
    while not done():
        for c in children:
            if c.proc.poll() is not None:
                raise DemoError(f"{c.name} exited with {c.proc.returncode} while {what}:\n"
                                f"{c.tail()}")
        if time.monotonic() > deadline:
            logs = "\n".join(c.tail(5) for c in children)
            raise DemoError(f"timed out {what} ({recorder.status()}):\n{logs}")
        recorder.spin_once(0.05)


def _geometry_dict(left: float, right: float, separation: float) -> dict[str, float]:
    return {"left_radius": left, "right_radius": right, "separation": separation}


def _final(est: evaluate.Trajectory, truth: evaluate.Trajectory) -> ErrorFigures:
    metrics = evaluate.evaluate(est, truth)
    return ErrorFigures(
        metrics.final_position_error_m, metrics.final_heading_error_rad,
        (float(est.x[-1]), float(est.y[-1]), float(est.yaw[-1])),
    )


def replay_calibrated(odo: OdometrySettings, joint_states: Sequence[Any]) -> PoseSeries:
    """The node's reading path, fed the recorded readings, with the true geometry."""
    pipe = ReadingPipeline(odo)
    out = PoseSeries()
    for stamp_ns, names, position, velocity in sorted(joint_states, key=lambda j: j[0]):
        if pipe.feed(stamp_ns, names, position, velocity).publish:
            p = pipe.estimator.pose
            out.add(stamp_ns, p.x, p.y, p.theta)
    return out


def _evaluate(opts: DemoOptions, odo: OdometrySettings, sim: SimSettings, recorder: Recorder,
              wall: float, bag: Path | None) -> DemoResult:
    odom, truth = recorder.odom.trajectory(), recorder.truth.trajectory()
    if len(odom) < 2 or len(truth) < 2:
        raise DemoError(f"too little data to evaluate ({recorder.status()})")
    cal_settings = calibrated_geometry(odo, sim)
    calibrated = replay_calibrated(cal_settings, recorder.joint_states).trajectory()
    metrics = evaluate.evaluate(odom, truth)
    plot_path = opts.output / "trajectory.png"
    if opts.write_plot:
        plot(plot_path, truth, odom, calibrated, opts.route.name)
    g, t = odo.geometry, sim.config.geometry
    result = DemoResult(
        route=opts.route.name,
        distance_m=metrics.distance_m,
        sim_seconds=opts.route.duration + 2 * SETTLE_S,
        wall_seconds=wall,
        truth_final_pose=(float(truth.x[-1]), float(truth.y[-1]), float(truth.yaw[-1])),
        odometry=_final(odom, truth),
        calibrated=_final(calibrated, truth),
        nominal=_geometry_dict(g.left_radius, g.right_radius, g.separation),
        true=_geometry_dict(t.left_radius, t.right_radius, t.separation),
        messages=dict(recorder.counts),
        bag=str(bag) if bag is not None else None,
        plot=str(plot_path) if opts.write_plot else None,
    )
    (opts.output / "results.json").write_text(
        json.dumps(result.as_dict(), indent=2) + "\n", encoding="utf-8")
    return result


# --- the picture ------------------------------------------------------------------------


def plot(path: Path, truth: evaluate.Trajectory, odom: evaluate.Trajectory,
         calibrated: evaluate.Trajectory, route_name: str) -> None:
    """Where the robot really went, where odometry thinks it went, and the gap growing."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(13, 6),
                                   gridspec_kw={"width_ratios": [1.15, 1.0]})
    ax1.plot(truth.x, truth.y, "-", color="black", lw=2.2, label="ground truth (where the "
             "robot really went)")
    ax1.plot(odom.x, odom.y, "-", color="tab:red", lw=1.4,
             label="odometry, nominal geometry (what the robot believes)")
    ax1.plot(calibrated.x, calibrated.y, "--", color="tab:green", lw=1.2,
             label="odometry, perfectly calibrated")
    ax1.plot([0.0], [0.0], "o", color="black", ms=8, label="start")
    tx, ty = float(truth.x[-1]), float(truth.y[-1])
    ox, oy = float(odom.x[-1]), float(odom.y[-1])
    ax1.plot([tx], [ty], "s", color="black", ms=7, label="end: where it really is")
    ax1.plot([ox], [oy], "s", color="tab:red", ms=7, label="end: where odometry says it is")
    drift = math.hypot(ox - tx, oy - ty)
    ax1.annotate("", xy=(ox, oy), xytext=(tx, ty),
                 arrowprops={"arrowstyle": "<->", "color": "tab:red", "lw": 1.5})
    ax1.annotate(f"drift at the end: {drift:.2f} m", xy=(0.5 * (ox + tx), 0.5 * (oy + ty)),
                 xytext=(-150, -45), textcoords="offset points", color="tab:red",
                 arrowprops={"arrowstyle": "-", "color": "tab:red", "lw": 0.8},
                 fontsize=10, fontweight="bold",
                 bbox={"boxstyle": "round", "facecolor": "white", "alpha": 0.8,
                       "edgecolor": "none"})
    ax1.set_aspect("equal", adjustable="datalim")
    ax1.set_xlabel("x [m]")
    ax1.set_ylabel("y [m]")
    ax1.grid(True, alpha=0.3)
    ax1.legend(loc="upper center", bbox_to_anchor=(0.5, -0.1), fontsize=9, ncol=1)
    ax1.set_title(f"{route_name}: the same drive, seen two ways")

    for traj, color, style, label in ((odom, "tab:red", "-", "nominal geometry"),
                                      (calibrated, "tab:green", "--", "perfectly calibrated")):
        m = evaluate.match(traj, truth)
        dist = evaluate.path_length(m.ref)
        err = np.hypot(*(m.est[:, :2] - m.ref[:, :2]).T)
        ax2.plot(dist, err, style, color=color, lw=1.5, label=label)
    ax2.set_xlabel("distance driven [m]")
    ax2.set_ylabel("position error of odometry [m]")
    ax2.set_title("odometry drift: distance between belief and truth")
    ax2.grid(True, alpha=0.3)
    ax2.legend(loc="upper left", fontsize=9)
    ax2.text(0.02, 0.84,
             "Odometry adds up every wheel turn. Wheel radii or track\n"
             "width slightly off the drawing bend every step the same\n"
             "way, so the error keeps growing with distance (a loop\n"
             "can bring the paths back close, the heading error stays).\n"
             "Calibration removes that systematic part; slip and\n"
             "encoder ticks leave a small random part.",
             transform=ax2.transAxes, ha="left", va="top", fontsize=8.5,
             bbox={"boxstyle": "round", "facecolor": "white", "alpha": 0.9})
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


# --- command line -----------------------------------------------------------------------


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog=PROGRAM,
        description="Closed-loop demo: sim_node + cmd_vel_node + odometry_node over DDS; "
                    "prints odometry drift, writes a plot and a bag.",
        formatter_class=HelpFormatter)
    ap.add_argument("--route", default="umbmark", choices=list(routes.names()),
                    help="route to drive (default: UMBmark, 4 m square CW then CCW)")
    ap.add_argument("--size", type=float, default=None,
                    help="side or radius of the route [m] (default per route)")
    ap.add_argument("--linear", type=float, default=0.4, help="driving speed [m/s]")
    ap.add_argument("--angular", type=float, default=0.8, help="turning rate [rad/s]")
    ap.add_argument("--short", action="store_true",
                    help="a 1 m square instead (about 20 s of simulated time)")
    ap.add_argument("--output", default="demo_output", help="output directory")
    ap.add_argument("--params-file", default=str(DEFAULT_PARAMS),
                    help="params YAML for all three nodes")
    ap.add_argument("--sim-param", action="append", default=[], metavar="NAME:=VALUE",
                    help="override a sim_node parameter (repeatable), e.g. "
                         "true_right_wheel_radius:=0.0505")
    ap.add_argument("--real-time-factor", type=float, default=4.0,
                    help="simulated seconds per wall second")
    ap.add_argument("--timeout", type=float, default=110.0, help="give up after [s] (wall)")
    ap.add_argument("--domain-id", type=int, default=None,
                    help="ROS_DOMAIN_ID for the run (default: a random one)")
    ap.add_argument("--no-bag", action="store_true", help="do not write the bag")
    ap.add_argument("--no-plot", action="store_true", help="do not write the PNG")
    return ap


def _on_sigterm(signum: int, frame: FrameType | None) -> None:
    raise KeyboardInterrupt


def main(argv: Sequence[str] | None = None) -> int:
    """``diffdrive-odom demo``: 0 on success, 1 if the run failed, 2 on bad options."""
    args = _parser().parse_args(list(sys.argv[1:] if argv is None else argv))
    try:
        if args.short:
            route = routes.square(1.0, args.linear, args.angular, clockwise=False)
        else:
            route = routes.make_route(args.route, args.size, args.linear, args.angular)
        overrides = dict(_parse_override(t) for t in args.sim_param)
    except (routes.RouteError, DemoError) as err:
        print(f"[{PROGRAM}] {err}", file=sys.stderr)
        return 2
    opts = DemoOptions(
        route=route, output=Path(args.output), params_file=Path(args.params_file),
        real_time_factor=args.real_time_factor, sim_overrides=overrides,
        timeout=args.timeout, write_bag=not args.no_bag, write_plot=not args.no_plot,
        domain_id=args.domain_id,
    )
    previous = signal.signal(signal.SIGTERM, _on_sigterm)
    try:
        print(f"[{PROGRAM}] driving {route.name} ({route.distance:.1f} m, "
              f"{route.duration:.0f} s simulated at {opts.real_time_factor:g}x real time)...",
              flush=True)
        result = run(opts)
    except DemoError as err:
        print(f"[{PROGRAM}] failed: {err}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"[{PROGRAM}] interrupted; every node stopped", file=sys.stderr)
        return 130
    finally:
        signal.signal(signal.SIGTERM, previous)
    print(result.table())
    return 0


