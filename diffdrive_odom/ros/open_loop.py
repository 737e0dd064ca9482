"""``odometry_node`` with ``open_loop: true``: odometry from the commanded velocity.

Thin rclpy shell around :class:`diffdrive_odom.core.estimation.open_loop.OpenLoopOdometry`
(the one ``replay`` runs too): commands come in through the cmd_vel node's own
subscription (:class:`~diffdrive_odom.ros.cmd_vel_input.CommandInput`: its type, QoS and
zero-stamp rule), on ``cmd_vel`` or the cmd_vel node's limited ``cmd_vel_out``
(``open_loop_source``), each at its arrival on the node's clock. There are no readings to
publish on, so a timer on the node's clock (simulated time included) publishes the pose
at ``publish_rate`` (50 Hz when 0). ``joint_states`` is not subscribed: a fixed switch,
as in diff_drive_controller, not a fallback. Same topics, frames, QoS, reset service,
``~/set_pose`` and publication rule (nothing non-finite goes out) as with encoders;
``/diagnostics`` says "open loop".
"""

from __future__ import annotations

import time

from rclpy.node import Node

from diffdrive_odom.core.estimation.config import OdometrySettings
from diffdrive_odom.core.estimation.open_loop import (
    TIME_RESET,
    OpenLoopOdometry,
    publication_rate,
)
from diffdrive_odom.core.estimation.publication import Refusal, publication
from diffdrive_odom.core.estimation.setpose import PoseRefusal, PoseRequest
from diffdrive_odom.core.health.diagnostics import RateMeter, Report, Reporter
from diffdrive_odom.core.health.open_loop_health import OpenLoopHealth, open_loop_report
from diffdrive_odom.ros.cmd_vel_input import CommandInput, Vector
from diffdrive_odom.ros.diagnostics import DiagnosticsPublisher
from diffdrive_odom.ros.parameters import ParameterGuard
from diffdrive_odom.ros.publishers import OdometryOutput, frames_text
from diffdrive_odom.ros.set_pose import PoseInputs
from diffdrive_odom.ros.throttle import KeyedThrottle
from diffdrive_odom.settings.errors import ParameterError
from diffdrive_odom.settings.odometry import odometry_settings
from diffdrive_odom.settings.params import ParamValue

DROP_TEXT = {"non_finite": "velocity command with NaN/inf ignored",
             "stale_stamp": "stale velocity command ignored (stamped over cmd_vel_timeout ago)",
             "no_clock": "velocity command ignored: the node's clock reads zero (use_sim_time "
                         "and no /clock yet)"}


class OpenLoopEndpoints:
    """Everything ``odometry_node`` does in open loop, on the node it is given.

    The same interface as :class:`~diffdrive_odom.ros.odometry_node.OdometryEndpoints`
    (built with the node's parameter values, :meth:`destroy`), so the plain and the
    managed node take either. Raises ParameterError for values that cannot work.
    """

    def __init__(self, node: Node, values: dict[str, ParamValue]) -> None:
        self._node = node
        if values.get("lockstep") is True:  # its own timer publishes: no step to answer
            raise ParameterError("lockstep", "cannot be true with open_loop (open-loop "
                                 "odometry publishes on its own timer, not on readings)")
        settings = self._build(values)
        cfg = settings.open_loop
        assert cfg is not None  # _build refuses settings without it
        self._settings = settings
        self._output = OdometryOutput(node, settings)
        self._odo = OpenLoopOdometry(cfg, settings.geometry,
                                     settings.estimator.time_jump_threshold)
        self._throttle = KeyedThrottle(node.get_logger())
        self._guard = ParameterGuard(node, values, self._build, self._apply)
        self._input = CommandInput(node, cfg.topic, cfg.stamped, self._on_command)
        self._pose_inputs = PoseInputs(node, self._odo.reset, self, self._throttle)
        self._rate_hz = publication_rate(settings.publish_rate)
        self._timer = node.create_timer(1.0 / self._rate_hz, self._on_timer)
        self._last_rx: float | None = None
        self._commands = RateMeter(start=time.monotonic())
        self._reporter = Reporter(open_loop_report)
        self._diagnostics = DiagnosticsPublisher(node, "odometry", self._diagnose)
        topic = self._input.subscription.topic_name
        node.get_logger().info(
            f"open loop: odometry from the commanded velocity on {topic} "
            f"({self._input.type_name.rsplit('/', 1)[-1]}), held for cmd_vel_timeout "
            f"{cfg.timeout:g} s, published at {self._rate_hz:g} Hz; joint_states is not "
            f"read; {frames_text(settings)}")

    def destroy(self) -> None:
        """Remove every endpoint, timer and parameter check from the node; the pose goes."""
        node = self._node
        self._guard.close()
        self._diagnostics.destroy()
        node.destroy_timer(self._timer)
        self._pose_inputs.destroy()
        self._input.destroy()
        self._output.destroy()

    def _build(self, values: dict[str, ParamValue]) -> OdometrySettings:
        settings = odometry_settings(values, self._node.get_namespace())
        if settings.open_loop is None:  # open_loop is read-only: only a bug gets here
            raise ParameterError("open_loop", "is read-only (true at start)")
        return settings

    def _apply(self, settings: OdometrySettings) -> None:
        """Install accepted runtime changes; the pose and the held command carry on."""
        assert settings.open_loop is not None
        self._settings = settings
        self._odo.configure(settings.open_loop, settings.geometry)
        self._odo.jump_ns = round(settings.estimator.time_jump_threshold * 1e9)
        self._output.configure(settings)
        rate = publication_rate(settings.publish_rate)
        if rate != self._rate_hz:
            self._rate_hz = rate
            self._node.destroy_timer(self._timer)
            self._timer = self._node.create_timer(1.0 / rate, self._on_timer)
        self._node.get_logger().info("parameters updated")

    def _now_ns(self) -> int:
        return int(self._node.get_clock().now().nanoseconds)

    def _on_command(self, lin: Vector, ang: Vector, stamp_ns: int | None) -> None:
        self._last_rx = t = time.monotonic()
        self._commands.add(t)
        code = self._odo.command(self._now_ns(), lin[0], ang[2], stamp_ns)
        if code == TIME_RESET:
            self._time_reset()
        elif code:
            self._throttle.warning(f"open_loop_{code}", f"{DROP_TEXT[code]} [{code}]: linear="
                                   f"{lin} angular={ang}")

    def _time_reset(self) -> None:
        self._node.get_logger().warning(
            "open loop: the clock went back over time_jump_threshold: odometry restarted "
            "at the origin, no command held")

    def _on_timer(self) -> None:
        now = self._now_ns()
        if now <= 0:  # simulated time before the first /clock: no stamp to publish with
            return
        if self._odo.advance(now) == TIME_RESET:
            self._time_reset()
        odo = self._odo
        out = publication(odo.pose, odo.linear, odo.angular, *odo.covariances())
        if isinstance(out, Refusal):
            self._throttle.warning(out.code, out.reason)
            return
        self._output.publish(now, out)

    def set_pose(self, request: PoseRequest) -> str | PoseRefusal:
        """``~/set_pose`` (the same subscription as with encoders), in the odom frame."""
        return self._odo.set_pose(request, self._settings.odom_frame_id)

    def _diagnose(self) -> Report:
        now = time.monotonic()
        assert self._settings.open_loop is not None
        if self._last_rx is None and (mismatch := self._input.type_mismatch()):
            self._throttle.warning("cmd_vel_type", mismatch)  # nothing can ever arrive
        return self._reporter(OpenLoopHealth(
            topic=self._input.subscription.topic_name,
            command_rate_hz=self._commands.rate(now),
            since_last_command_s=None if self._last_rx is None else now - self._last_rx,
            timeout_s=self._settings.open_loop.timeout,
            stats=self._odo.stats,
        ))
