"""One cmd_vel command's path and one wheel_commands tick, without rclpy.

The cmd_vel node is a shell around :class:`CommandPipeline`: every rule between a
received Twist and the numbers a driver gets lives here, in this order. A command
is refused (and counted by reason) when a part is NaN/inf, when its stamp is older
than ``cmd_vel_timeout``, or when the wheel targets it leads to -- after the control
point, the inverse kinematics, the velocity bounds and the wheel saturation, in the
output unit -- are not finite or beyond ``max_plausible_wheel_velocity``. A refused
command is as if it never arrived: the one before it stays in force until its timeout.
Each tick checks its own output against the same bound, so nothing absurd gets out
whatever path it took (e.g. a runtime change of the geometry); it then sends zeros.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from diffdrive_odom.core.commands.limits import LIMIT_REASONS, CommandLimits, TwistLimiter, Watchdog
from diffdrive_odom.core.geometry.kinematics import Geometry, point_velocity_to_twist

# The wheel_commands formats, here once: the sim reads what the cmd_vel node writes.
FLOAT64_ARRAY = "float64_array"
JOINT_STATE = "joint_state"
TICKS_PER_SECOND = "ticks_per_second"
WHEEL_COMMAND_FORMATS: tuple[str, ...] = (FLOAT64_ARRAY, JOINT_STATE, TICKS_PER_SECOND)

NON_FINITE = "non_finite"
STALE_STAMP = "stale_stamp"
IMPLAUSIBLE = "implausible"
# Why a command is refused (the /diagnostics "dropped" counters).
DROP_REASONS = (NON_FINITE, STALE_STAMP, IMPLAUSIBLE)


@dataclass(frozen=True)
class Command:
    """The parts of a Twist the kinematics use."""

    linear_x: float
    linear_y: float
    angular_z: float


@dataclass(frozen=True)
class Refusal:
    """Why a command (or a tick's output) was not forwarded; ``text`` is for the log."""

    reason: str  # one of DROP_REASONS
    text: str


@dataclass(frozen=True)
class Tick:
    """What one wheel_commands tick sends."""

    rates: tuple[float, ...]  # left wheels then right wheels, in the output unit
    linear: float  # the body twist these rates give (cmd_vel_out)
    angular: float
    commanding: bool  # a command is followed (False: the watchdog's zeros)
    refused: Refusal | None = None  # the output was implausible: zeros instead


@dataclass(frozen=True)
class CmdVelSettings:
    """All validated settings of the cmd_vel node (``settings.cmd_vel`` builds it)."""

    geometry: Geometry
    left_wheel_names: tuple[str, ...]
    right_wheel_names: tuple[str, ...]
    ticks_per_revolution: float
    enable_stamped_cmd_vel: bool
    wheel_command_format: str
    cmd_vel_timeout: float
    wheel_command_rate: float
    publish_limited_velocity: bool
    control_point_offset: float
    limits: CommandLimits
    max_plausible_wheel_velocity: float

    @property
    def output_per_rad_s(self) -> float:
        """wheel_commands units per rad/s: 1, or counts per radian for ticks_per_second."""
        if self.wheel_command_format == TICKS_PER_SECOND:
            return self.ticks_per_revolution / (2.0 * math.pi)
        return 1.0

    @property
    def output_unit(self) -> str:
        """The unit of wheel_commands, for messages."""
        return "counts/s" if self.wheel_command_format == TICKS_PER_SECOND else "rad/s"

    @property
    def wheel_names(self) -> tuple[str, ...]:
        """Left wheels then right wheels: the order of every wheel command."""
        return self.left_wheel_names + self.right_wheel_names


class CommandPipeline:
    """Validation, watchdog, control point, limits, IK and the plausibility bound."""

    def __init__(self, settings: CmdVelSettings) -> None:
        self.settings = settings
        self.limiter = TwistLimiter(settings.limits, settings.geometry)
        self.watchdog: Watchdog[Command] = Watchdog(settings.cmd_vel_timeout)
        self.dropped = dict.fromkeys(DROP_REASONS, 0)
        self.limited = dict.fromkeys(LIMIT_REASONS, 0)
        self._counted_limits: set[str] = set()  # limits already counted for the held command
        self._last_tick_ns: int | None = None

    def configure(self, settings: CmdVelSettings) -> None:
        """Install accepted runtime changes; the motion state carries on (no jump)."""
        self.settings = settings
        self.limiter.configure(settings.limits, settings.geometry)
        self.watchdog.timeout_ns = round(settings.cmd_vel_timeout * 1e9)

    @property
    def bound(self) -> float:
        """The plausibility bound in the output unit."""
        s = self.settings
        return s.max_plausible_wheel_velocity * s.output_per_rad_s

    def accept(self, linear: Sequence[float], angular: Sequence[float], steady_ns: int,
               ros_now_ns: int, stamp_ns: int | None = None) -> Refusal | None:
        """Take a Twist (x, y, z parts) as the command to follow, or say why not."""
        refusal = self._check(linear, angular, ros_now_ns, stamp_ns)
        if refusal is not None:
            self.dropped[refusal.reason] += 1
            return refusal
        self.watchdog.accept(Command(linear[0], linear[1], angular[2]), steady_ns, stamp_ns)
        self._counted_limits = set()
        return None

    def tick(self, steady_ns: int, ros_now_ns: int) -> Tick:
        """The wheel commands for now: the held command through the limits, or zeros."""
        s = self.settings
        period = 1.0 / s.wheel_command_rate
        last, self._last_tick_ns = self._last_tick_ns, steady_ns
        # Measured period, capped: after a stall the limits must not allow a leap.
        dt = period if last is None else min((steady_ns - last) * 1e-9, 2.0 * period)
        command = self.watchdog.current(steady_ns, ros_now_ns)
        linear, angular = (0.0, 0.0) if command is None else self._body_twist(command)
        if not (math.isfinite(linear) and math.isfinite(angular)):
            linear, angular = 0.0, 0.0  # accept() refuses these: only a runtime change gets here
        out = self.limiter.step(linear, angular, dt)
        if command is not None:
            for reason in out.limited:  # each command counts once per limit that acted
                if reason not in self._counted_limits:
                    self._counted_limits.add(reason)
                    self.limited[reason] += 1
        rates = self._rates(out.left, out.right)
        refusal = self._implausible(rates, "wheel_commands output")
        if refusal is None:
            return Tick(rates, out.linear, out.angular, command is not None)
        self.dropped[IMPLAUSIBLE] += 1
        self.watchdog.clear()
        self.limiter.reset()
        return Tick(self._rates(0.0, 0.0), 0.0, 0.0, False, refusal)

    def _check(self, linear: Sequence[float], angular: Sequence[float], ros_now_ns: int,
               stamp_ns: int | None) -> Refusal | None:
        parts = (*linear, *angular)
        if not all(math.isfinite(p) for p in parts):
            return Refusal(NON_FINITE, f"cmd_vel with NaN/inf ignored: linear={tuple(linear)} "
                                       f"angular={tuple(angular)}")
        if stamp_ns is not None and self.watchdog.is_stale(stamp_ns, ros_now_ns):
            return Refusal(STALE_STAMP, f"stale cmd_vel ignored: stamped "
                                        f"{(ros_now_ns - stamp_ns) * 1e-9:.3f} s ago, "
                                        f"cmd_vel_timeout is {self.settings.cmd_vel_timeout:g} s")
        v, w = self._body_twist(Command(linear[0], linear[1], angular[2]))
        left, right = self.limiter.settled(v, w)
        return self._implausible(self._rates(left, right),
                                 f"cmd_vel linear={tuple(linear)} angular={tuple(angular)}")

    def _implausible(self, rates: tuple[float, ...], what: str) -> Refusal | None:
        bound = self.bound
        if all(math.isfinite(r) and abs(r) <= bound for r in rates):
            return None
        s = self.settings
        return Refusal(IMPLAUSIBLE, f"implausible cmd_vel refused ({what}): wheel targets "
                                    f"{list(rates)} {s.output_unit} are not finite or beyond "
                                    f"max_plausible_wheel_velocity ({bound:g} {s.output_unit})")

    def _body_twist(self, c: Command) -> tuple[float, float]:
        offset = self.settings.control_point_offset
        if offset != 0.0:
            return point_velocity_to_twist(offset, c.linear_x, c.linear_y)
        return c.linear_x, c.angular_z

    def _rates(self, left: float, right: float) -> tuple[float, ...]:
        """Joint rates [rad/s] -> one value per wheel in the output unit."""
        s = self.settings
        k = s.output_per_rad_s
        return (left * k,) * len(s.left_wheel_names) + (right * k,) * len(s.right_wheel_names)
