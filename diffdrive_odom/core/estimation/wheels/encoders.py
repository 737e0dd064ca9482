"""Encoder readings -> per-side wheel angle increments.

Turns the arrays of a JointState (names, position, velocity) into the
left/right joint angle change since the previous reading: joints found by name
(order and extra joints do not matter), raw counts converted to radians, fixed-width
counters unwrapped on the *difference* (so the first reading may be any value),
several wheels per side averaged, and velocity-only drivers integrated over the
stamp interval. The unwrap and the position increment have their array forms beside
them (:func:`unwrap_differences`, :func:`position_increments`), used by the fast lane,
so the two cannot differ.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from diffdrive_odom.core.compat import StrEnum
from diffdrive_odom.core.errors import ConfigError

TWO_PI = 2.0 * math.pi
Array = npt.NDArray[np.float64]


class Reason(StrEnum):
    """Stable short keys for what happened to a reading, beside the human text.

    Counters and diagnostics key on these, so wording can improve without breaking
    anything that counts. Defined at the lowest layer because decoding gives most of them.
    """

    UPDATED = "updated"  # integrated as motion
    FIRST = "first"  # first reading (or the first after a restart): the reference
    ZERO_STAMP = "zero_stamp"  # header stamp zero or negative: driver does not stamp
    MISSING_JOINT = "missing_joint"  # a configured wheel joint is not in the message
    BAD_ARRAY = "bad_array"  # position/velocity not one value per name (nor empty)
    NON_FINITE = "non_finite"  # a wheel value is NaN or infinite
    NO_DATA = "no_data"  # neither position nor velocity filled
    STALE_STAMP = "stale_stamp"  # same or slightly older stamp than the reference
    TOO_FAST = "too_fast"  # step over max_wheel_speed: skipped, re-anchored
    GAP = "gap"  # more than max_reading_gap since the last usable reading: re-anchored
    GAP_INTEGRATED = "gap_integrated"  # the same, the counts went on: the gap's motion integrated
    TIME_RESET = "time_reset"  # stamp far back: restarted at the origin
    OUT_OF_RANGE = "out_of_range"  # a count outside the configured counter's range
    HELD = "held"  # stamp over max_reading_gap ahead: held until the next reading decides
    FUTURE_STAMP = "future_stamp"  # reading(s) stamped far ahead: dropped as outliers
    CLOCK_JUMP = "clock_jump"  # stamps jumped ahead of the time elapsed: not published yet
    INPUT_SWITCH = "input_switch"  # switched between position and velocity input


class Rejection(str):
    """Why a reading cannot be used: the human text (the string itself) and a stable code."""

    code: Reason

    def __new__(cls, code: Reason, text: str) -> Rejection:
        """A str (so it reads and compares as the text) that also carries its code."""
        self = super().__new__(cls, text)
        self.code = code
        return self


class EncoderConfigError(ConfigError):
    """An encoder setting that cannot work (names the parameter)."""


@dataclass(frozen=True)
class EncoderConfig:
    """How the driver reports wheel positions.

    ``ticks_per_revolution`` > 0 means ``position`` holds raw counts (non-integer
    allowed: a 43.7:1 gear and a 64-count encoder give 2796.8). ``counter_bits`` > 0
    means the counter wraps at ``2**counter_bits`` (signed or unsigned, it makes no
    difference to a difference).
    """

    left_wheel_names: tuple[str, ...]
    right_wheel_names: tuple[str, ...]
    ticks_per_revolution: float = 0.0
    counter_bits: int = 0

    def __post_init__(self) -> None:
        for field in ("left_wheel_names", "right_wheel_names"):
            names = getattr(self, field)
            if len(names) == 0:
                raise EncoderConfigError(field, "must name at least one joint, got an empty "
                                         "list")
            if any((not isinstance(n, str)) or n == "" for n in names):
                raise EncoderConfigError(field, "joint names must be non-empty strings")
        if len(self.left_wheel_names) != len(self.right_wheel_names):
            raise EncoderConfigError(
                "right_wheel_names",
                f"has {len(self.right_wheel_names)} joints but left_wheel_names has "
                f"{len(self.left_wheel_names)}",
            )
        all_names = self.left_wheel_names + self.right_wheel_names
        if len(set(all_names)) != len(all_names):
            # Name the list that holds the repeat: within left, or within/into right.
            left_repeats = len(set(self.left_wheel_names)) != len(self.left_wheel_names)
            field = "left_wheel_names" if left_repeats else "right_wheel_names"
            raise EncoderConfigError(field, "a joint is listed twice")
        tpr = self.ticks_per_revolution
        if not math.isfinite(tpr) or tpr < 0.0:
            raise EncoderConfigError(
                "ticks_per_revolution", f"must be 0 (radians) or > 0, got {tpr!r}"
            )
        if not isinstance(self.counter_bits, int) or not 0 <= self.counter_bits <= 64:
            raise EncoderConfigError(
                "encoder_counter_bits", f"must be 0 (no wrap) to 64, got {self.counter_bits!r}"
            )
        if self.counter_bits > 0 and tpr == 0.0:
            raise EncoderConfigError(
                "encoder_counter_bits", "a wrapping counter needs ticks_per_revolution > 0"
            )

    @property
    def radians_per_unit(self) -> float:
        """Scale from the reported unit (rad or counts) to radians."""
        return TWO_PI / self.ticks_per_revolution if self.ticks_per_revolution > 0 else 1.0


def unwrap_difference(delta: float, counter_bits: int) -> float:
    """Shortest signed difference of a counter that wraps at ``2**counter_bits``.

    A non-finite difference is passed through (the caller rejects it) rather than
    raising in ``floor``.
    """
    if counter_bits <= 0 or not math.isfinite(delta):
        return delta
    span = float(2**counter_bits)
    return delta - span * math.floor(delta / span + 0.5)


def unwrap_differences(deltas: Array, counter_bits: int) -> Array:
    """:func:`unwrap_difference` of each element (the fast lane's form), non-finite ones alike."""
    if counter_bits <= 0:
        return deltas
    span = float(2**counter_bits)
    with np.errstate(invalid="ignore"):
        unwrapped = deltas - span * np.floor(deltas / span + 0.5)
    return np.where(np.isfinite(deltas), unwrapped, deltas)


def in_counter_range(value: float, counter_bits: int) -> bool:
    """True if ``value`` can be a count of a ``counter_bits`` counter, signed or unsigned.

    ``[-2**(bits-1), 2**bits)`` covers both; anything outside is not a reading of that
    counter (and a huge value would unwrap to a meaningless step), so it is dropped.
    """
    if counter_bits <= 0:
        return True
    low, high = counter_range(counter_bits)
    return low <= value < high


def counter_range(counter_bits: int) -> tuple[float, float]:
    """``[low, high)``: the counts of :func:`in_counter_range` (``counter_bits`` > 0)."""
    return -float(2 ** (counter_bits - 1)), float(2**counter_bits)


def side_mean(values: Sequence[float]) -> float:
    """Mean of one side's wheel increments; NaN when it cannot be a finite number.

    Huge finite increments overflow in the sum (``fsum`` raises) and opposite infinite
    ones have no sum at all: either way the step is unusable, and NaN says so without
    an exception escaping into the node.
    """
    try:
        mean = math.fsum(values) / len(values)
    except (OverflowError, ValueError):
        return math.nan
    return mean if math.isfinite(mean) else math.nan


@dataclass(frozen=True)
class WheelReading:
    """One decoded reading: per-joint raw values in the config's name order."""

    stamp_ns: int
    values: tuple[float, ...]
    from_velocity: bool
    # When it arrived, on the receiver's clock (None: not known); tells a pause from a
    # clock that jumped.
    receive_ns: int | None = None


@dataclass(frozen=True)
class WheelIncrement:
    """Mean joint angle change per side (rad, joint sign not yet applied) and its interval."""

    dt: float
    d_left: float
    d_right: float
    # Largest change of any one wheel (rad; NaN if one is not finite): two wheels of a
    # side that disagree wildly can still average to a plausible number.
    peak: float = 0.0


class JointLookup:
    """Maps a message's joint order to the configured wheels, cached per name list.

    Drivers send the same name list every time, so the index search runs once.
    """

    def __init__(self, config: EncoderConfig) -> None:
        self._left = config.left_wheel_names
        self._right = config.right_wheel_names
        self._wanted = config.left_wheel_names + config.right_wheel_names
        self._cache: dict[tuple[str, ...], tuple[int, ...] | None] = {}

    def indices(self, names: Sequence[str]) -> tuple[int, ...] | None:
        """Index of each configured wheel in ``names``; None if one is missing."""
        key = tuple(names)
        found = self._cache.get(key, ())
        if found == ():
            where = {name: i for i, name in enumerate(key)}
            found = (
                tuple(where[n] for n in self._wanted)
                if all(n in where for n in self._wanted)
                else None
            )
            if len(self._cache) < 64:
                self._cache[key] = found
        return found

    def missing(self, names: Sequence[str]) -> Rejection:
        """The reason for a name list that lacks a wheel: what was expected, what came.

        A wrong name is a configuration mistake, so the text gives both lists in full.
        """
        have = set(names)
        absent = [n for n in self._wanted if n not in have]
        return Rejection(
            Reason.MISSING_JOINT,
            f"joint_states lacks wheel joint(s) {absent}: expected left_wheel_names "
            f"{list(self._left)} and right_wheel_names {list(self._right)}, got names "
            f"{list(names)}",
        )


def decode(
    lookup: JointLookup,
    stamp_ns: int,
    names: Sequence[str],
    position: Sequence[float],
    velocity: Sequence[float],
    counter_bits: int = 0,
    receive_ns: int | None = None,
) -> WheelReading | Rejection:
    """Pick the wheels' values out of a JointState's arrays; a reason if unusable.

    Positions are preferred. Velocities are used when ``position`` is empty or holds
    NaN for every wheel (ros2_control's joint_state_broadcaster reports a missing
    position interface as NaN). With a wrapping counter (``counter_bits`` > 0) a
    position outside the counter's range is refused. An array that is neither empty
    nor one value per name is refused whole: a longer one is as malformed as a shorter
    one (which value belongs to which joint is unknown), so neither is integrated.
    """
    idx = lookup.indices(names)
    if idx is None:
        return lookup.missing(names)
    n = len(names)
    if len(position) not in (0, n):
        return Rejection(Reason.BAD_ARRAY, f"position has {len(position)} entries for {n} names")
    if len(velocity) not in (0, n):
        return Rejection(Reason.BAD_ARRAY, f"velocity has {len(velocity)} entries for {n} names")
    if len(position) > 0:
        values = tuple([float(position[i]) for i in idx])
        if all(map(math.isfinite, values)):
            if counter_bits > 0:
                low, high = counter_range(counter_bits)
                # Finite values: the extremes in range means every value is.
                if not (low <= min(values) and max(values) < high):
                    return Rejection(
                        Reason.OUT_OF_RANGE,
                        f"a wheel count is outside the range of a {counter_bits}-bit counter "
                        "(encoder_counter_bits)",
                    )
            return WheelReading(stamp_ns, values, False, receive_ns)
        if not (len(velocity) > 0 and all(map(math.isnan, values))):
            return Rejection(Reason.NON_FINITE, "a wheel position is NaN or infinite")
    if len(velocity) == 0:
        return Rejection(Reason.NO_DATA, "neither position nor velocity is filled")
    values = tuple([float(velocity[i]) for i in idx])
    if not all(map(math.isfinite, values)):
        return Rejection(Reason.NON_FINITE, "a wheel velocity is NaN or infinite")
    return WheelReading(stamp_ns, values, True, receive_ns)


def increment(
    config: EncoderConfig, previous: WheelReading, current: WheelReading
) -> WheelIncrement:
    """Per-side mean joint angle change (rad) between two decoded readings.

    Positions: difference, unwrapped, scaled. Velocities: trapezoidal rule over the
    stamp interval (exact for a constant acceleration between readings). A side whose
    mean is not a finite number comes back as NaN (see :func:`side_mean`).
    """
    dt = (current.stamp_ns - previous.stamp_ns) * 1e-9
    if current.from_velocity:
        scale = config.radians_per_unit
        deltas = [
            0.5 * (a + b) * dt * scale
            for a, b in zip(previous.values, current.values, strict=True)
        ]
    else:
        deltas = joint_deltas(config, previous.values, current.values)
    n = len(config.left_wheel_names)
    peak = max(map(abs, deltas)) if all(map(math.isfinite, deltas)) else math.nan
    return WheelIncrement(dt, side_mean(deltas[:n]), side_mean(deltas[n:]), peak)


def joint_deltas(config: EncoderConfig, previous: Sequence[float],
                 current: Sequence[float]) -> list[float]:
    """Each wheel's angle change [rad] from positions ``previous`` to ``current``.

    Raw differences, the counter's wrap taken out (the shortest one) and scaled; what
    :func:`increment` averages per side and the gap rule (:mod:`~.wheels.counts`) reads
    wheel by wheel.
    """
    scale = config.radians_per_unit
    bits = config.counter_bits
    if bits > 0:
        return [unwrap_difference(b - a, bits) * scale
                for a, b in zip(previous, current, strict=True)]
    return [(b - a) * scale for a, b in zip(previous, current, strict=True)]


def position_increments(config: EncoderConfig, values: Array) -> tuple[Array, Array, Array]:
    """:func:`increment` of positions for each row of ``values`` from the row before it.

    The fast lane's form: ``values`` (n + 1, wheels) raw positions in the config's name
    order; each step's ``d_left``, ``d_right`` and ``peak`` as in :class:`WheelIncrement`
    (a NaN or inf among a row's wheels comes out in all three, and the caller refuses the
    row). The sides are averaged by a plain sum, exactly ``fsum`` for up to two wheels a
    side (within a rounding beyond).
    """
    deltas = unwrap_differences(values[1:] - values[:-1], config.counter_bits)
    deltas = deltas * config.radians_per_unit
    n = len(config.left_wheel_names)
    return (deltas[:, :n].sum(axis=1) / n, deltas[:, n:].sum(axis=1) / n,
            np.abs(deltas).max(axis=1))
