"""``cmd_vel_node``: velocity commands -> wheel velocity commands, limited and watched.

Thin rclpy shell around :class:`diffdrive_odom.core.commands.cmd_vel_pipeline.CommandPipeline`
(validation, watchdog, limits, inverse kinematics, plausibility bound): it declares
parameters, converts messages, logs the pipeline's refusals (one throttle per reason)
and runs one steady timer. Wheel commands go out at ``wheel_command_rate`` whatever
happens on ``cmd_vel`` (drivers use them as a heartbeat); without a valid command for
``cmd_vel_timeout`` seconds they are zeros, never the last command repeated forever.
With ``lockstep`` (a simulation's loop, :mod:`diffdrive_odom.ros.lockstep`) the
heartbeat, the watchdog and the limits run on the simulated clock instead of the
steady one; on a robot nothing changes.
"""

from __future__ import annotations

from typing import Any, cast

from geometry_msgs.msg import TwistStamped
from rclpy.node import Node
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray

from diffdrive_odom.core.commands.cmd_vel_pipeline import (
    JOINT_STATE,
    CmdVelSettings,
    CommandPipeline,
    Tick,
)
from diffdrive_odom.core.health.base_diagnostics import CommandHealth, CommandState, cmd_vel_report
from diffdrive_odom.core.health.diagnostics import RateMeter, Report, Reporter
from diffdrive_odom.ros.cmd_vel_input import CommandInput, Vector
from diffdrive_odom.ros.diagnostics import DiagnosticsPublisher
from diffdrive_odom.ros.lockstep import join
from diffdrive_odom.ros.parameters import ParameterGuard, declare
from diffdrive_odom.ros.qos import RELIABLE_OUT_QOS
from diffdrive_odom.ros.runtime import run
from diffdrive_odom.ros.throttle import WARN_THROTTLE_S, KeyedThrottle
from diffdrive_odom.settings.cmd_vel import CMD_VEL_PARAMS, cmd_vel_settings

NODE_NAME = "cmd_vel_node"
DIAGNOSTIC_TASK = "cmd_vel"  # status "cmd_vel_node: cmd_vel" on /diagnostics
THROTTLE_S = WARN_THROTTLE_S


class CmdVelNode(Node):
    """Turns cmd_vel into wheel velocity commands at a steady rate."""

    # Diagnostics state (see _init_diagnostics).
    _accepted_ns: int | None  # the loop clock's time of the last valid command
    _last_moving: bool  # it asked for motion
    _command_rate: RateMeter
    _output_rate: RateMeter

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(NODE_NAME, **kwargs)
        self._log: Any = cast(Any, self).get_logger()  # rclpy's get_logger is untyped
        self._throttle = KeyedThrottle(self._log)
        values = declare(self, CMD_VEL_PARAMS)
        s = cmd_vel_settings(values)
        self._settings = s
        self._pipeline = CommandPipeline(s)
        # The clock of the heartbeat, watchdog and limits: steady, or simulated in lockstep.
        self._loop = join(self, bool(values["lockstep"]))
        self._loop_clock = self._loop.clock
        self._moving = False  # a command is being followed (for the timeout log)
        self._received = False
        self._type_checked_ns = 0
        self._guard = ParameterGuard(self, values, cmd_vel_settings, self._apply)
        self._init_diagnostics()

        wheel_type = JointState if s.wheel_command_format == JOINT_STATE else Float64MultiArray
        self._publish_wheels = self._loop.publish(self.create_publisher(
            wheel_type, "wheel_commands", RELIABLE_OUT_QOS))
        self._publish_limited: Any = None
        if s.publish_limited_velocity:
            self._make_limited_pub()
        self._input = CommandInput(self, "cmd_vel", s.enable_stamped_cmd_vel, self._accept,
                                   self._loop)
        self._timer = self._make_timer(s.wheel_command_rate)
        g = s.geometry
        self._log.info(
            f"cmd_vel ({'TwistStamped' if s.enable_stamped_cmd_vel else 'Twist'}) -> "
            f"wheel_commands ({s.wheel_command_format}) at {s.wheel_command_rate:g} Hz: "
            f"r_left={g.left_radius:.6g} m, r_right={g.right_radius:.6g} m, "
            f"b={g.separation:.6g} m, timeout {s.cmd_vel_timeout:g} s, "
            f"wheels {list(s.left_wheel_names)} / {list(s.right_wheel_names)}"
        )

    # --- parameters -------------------------------------------------------------

    def _make_timer(self, rate: float) -> Any:
        return self._loop.timer(1.0 / rate, self._on_tick)

    def _make_limited_pub(self) -> None:
        self._publish_limited = self._loop.publish(self.create_publisher(
            TwistStamped, "cmd_vel_out", RELIABLE_OUT_QOS))

    def _apply(self, s: CmdVelSettings) -> None:
        """Install accepted runtime changes; the motion state carries on (no jump)."""
        old = self._settings
        self._settings = s
        self._pipeline.configure(s)
        if s.wheel_command_rate != old.wheel_command_rate:
            self._loop.destroy_timer(self._timer)
            self._timer = self._make_timer(s.wheel_command_rate)
        if s.publish_limited_velocity and self._publish_limited is None:
            self._make_limited_pub()
        self._log.info("parameters updated")

    # --- input ------------------------------------------------------------------

    def _accept(self, lin: Vector, ang: Vector, stamp_ns: int | None) -> None:
        self._received = True
        now_ns = self._loop_clock.now().nanoseconds
        refusal = self._pipeline.accept(lin, ang, now_ns,
                                        self.get_clock().now().nanoseconds, stamp_ns)
        if refusal is not None:
            self._throttle.warning(refusal.reason, refusal.text)
            return
        self._accepted_ns = now_ns
        self._command_rate.add(now_ns * 1e-9)
        self._last_moving = any(p != 0.0 for p in (*lin, *ang))

    # --- output -----------------------------------------------------------------

    def _on_tick(self) -> None:
        now = self._loop_clock.now().nanoseconds
        tick = self._pipeline.tick(now, self.get_clock().now().nanoseconds)
        if tick.refused is not None:
            self._throttle.warning(tick.refused.reason, tick.refused.text)
        elif not tick.commanding:
            if self._moving:
                self._log.info(
                    f"no valid cmd_vel for {self._settings.cmd_vel_timeout:g} s: stopping")
            if not self._received:
                self._check_input_type(now)
        self._moving = tick.commanding
        self._publish(tick)
        self._output_rate.add(now * 1e-9)

    def _publish(self, tick: Tick) -> None:
        s = self._settings
        stamp = self.get_clock().now().to_msg()
        if s.wheel_command_format == JOINT_STATE:
            js = JointState()
            js.header.stamp = stamp
            js.name = list(s.wheel_names)
            js.velocity = list(tick.rates)
            self._publish_wheels(js)
        else:
            self._publish_wheels(Float64MultiArray(data=list(tick.rates)))
        if s.publish_limited_velocity and self._publish_limited is not None:
            ts = TwistStamped()
            ts.header.stamp = stamp
            ts.twist.linear.x = tick.linear
            ts.twist.angular.z = tick.angular
            self._publish_limited(ts)

    # --- diagnostics --------------------------------------------------------------

    def _init_diagnostics(self) -> None:
        start = self._loop_clock.now().nanoseconds * 1e-9
        self._accepted_ns = None
        self._last_moving = False
        self._command_rate = RateMeter(start)
        self._output_rate = RateMeter(start)
        self._reporter = Reporter(cmd_vel_report)
        self._diagnostics = DiagnosticsPublisher(
            self, DIAGNOSTIC_TASK, self._diagnose)

    def _diagnose(self) -> Report:
        now_ns = self._loop_clock.now().nanoseconds
        if self._moving:
            state = CommandState.COMMANDING
        elif self._accepted_ns is None:
            state = CommandState.NEVER
        else:
            state = CommandState.TIMED_OUT
        s = self._settings
        return self._reporter(CommandHealth(
            state=state,
            command_age_s=None if self._accepted_ns is None
            else (now_ns - self._accepted_ns) * 1e-9,
            last_command_moving=self._last_moving,
            limited=dict(self._pipeline.limited),
            dropped=dict(self._pipeline.dropped),
            command_rate_hz=self._command_rate.rate(now_ns * 1e-9),
            output_rate_hz=self._output_rate.rate(now_ns * 1e-9),
            expected_output_hz=s.wheel_command_rate,
            timeout_s=s.cmd_vel_timeout,
        ))

    def _check_input_type(self, now_ns: int) -> None:
        """Nothing ever arrived: say so if cmd_vel's publishers use the other message type."""
        if now_ns - self._type_checked_ns < 2_000_000_000:
            return
        self._type_checked_ns = now_ns
        mismatch = self._input.type_mismatch()
        if mismatch:
            self._log.warning(mismatch, throttle_duration_sec=THROTTLE_S)


def main(args: list[str] | None = None) -> int:
    """Console script / ``ros2 run diffdrive_odom cmd_vel_node``."""
    return run(CmdVelNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
