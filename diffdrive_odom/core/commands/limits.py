"""Velocity / acceleration / jerk limiting of body commands (the watchdog: ``core.watchdog``).

Pure Python (no rclpy): the cmd_vel node, the simulator and the tests share it.

The parameters keep diff_drive_controller's names *and signs* so a user's YAML
carries over (``linear.x.*`` and ``angular.z.*``; NaN = no limit):

===========================  ====  ==================================================
name                         sign  bounds the change of velocity ...
===========================  ====  ==================================================
max_velocity / min_velocity  +/-   the velocity itself (min defaults to -max)
max_acceleration             > 0   speeding up forwards (and from rest)
max_deceleration             < 0   slowing down while moving forwards
max_acceleration_reverse     < 0   speeding up backwards (and from rest)
max_deceleration_reverse     > 0   slowing down while moving backwards
max_jerk / min_jerk          +/-   the change of acceleration while it builds up
===========================  ====  ==================================================

Unset (NaN) values fall back as in control_toolbox's RateLimiter:
``max_acceleration_reverse = -max_acceleration``, ``max_deceleration =
max_acceleration_reverse``, ``max_deceleration_reverse = -max_deceleration``,
``min_jerk = -max_jerk``, ``min_velocity = -max_velocity``.

Where we differ from diff_drive_controller, on purpose:

* a wrong sign (``max_deceleration: 2.0``: a robot that cannot slow down) or a
  velocity range that excludes 0 (a robot that cannot stop) is refused, not used;
* each bound stands on its own: ``max_deceleration`` alone limits braking (the
  controller ignores every acceleration bound unless ``max_acceleration`` is set);
* a step that crosses zero brakes at the deceleration limit only until the stop and
  spends the rest of the period under the *reverse* acceleration limit, instead of
  starting the reverse motion at the (often much larger) braking rate;
* jerk is ``(a - a_prev) / dt`` (the controller's old SpeedLimiter used ``2 dt^2``),
  with the previous acceleration remembered, so it holds for uneven periods too.
  As in control_toolbox it is only limited while the acceleration builds up;
  releasing it is immediate, which avoids the overshoot and oscillation reported
  in control_toolbox#240.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from diffdrive_odom.core.errors import ConfigError
from diffdrive_odom.core.geometry.kinematics import Geometry, scale_to_wheel_limit, wheel_rates
from diffdrive_odom.core.watchdog import Held as Held
from diffdrive_odom.core.watchdog import Watchdog as Watchdog

NAN = math.nan
INF = math.inf


# Why a step's output differs from its target, as LimitedCommand.limited names it.
LIMIT_REASONS = ("velocity", "acceleration", "jerk", "wheel_saturation")


class LimitError(ConfigError):
    """A limit that cannot be used (``field`` is the name within the axis)."""


def _clamp(value: float, low: float, high: float) -> float:
    return low if value < low else high if value > high else value


def _or(value: float, fallback: float) -> float:
    return fallback if math.isnan(value) else value


# field -> (required sign, why): +1 means the value must be > 0, -1 means < 0.
_SIGNED: dict[str, tuple[int, str]] = {
    "max_acceleration": (1, "speeding up forwards raises the velocity"),
    "max_deceleration": (-1, "slowing down while moving forwards lowers the velocity"),
    "max_acceleration_reverse": (-1, "speeding up backwards lowers the velocity"),
    "max_deceleration_reverse": (1, "slowing down while moving backwards raises the velocity"),
    "max_jerk": (1, "it is the upper bound of the change of acceleration"),
    "min_jerk": (-1, "it is the lower bound of the change of acceleration"),
}


@dataclass(frozen=True)
class AxisLimits:
    """diff_drive_controller's limits for one axis (``linear.x`` or ``angular.z``)."""

    max_velocity: float = NAN
    min_velocity: float = NAN
    max_acceleration: float = NAN
    max_deceleration: float = NAN
    max_acceleration_reverse: float = NAN
    max_deceleration_reverse: float = NAN
    max_jerk: float = NAN
    min_jerk: float = NAN

    def __post_init__(self) -> None:
        for name in self.__dataclass_fields__:
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise LimitError(name, f"must be a number or .nan (no limit), got {value!r}")
            if math.isinf(value):
                raise LimitError(name, f"must be finite or .nan (no limit), got {value!r}")
        if self.max_velocity < 0.0:
            raise LimitError("max_velocity", f"must be >= 0 so that the robot can stop, "
                                             f"got {self.max_velocity!r}")
        if self.min_velocity > 0.0:
            raise LimitError("min_velocity", f"must be <= 0 so that the robot can stop, "
                                             f"got {self.min_velocity!r}")
        for name, (sign, why) in _SIGNED.items():
            value = getattr(self, name)
            if not math.isnan(value) and value * sign <= 0.0:
                relation = "> 0" if sign > 0 else "< 0"
                zero = " (0 would forbid any change; .nan = no limit)" if value == 0 else ""
                raise LimitError(name, f"must be {relation} (diff_drive_controller's sign "
                                       f"convention: {why}), got {value!r}{zero}")

    @property
    def velocity_bounds(self) -> tuple[float, float]:
        """(lowest, highest) velocity; +-inf where unlimited."""
        high = _or(self.max_velocity, INF)
        return _or(self.min_velocity, -high), high

    @property
    def forward_bounds(self) -> tuple[float, float]:
        """(max_deceleration, max_acceleration) in effect while moving forwards."""
        return _or(self.max_deceleration, self.reverse_start), _or(self.max_acceleration, INF)

    @property
    def reverse_bounds(self) -> tuple[float, float]:
        """(max_acceleration_reverse, max_deceleration_reverse) while moving backwards."""
        decel = _or(self.max_deceleration, self.reverse_start)
        return self.reverse_start, _or(self.max_deceleration_reverse, -decel)

    @property
    def reverse_start(self) -> float:
        """max_acceleration_reverse after its fallback (-max_acceleration)."""
        return _or(self.max_acceleration_reverse, -_or(self.max_acceleration, INF))

    @property
    def jerk_bounds(self) -> tuple[float, float]:
        """(min_jerk, max_jerk); +-inf where unlimited."""
        high = _or(self.max_jerk, INF)
        return _or(self.min_jerk, -high), high


# diff_drive_controller's deprecated per-axis switches and their fields.
_SWITCHES: dict[str, tuple[str, ...]] = {
    "has_velocity_limits": ("max_velocity", "min_velocity"),
    "has_acceleration_limits": ("max_acceleration", "max_deceleration",
                                "max_acceleration_reverse", "max_deceleration_reverse"),
    "has_jerk_limits": ("max_jerk", "min_jerk"),
}


def ddc_axis_limits(values: dict[str, float | bool]) -> AxisLimits:
    """AxisLimits from one axis' diff_drive_controller parameters, deprecated ones included.

    As Jazzy's diff_drive_controller does: ``has_X_limits: false`` clears those limits
    whatever their values say (so ddc's ``max_jerk: 0.0`` next to ``has_jerk_limits:
    false`` means no jerk limit), and Humble's ``min_acceleration`` (the most negative
    acceleration) is ``max_acceleration_reverse`` when that is not set.
    """
    v = dict(values)
    legacy = v.pop("min_acceleration", NAN)
    if math.isnan(v.get("max_acceleration_reverse", NAN)):
        v["max_acceleration_reverse"] = legacy
    for switch, fields in _SWITCHES.items():
        if v.pop(switch, True) is False:
            v.update(dict.fromkeys(fields, NAN))
    return AxisLimits(**v)  # type: ignore[arg-type]  # the switches are popped


class AxisLimiter:
    """Limits one velocity component step by step; remembers velocity and acceleration."""

    def __init__(self, limits: AxisLimits | None = None) -> None:
        self.limits = limits if limits is not None else AxisLimits()
        self.velocity = 0.0
        self.acceleration = 0.0
        self._previous = 0.0
        self._dt = 0.0
        self.limited_by: tuple[str, ...] = ()  # which bounds changed the last step

    def reset(self, velocity: float = 0.0) -> None:
        """Forget the history: the robot is taken to move at ``velocity`` and not accelerate."""
        self.velocity = self._previous = velocity
        self.acceleration = 0.0
        self._dt = 0.0

    def limit(self, target: float, dt: float) -> float:
        """Return the velocity to command ``dt`` seconds after the last one, towards ``target``."""
        if not math.isfinite(target):
            raise ValueError(f"target must be finite, got {target!r}")
        v0, a0 = self.velocity, self.acceleration
        lim = self.limits
        low, high = lim.velocity_bounds
        if not (dt > 0.0 and math.isfinite(dt)):
            # No time has passed: nothing may change except what the velocity bounds force.
            v = _clamp(v0, low, high)
            self.limited_by = ("velocity",) if v != v0 else ()
            return self._commit(v0, v, 0.0)
        limited_by: list[str] = []
        v = target
        j_low, j_high = lim.jerk_bounds
        if math.isfinite(j_low) or math.isfinite(j_high):
            a = (v - v0) / dt
            if (a - a0) * a > 0.0:  # acceleration building up: limit; releasing is free
                a_limited = _clamp(a, a0 + j_low * dt, a0 + j_high * dt)
                if a_limited != a:
                    limited_by.append("jerk")
                a = a_limited
                v = v0 + a * dt
        v_acc = self._limit_acceleration(v0, v, dt)
        if v_acc != v:
            limited_by.append("acceleration")
        v = _clamp(v_acc, low, high)
        if v != v_acc:
            limited_by.append("velocity")
        self.limited_by = tuple(limited_by)
        return self._commit(v0, v, dt)

    def correct(self, velocity: float) -> None:
        """Replace the last output by what was really commanded (e.g. after wheel scaling).

        Keeps the limiter's idea of the robot's speed honest: braking from a phantom,
        unsaturated speed would delay the real stop.
        """
        self.velocity = velocity
        if self._dt > 0.0:
            self.acceleration = (velocity - self._previous) / self._dt

    def _commit(self, v0: float, v: float, dt: float) -> float:
        self._previous, self.velocity, self._dt = v0, v, dt
        self.acceleration = (v - v0) / dt if dt > 0.0 else 0.0
        return v

    def _limit_acceleration(self, v0: float, v: float, dt: float) -> float:
        lim = self.limits
        acc_rev = lim.reverse_start
        if v0 > 0.0:
            low, high = lim.forward_bounds
        elif v0 < 0.0:
            low, high = lim.reverse_bounds
        else:
            low, high = acc_rev, lim.forward_bounds[1]
        v1 = v0 + _clamp(v - v0, low * dt, high * dt)
        if v0 > 0.0 > v1:
            # Braked through zero: after the stop, reverse acceleration applies.
            rest = dt - (v0 / -low if math.isfinite(low) else 0.0)
            v1 = max(v, acc_rev * rest)
        elif v0 < 0.0 < v1:
            rest = dt - (-v0 / high if math.isfinite(high) else 0.0)
            v1 = min(v, lim.forward_bounds[1] * rest)
        return v1


@dataclass(frozen=True)
class CommandLimits:
    """Limits on the body twist and on each wheel's joint rate (rad/s; NaN or 0 = none)."""

    linear: AxisLimits = field(default_factory=AxisLimits)
    angular: AxisLimits = field(default_factory=AxisLimits)
    max_wheel_velocity: float = NAN

    def __post_init__(self) -> None:
        m = self.max_wheel_velocity
        if isinstance(m, bool) or not isinstance(m, (int, float)) or math.isinf(m) or m < 0.0:
            raise LimitError("max_wheel_velocity",
                             f"must be > 0 [rad/s], or 0 / .nan for no limit, got {m!r}")


@dataclass(frozen=True)
class LimitedCommand:
    """What one limiter step commands: the body twist and the joint rates (rad/s)."""

    linear: float
    angular: float
    left: float
    right: float
    wheel_scale: float
    # The bounds that changed this step (names from LIMIT_REASONS); () = followed as asked.
    limited: tuple[str, ...] = ()


class TwistLimiter:
    """Body-twist limits, inverse kinematics, then curvature-keeping wheel saturation."""

    def __init__(self, limits: CommandLimits, geometry: Geometry) -> None:
        self.linear = AxisLimiter(limits.linear)
        self.angular = AxisLimiter(limits.angular)
        self.limits = limits
        self.geometry = geometry

    def configure(self, limits: CommandLimits, geometry: Geometry) -> None:
        """Install new limits/geometry (runtime change); the motion state carries on."""
        self.linear.limits, self.angular.limits = limits.linear, limits.angular
        self.limits, self.geometry = limits, geometry

    def reset(self) -> None:
        """Take the robot to be at rest."""
        self.linear.reset()
        self.angular.reset()

    def step(self, linear: float, angular: float, dt: float) -> LimitedCommand:
        """Limit the twist (v [m/s], w [rad/s]) ``dt`` seconds after the previous step."""
        v, w, left, right, scale = self._wheels(self.linear.limit(linear, dt),
                                                self.angular.limit(angular, dt))
        if scale != 1.0:
            self.linear.correct(v)
            self.angular.correct(w)
        acted = {*self.linear.limited_by, *self.angular.limited_by}
        if scale != 1.0:
            acted.add("wheel_saturation")
        limited = tuple(r for r in LIMIT_REASONS if r in acted)
        return LimitedCommand(v, w, left, right, scale, limited)

    def settled(self, linear: float, angular: float) -> tuple[float, float]:
        """The joint rates a held twist is limited to: velocity bounds, wheel saturation.

        Acceleration and jerk only shape the way there, so this is the target a command
        is judged by (the cmd_vel plausibility check). Overflow shows as inf/NaN.
        """
        v = _clamp(linear, *self.linear.limits.velocity_bounds)
        w = _clamp(angular, *self.angular.limits.velocity_bounds)
        _, _, left, right, _ = self._wheels(v, w)
        return left, right

    def _wheels(self, v: float, w: float) -> tuple[float, float, float, float, float]:
        """IK then curvature-keeping saturation: (v, w, left, right, scale) as commanded."""
        left, right = wheel_rates(self.geometry, v, w)
        left, right, scale = scale_to_wheel_limit(left, right, self.limits.max_wheel_velocity)
        if scale != 1.0:
            v, w = v * scale, w * scale  # the IK is linear: the twist these wheels give
        return v, w, left, right, scale
