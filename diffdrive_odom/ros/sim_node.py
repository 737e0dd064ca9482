"""``sim_node``: a simulated differential-drive base on DDS.

Thin rclpy shell around :class:`diffdrive_odom.core.sim.model.DiffDriveSim`: it takes the
cmd_vel node's wheel commands, steps the simulation at a fixed rate and publishes
what a real base's driver would (``joint_states``, header-stamped, radians or
ticks; with ``imu_rate`` a gyro on ``imu``: the true yaw rate over each sample's
period, stamped at its middle, bias, white noise) plus
what only a simulator knows: the true pose on ``ground_truth/odom``. Scripted
``slip_events`` make a wheel spin without moving the ground.

Time: by default the node follows its own clock (wall time, or ``/clock`` when run
with ``use_sim_time``). With ``publish_clock`` it owns the time instead: it advances
in fixed steps of simulated time, ``real_time_factor`` times faster than the wall,
and publishes ``/clock`` so the other nodes (``use_sim_time:=true``) and the stamps
agree. A slow machine then slows the simulated world down instead of making it
jerky: every step is exactly ``1 / joint_state_rate`` simulated seconds. With
``lockstep`` it owns the time and waits for the loop (:mod:`diffdrive_odom.ros.lockstep`):
each step is two phases, each sent once the loop has answered the one before: ``/clock``
(the nodes' timers due then run), then the readings of that instant (the odometry, the
follower and the cmd_vel node answer them); then the physics moves one step on the
wheel command the loop sent. The same run gives the same messages, however loaded the
machine.

Like the other nodes it reports its health on ``/diagnostics`` (status
"sim_node: simulation", :func:`diffdrive_odom.core.health.base_diagnostics.sim_report`): the step
and command rates, the age of the last wheel command and the watchdog's state, the
wheel commands it refused.
"""

from __future__ import annotations

import math
import time
from enum import Enum
from typing import Any

from nav_msgs.msg import Odometry
from rclpy.clock import Clock
from rclpy.clock_type import ClockType
from rclpy.node import Node
from rosgraph_msgs.msg import Clock as ClockMsg
from sensor_msgs.msg import Imu, JointState
from std_msgs.msg import Float64MultiArray

from diffdrive_odom.core.commands.cmd_vel_pipeline import JOINT_STATE, TICKS_PER_SECOND
from diffdrive_odom.core.estimation.wheels.encoders import EncoderConfig, JointLookup
from diffdrive_odom.core.health.base_diagnostics import CommandState, SimHealth, sim_report
from diffdrive_odom.core.health.diagnostics import RateMeter, Report, Reporter
from diffdrive_odom.core.sim.model import TWO_PI, DiffDriveSim
from diffdrive_odom.ros.diagnostics import DiagnosticsPublisher
from diffdrive_odom.ros.lockstep import Alone, Conductor
from diffdrive_odom.ros.parameters import ParameterGuard, declare
from diffdrive_odom.ros.qos import CMD_IN_QOS, RELIABLE_OUT_QOS, qos
from diffdrive_odom.ros.runtime import run
from diffdrive_odom.ros.throttle import WARN_THROTTLE_S
from diffdrive_odom.settings.params import ParamValue
from diffdrive_odom.settings.sim import SIM_PARAMS, TICKS, SimSettings, sim_settings
from diffdrive_odom.wire.conversions import ns_to_stamp, yaw_to_quaternion

NODE_NAME = "sim_node"
MAX_STEP_NS = 1_000_000_000  # a clock jump larger than this is not simulated as motion
CLOCK_QOS = qos(1, reliable=True)
# Lockstep's clock starts here, the same every run (not at 0: a zero stamp means "unset"
# to ROS tools and to the odometry's gyro).
LOCKSTEP_START_NS = 1_000_000_000


class Phase(Enum):
    """What of a lockstep step was sent last: its /clock, or its readings."""

    CLOCK = "/clock"
    READINGS = "readings"


class SimNode(Node):
    """Simulated base: wheel commands in; joint_states, ground truth (and /clock) out."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(NODE_NAME, **kwargs)
        self._log: Any = self.get_logger()
        values = declare(self, SIM_PARAMS)
        s = sim_settings(values)
        self._settings = s
        self._sim = DiffDriveSim(s.config)
        self._lookup = JointLookup(EncoderConfig(s.left_wheel_names, s.right_wheel_names))
        self._guard = ParameterGuard(self, values, self._build, self._apply)
        self._step_ns = round(1e9 / s.joint_state_rate)
        # The simulated clock starts at the wall time, or in lockstep at a fixed time.
        self._start_ns = LOCKSTEP_START_NS if s.lockstep else time.time_ns()
        self._last_clock_ns: int | None = None
        started = time.monotonic()
        self._steps = RateMeter(start=started)
        self._commands = RateMeter(start=started)
        self._last_moving = False
        self._dropped: dict[str, int] = {}
        self._reporter = Reporter(sim_report)
        self._phase = Phase.READINGS
        self._imu_due: list[Imu] = []  # lockstep: the step's gyro samples, sent with its readings
        loop = self._loop = (Conductor(self, s.lockstep_nodes, self._lockstep_start,
                                       self._lockstep_step, self._lockstep_where)
                             if s.lockstep else Alone(self))

        self._publish_joints = loop.publish(self.create_publisher(
            JointState, "joint_states", RELIABLE_OUT_QOS))
        self._publish_truth = loop.publish(self.create_publisher(
            Odometry, "ground_truth/odom", RELIABLE_OUT_QOS))
        self._publish_imu: Any = None
        self._publish_clock_msg: Any = None
        self._imu_per_step = max(1, round(s.imu_rate / s.joint_state_rate))
        if s.imu_rate > 0.0:  # read-only: on or off for the node's life
            self._publish_imu = loop.publish(self.create_publisher(
                Imu, "imu", RELIABLE_OUT_QOS))
        owns_clock = s.publish_clock or s.lockstep
        if owns_clock:
            self._publish_clock_msg = loop.publish(self.create_publisher(
                ClockMsg, "/clock", CLOCK_QOS))
        if s.wheel_command_format == JOINT_STATE:
            loop.subscription(JointState, "wheel_commands", self._on_joint_command, CMD_IN_QOS)
        else:
            loop.subscription(
                Float64MultiArray, "wheel_commands", self._on_array_command, CMD_IN_QOS)
        if s.lockstep:
            pass  # the Conductor starts and steps it
        elif s.publish_clock:
            # Wall-clock (steady) timer: the node drives /clock, it must not wait on it.
            steady = Clock(clock_type=ClockType.STEADY_TIME)
            period = 1.0 / (s.joint_state_rate * s.real_time_factor)
            self.create_timer(period, self._on_sim_tick, clock=steady)
        else:
            self.create_timer(1.0 / s.joint_state_rate, self._on_clock_tick)
        g = s.config.geometry
        self._log.info(
            f"simulated base: true r_left={g.left_radius:.6g} m, r_right={g.right_radius:.6g} m, "
            f"b={g.separation:.6g} m, signs {g.left_wheel_sign:+d}/{g.right_wheel_sign:+d}, "
            f"joint_states in {s.joint_state_units} at {s.joint_state_rate:g} Hz"
            + (f", /clock in lockstep with {', '.join(s.lockstep_nodes)}" if s.lockstep
               else f", /clock at {s.real_time_factor:g}x real time" if s.publish_clock
               else "")
        )
        self._diagnostics = DiagnosticsPublisher(self, "simulation", self._diagnose)
        if not s.lockstep:
            self._publish(self._start_ns)

    def _diagnose(self) -> Report:
        """The /diagnostics status: rates, the last command's age, the watchdog, drops."""
        s, sim, now = self._settings, self._sim, time.monotonic()
        timeout = s.config.command_timeout
        last = sim.last_command_ns
        age = None if last is None else (sim.time_ns - last) * 1e-9
        state = (CommandState.NEVER if age is None else
                 CommandState.TIMED_OUT if timeout > 0.0 and age >= timeout else
                 CommandState.COMMANDING)
        return self._reporter(SimHealth(
            state=state, command_age_s=age, last_command_moving=self._last_moving,
            command_rate_hz=self._commands.rate(now), step_rate_hz=self._steps.rate(now),
            expected_step_hz=(0.0 if s.lockstep  # as fast as the loop answers
                              else s.joint_state_rate * (s.real_time_factor if s.publish_clock
                                                         else 1.0)),
            timeout_s=timeout, sim_time_s=sim.time_ns * 1e-9, distance_m=sim.distance,
            dropped=dict(self._dropped)))

    # --- parameters -------------------------------------------------------------

    def _build(self, values: dict[str, ParamValue]) -> SimSettings:
        return sim_settings(values)

    def _apply(self, settings: SimSettings) -> None:
        """Accepted runtime change: new physics from now on, the robot stays where it is."""
        self._settings = settings
        self._sim.reconfigure(settings.config)
        self._log.info("parameters updated")

    # --- commands ---------------------------------------------------------------

    def _warn(self, text: str) -> None:
        self._log.warning(text, throttle_duration_sec=WARN_THROTTLE_S)

    def _drop(self, code: str, text: str) -> None:
        """Refuse a wheel command: counted for /diagnostics, a throttled warning."""
        self._dropped[code] = self._dropped.get(code, 0) + 1
        self._warn(text)

    def _command(self, rates: list[float]) -> None:
        if not all(math.isfinite(r) for r in rates):
            self._drop("non_finite", "wheel command with NaN/inf dropped")
            return
        self._sim.command(rates)
        self._commands.add(time.monotonic())
        self._last_moving = any(r != 0.0 for r in rates)

    def _on_array_command(self, msg: Float64MultiArray) -> None:
        data = list(msg.data)
        n = self._sim.config.joints
        if len(data) != n:
            self._drop("bad_array", f"wheel command with {len(data)} values dropped: "
                       f"expected {n} ({', '.join(self._settings.wheel_names)})")
            return
        if self._settings.wheel_command_format == TICKS_PER_SECOND:
            scale = TWO_PI / self._sim.config.ticks_per_revolution
            data = [d * scale for d in data]
        self._command(data)

    def _on_joint_command(self, msg: JointState) -> None:
        idx = self._lookup.indices(msg.name)
        if idx is None:
            self._drop("missing_joint", "wheel command JointState lacks a wheel joint: dropped")
            return
        if len(msg.velocity) != len(msg.name):
            self._drop("bad_array", f"wheel command JointState has {len(msg.velocity)} "
                       f"velocities for {len(msg.name)} names: dropped")
            return
        self._command([float(msg.velocity[i]) for i in idx])

    # --- time -------------------------------------------------------------------

    def _advance(self, dt_ns: int, end_ns: int) -> list[Imu]:
        """Move the simulation to ``end_ns``; with an IMU, a gyro sample per piece.

        A sample is the mean rate over its piece: it is stamped at the piece's middle,
        the time that mean belongs to (stamped at the end it would lag half a piece).
        The samples are returned, for the caller to publish before the step's readings.
        """
        if self._publish_imu is None:
            self._sim.advance(dt_ns)
            return []
        n = self._imu_per_step
        rate = n * 1e9 / dt_ns
        samples = []
        for i in range(n):
            a, b = dt_ns * i // n, dt_ns * (i + 1) // n
            self._sim.advance(b - a)
            msg = Imu()
            ns_to_stamp(end_ns - dt_ns + (a + b) // 2, msg.header.stamp)
            msg.header.frame_id = self._settings.imu_frame_id
            msg.orientation_covariance[0] = -1.0  # no orientation (REP-145)
            msg.linear_acceleration_covariance[0] = -1.0
            msg.angular_velocity.z = self._sim.gyro(rate)
            samples.append(msg)
        return samples

    def _now_ns(self) -> int:
        """The simulated clock (owned by this node) now."""
        return self._start_ns + self._sim.time_ns

    def _send_clock(self) -> None:
        clock = ClockMsg()
        ns_to_stamp(self._now_ns(), clock.clock)
        self._publish_clock_msg(clock)

    def _on_sim_tick(self) -> None:
        """publish_clock: one fixed step of simulated time."""
        samples = self._advance(self._step_ns, self._now_ns() + self._step_ns)
        for msg in samples:
            self._publish_imu(msg)
        self._send_clock()
        self._publish(self._now_ns())

    def _lockstep_start(self) -> None:
        """Lockstep: the loop is up; the first step's /clock."""
        self._log.info("lockstep: every node of the loop has answered; stepping")
        self._phase = Phase.CLOCK
        self._send_clock()

    def _lockstep_step(self) -> bool:
        """Lockstep: the loop answered the last phase; the next one (True: a /clock).

        After the /clock: this instant's readings (its gyro samples first), then at once
        the physics one step on the wheel command the loop sent at the /clock, while the
        loop answers the readings (no wheel command comes meanwhile). After the readings:
        the next step's /clock.
        """
        if self._phase is Phase.CLOCK:
            self._phase = Phase.READINGS
            for msg in self._imu_due:
                self._publish_imu(msg)
            now = self._now_ns()
            self._publish(now)
            self._imu_due = self._advance(self._step_ns, now + self._step_ns)
        else:
            self._phase = Phase.CLOCK
            self._send_clock()
        return self._phase is Phase.CLOCK

    def _lockstep_where(self) -> str:
        """The step the loop owes an answer to, for the guard's warning."""
        at = self._now_ns() - self._start_ns - (self._step_ns if self._phase is Phase.READINGS
                                               else 0)
        return f"the {self._phase.value} of the step at {at * 1e-9:.3f} s (simulated)"

    def _on_clock_tick(self) -> None:
        """Follow the node's clock: advance by however much time really passed."""
        now_ns = self.get_clock().now().nanoseconds
        last, self._last_clock_ns = self._last_clock_ns, now_ns
        if last is None or now_ns <= last:
            return  # first tick, or time went backwards (a bag restarted): re-anchor
        dt = now_ns - last
        if dt > MAX_STEP_NS:
            self._warn(f"clock jumped {dt * 1e-9:.3f} s: simulating {MAX_STEP_NS * 1e-9:g} s")
            dt = MAX_STEP_NS
        for msg in self._advance(dt, now_ns):
            self._publish_imu(msg)
        self._publish(now_ns)

    # --- output -----------------------------------------------------------------

    def _publish(self, stamp_ns: int) -> None:
        self._steps.add(time.monotonic())
        s, sim = self._settings, self._sim
        js = JointState()
        ns_to_stamp(stamp_ns, js.header.stamp)
        js.name = list(s.wheel_names)
        if s.joint_state_units == TICKS:
            js.position = [float(c) for c in sim.encoder_counts()]
            per_rad = sim.config.ticks_per_revolution / TWO_PI
            js.velocity = [float(r) * per_rad for r in sim.joint_rates]
        else:
            js.position = [float(a) for a in sim.encoder_radians()]
            js.velocity = [float(r) for r in sim.joint_rates]
        self._publish_joints(js)

        pose, twist = sim.pose, sim.twist
        odom = Odometry()
        odom.header.stamp = js.header.stamp
        odom.header.frame_id = s.world_frame_id
        odom.child_frame_id = s.base_frame_id
        p = odom.pose.pose
        p.position.x, p.position.y = pose.x, pose.y
        qx, qy, qz, qw = yaw_to_quaternion(pose.theta)
        p.orientation.x, p.orientation.y, p.orientation.z, p.orientation.w = qx, qy, qz, qw
        odom.twist.twist.linear.x = twist.linear
        odom.twist.twist.angular.z = twist.angular
        self._publish_truth(odom)


def main(args: list[str] | None = None) -> int:
    """Console script / ``ros2 run diffdrive_odom sim_node``."""
    return run(SimNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
