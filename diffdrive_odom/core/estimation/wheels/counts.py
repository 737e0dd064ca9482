"""What the counts have done, and what they say: the interval a step is judged over, a gap.

Positions only (velocities say nothing between two readings). Two rules read the
counts' own history, kept in :class:`CountTrack` beside the reference:

- **a step is judged over the time since the counts last changed** (capped at
  ``max_reading_gap``): a driver or logger that holds a reading (repeats its counts) and
  then releases the moved counts with a stamp just after the last adds the whole hold's
  motion in one step, and it belongs to the whole interval, where the wheels' speed
  before the hold explains it within ``max_wheel_acceleration`` (:func:`carried_on`: a
  spike on the released reading is judged over its own step) (:meth:`CountTrack.judged`,
  its array form for the fast lane :func:`judged_steps`);
- **a gap is a restart only where the counts say so.** A reading more than
  ``max_reading_gap`` after the last usable one that the next reading continues (a
  real pause, not a lone outlier: :mod:`~.wheels.estimator`) ends either a gap in the
  log, over which counters that went on counting hold the motion exactly (a
  differential drive's heading change depends on the two counts alone), or a driver
  restart, over which their difference says nothing (:func:`gap_motion`). A restart:

  - every counter back at zero (within twice what it moved in the step after the gap:
    a driver that restarted a period or two before its first reading), or back at the
    values the timeline started with;
  - the step after the gap implausible;
  - a wheel whose mean speed over the gap is outside what it showed just before and
    just after, widened by what ``max_wheel_acceleration`` ``A`` allows: a wheel going
    from ``v0`` to ``v1`` over ``T`` averages at most ``max(v0, v1) + A T / 4`` (speeding
    up half the gap, slowing down the other half) and at least
    ``min(v0, v1) - A T / 4``, and never faster than ``max_wheel_speed``. A counter
    that jumped back (restarted from a value it kept) or forward lands outside unless
    the gap was long enough for the wheel to drive it;
  - a wrapping counter (``encoder_counter_bits``) whose difference, read as any whole
    number of wraps, falls in that range more than once: the counts cannot tell which
    (a 16-bit Kobuki's restart can look like anything within +-80 rad of wheel angle);
  - the gap's step implausible by the one definition
    (:func:`~.wheels.plausibility.implausible` over the gap's interval).

  Otherwise the gap's step is the one reading of each wheel's difference within that
  range (for a wrapping counter, possibly more than half a wrap).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from diffdrive_odom.core.estimation.wheels.config import EstimatorConfig
from diffdrive_odom.core.estimation.wheels.encoders import (
    EncoderConfig,
    WheelIncrement,
    WheelReading,
    increment,
    joint_deltas,
    side_mean,
    unwrap_difference,
)
from diffdrive_odom.core.estimation.wheels.plausibility import implausible
from diffdrive_odom.core.geometry.kinematics import Geometry, wheel_arcs

__all__ = ["CountTrack", "JudgedSteps", "carried_on", "gap_motion", "judged_steps", "speeds"]

Array = npt.NDArray[np.float64]

QUANTA = 2.0  # ticks a gap's difference may be off: one at each end


@dataclass
class CountTrack:
    """What the counts did lately, beside the estimator's reference reading.

    ``changed_ns``: where the reference's counts were first seen (a step is judged over
    the time since); ``moved``: the last step that changed them (its speeds are what a
    gap's motion is judged against); ``start``: the timeline's first positions.
    """

    changed_ns: int = 0
    moved: WheelIncrement | None = None
    start: tuple[float, ...] | None = None

    def anchor(self, reading: WheelReading) -> None:
        """``reading`` starts a timeline: its counts are the start."""
        self.changed_ns, self.moved = reading.stamp_ns, None
        self.start = None if reading.from_velocity else reading.values

    def judged(self, ref: WheelReading, reading: WheelReading, inc: WheelIncrement,
               since_ns: int, config: EstimatorConfig) -> WheelIncrement:
        """``inc`` (``ref`` to ``reading``) over the time since the counts last changed.

        ``since_ns``: when ``ref``'s counts were first seen. The interval is capped at
        ``max_reading_gap``, and taken only where the wheels' speed before the hold
        explains the motion (:func:`carried_on`): a spike on a released reading is judged
        over its own step. Notes where ``reading``'s counts were first seen.
        """
        moved = reading.from_velocity or reading.values != ref.values
        self.changed_ns = reading.stamp_ns if moved else since_ns
        since = (reading.stamp_ns - since_ns) * 1e-9
        if reading.from_velocity or since <= inc.dt:
            return inc
        cap = config.max_reading_gap
        span = max(inc.dt, since if since < cap else cap)
        if moved and not carried_on(self.moved, inc, span, config):
            return inc
        return WheelIncrement(span, inc.d_left, inc.d_right, inc.peak)

    def stepped(self, reading: WheelReading, inc: WheelIncrement | None) -> None:
        """The step to ``reading`` was integrated as ``inc``, or skipped (None)."""
        if inc is None:
            self.changed_ns, self.moved = reading.stamp_ns, None
        elif self.changed_ns == reading.stamp_ns:
            self.moved = inc

    def before(self, ref: WheelReading, cap: float) -> tuple[float, float]:
        """The wheels' speeds [rad/s] just before ``ref``: the last step that moved them.

        Standing (0) if they then stood longer than ``cap`` [s].
        """
        recent = ref.stamp_ns - self.changed_ns <= cap * 1e9
        return speeds(self.moved if recent else None)


def carried_on(before: WheelIncrement | None, inc: WheelIncrement, span: float,
               config: EstimatorConfig) -> bool:
    """True when a released reading's motion ``inc`` fits the wheels carrying on.

    Over the ``span`` [s] since the counts last changed, at the speeds ``v`` of the last
    step that moved them (``before``; none: standing), known to within themselves (one
    step's counts are coarse: a driver's counters a period stale make it 0 or twice the
    speed) and one update of the counts, changed within ``max_wheel_acceleration``
    (``A span^2 / 2``), give or take one ordinary step at ``max_wheel_speed``
    (``inc.dt``): what a hold hid, not a glitch. A spike is far outside.
    """
    v = speeds(before)
    update = 0.0 if before is None else before.dt
    slack = 0.5 * config.max_wheel_acceleration * span * span + config.max_wheel_speed * inc.dt
    return (abs(inc.d_left - v[0] * span) <= slack + abs(v[0]) * (span + update)
            and abs(inc.d_right - v[1] * span) <= slack + abs(v[1]) * (span + update))


def speeds(inc: WheelIncrement | None) -> tuple[float, float]:
    """A step's mean joint speeds (left, right) [rad/s]; none: standing (0, 0)."""
    if inc is None or not inc.dt > 0.0:
        return 0.0, 0.0
    return inc.d_left / inc.dt, inc.d_right / inc.dt


@dataclass(frozen=True)
class JudgedSteps:
    """:func:`judged_steps`' arrays."""

    dt: Array  # (n,) each step's interval (since its reference's counts first seen)
    moved: npt.NDArray[np.bool_]  # (n,) the step changes the counts
    changed: npt.NDArray[np.int64]  # (n + 1,) where each row's counts were first seen
    before: npt.NDArray[np.int64]  # (n + 1,) the last step before each row that moved
    carried_on: npt.NDArray[np.bool_]  # (n,) a released step fits the wheels carrying on


def judged_steps(values: Array, stamps: npt.NDArray[np.int64],
                 first: tuple[int, WheelIncrement | None], step_dt: Array,
                 sides: tuple[Array, Array], cfg: EstimatorConfig, margin: float = 1.0
                 ) -> JudgedSteps:
    """:meth:`CountTrack.judged` of each row from the one before, in array form.

    The fast lane's form: every row taken as the reference in turn (as plain readings
    are); ``values`` (n + 1, wheels) positions, ``stamps`` (n + 1,) their stamps,
    ``first`` the counts' state at row 0 (``changed_ns``, ``moved``), ``step_dt`` and
    ``sides`` each step's stamps' interval and side increments. :func:`carried_on` within
    ``margin`` (just below 1: a borderline step goes the scalar way).
    """
    moved = (values[1:] != values[:-1]).any(axis=1)
    rows = np.arange(len(values))
    last = np.maximum.accumulate(np.where(np.concatenate(([True], moved)), rows, 0))
    changed = np.where(last == 0, first[0], stamps[last])
    since = (stamps[1:] - changed[:-1]) * 1e-9
    cap = cfg.max_reading_gap
    dt = np.where(since <= step_dt, step_dt, np.maximum(step_dt, np.minimum(since, cap)))
    steps = np.arange(len(moved))
    before = np.concatenate(([-1], np.maximum.accumulate(np.where(moved, steps, -1))))
    prev = before[:-1]
    speed0 = speeds(first[1])
    update = np.where(prev < 0, 0.0 if first[1] is None else first[1].dt, dt[prev])
    slack = 0.5 * cfg.max_wheel_acceleration * dt * dt + cfg.max_wheel_speed * step_dt
    fits = np.ones(len(moved), dtype=np.bool_)
    for side, d in enumerate(sides):
        v0 = np.where(prev < 0, speed0[side], d[prev] / dt[prev])
        fits &= np.abs(d - v0 * dt) <= (slack + np.abs(v0) * (dt + update)) * margin
    return JudgedSteps(dt, moved, changed, before, ~(moved & (since > step_dt)) | fits)


def gap_motion(
    encoders: EncoderConfig, config: EstimatorConfig, geometry: Geometry,
    before: WheelReading, after: WheelReading, following: WheelReading, counts: CountTrack,
) -> WheelIncrement | str:
    """The gap's step from ``before`` to ``after`` (the module's rules), or why it is a restart.

    ``following``: the reading that continued ``after`` (its step shows the wheels'
    speeds after the gap); ``counts``: the track as it stood at ``before``.
    """
    values = after.values
    if after.from_velocity or following.from_velocity or before.from_velocity:
        return "over a gap, velocities say nothing of the motion"
    step = increment(encoders, after, following)
    why = implausible(config, step, wheel_arcs(geometry, step.d_left, step.d_right))
    if why:
        return f"the step after it is implausible: {why}"
    unit = encoders.radians_per_unit
    tolerance = QUANTA * unit if encoders.ticks_per_revolution > 0 else 0.0
    if all(abs(unwrap_difference(v, encoders.counter_bits)) * unit <= 2.0 * abs(m) + tolerance
           for v, m in zip(values, joint_deltas(encoders, after.values, following.values),
                           strict=True)):
        return "the counters are back at zero (within two steps like the one after it)"
    if values == counts.start:
        return "the counters are back at their start values"
    speed_before = counts.before(before, config.max_reading_gap)
    speed_after = speeds(step)
    span_s = (after.stamp_ns - before.stamp_ns) * 1e-9
    names = encoders.left_wheel_names + encoders.right_wheel_names
    n = len(encoders.left_wheel_names)
    wrap = 2.0 ** encoders.counter_bits * unit if encoders.counter_bits > 0 else 0.0
    slack = config.max_wheel_acceleration * span_s / 4.0
    top = config.max_wheel_speed
    chosen: list[float] = []
    for k, delta in enumerate(joint_deltas(encoders, before.values, values)):
        v0, v1 = (speed_before[0], speed_after[0]) if k < n else (speed_before[1], speed_after[1])
        low = max(-top, min(v0, v1) - slack) * span_s - tolerance
        high = min(top, max(v0, v1) + slack) * span_s + tolerance
        readings = _readings(delta, wrap, low, high)
        if len(readings) != 1:
            return _why(names[k], delta, span_s, (v0, v1), readings, encoders.counter_bits,
                        config.max_wheel_acceleration)
        chosen.append(readings[0])
    left, right = side_mean(chosen[:n]), side_mean(chosen[n:])
    peak = max(map(abs, chosen)) if all(map(math.isfinite, chosen)) else math.nan
    inc = WheelIncrement(span_s, left, right, peak)
    why = implausible(config, inc, wheel_arcs(geometry, left, right))
    return f"the gap's step is implausible: {why}" if why else inc


def _readings(delta: float, wrap: float, low: float, high: float) -> list[float]:
    """The readings of ``delta`` (plus whole wraps of ``wrap``) within ``[low, high]``."""
    if not math.isfinite(delta) or not low <= high:
        return []
    if wrap <= 0.0:
        return [delta] if low <= delta <= high else []
    if not (math.isfinite(low) and math.isfinite(high)):
        return [math.nan] * 3  # no bound: every wrap fits
    first, last = math.ceil((low - delta) / wrap), math.floor((high - delta) / wrap)
    if last - first > 1:
        return [math.nan] * 3  # many: ambiguous whatever they are
    return [delta + k * wrap for k in range(first, last + 1)]


def _why(name: str, delta: float, span_s: float, around: tuple[float, float],
         readings: list[float], bits: int, acceleration: float) -> str:
    """Why a wheel's difference over the gap is not one motion."""
    if readings:
        return (f"{name}'s {bits}-bit counter makes the gap ambiguous: {len(readings)} or "
                f"more whole-wrap readings of its difference fit the wheel's speeds "
                f"({around[0]:.3g} and {around[1]:.3g} rad/s before and after) over "
                f"{span_s:.3f} s")
    return (f"{name}'s mean speed over the gap, {delta / span_s:.3g} rad/s, is beyond what "
            f"it showed before and after ({around[0]:.3g} and {around[1]:.3g} rad/s) with "
            f"max_wheel_acceleration {acceleration:g} rad/s^2")
