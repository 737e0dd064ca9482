"""What a wheel step may be: the one definition of an implausible step.

Apart from the estimator because two paths ask it: the estimator per reading
(:func:`implausible`, with the text the verdict carries) and the fast lane over arrays of
steps (:func:`plausible_steps`, within a margin so a borderline step goes the scalar way).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from diffdrive_odom.core.estimation.wheels.config import EstimatorConfig
from diffdrive_odom.core.estimation.wheels.encoders import EncoderConfig, WheelIncrement

__all__ = ["MAX_STEP_ARC", "counter_wrap", "implausible", "plausible_steps"]

# Widths of the counters drivers report (bits): a step that moved one of these spans of
# counts is the counter wrapping, not motion (:func:`counter_wrap`).
COUNTER_WIDTHS = (8, 10, 12, 14, 16, 20, 24, 32)
# m a wheel can roll between two readings, whatever the settings: more is no robot's
# motion (1 km is 36 km/h for 100 s), and it keeps the pose where a double still
# resolves the next millimetre even with ``max_wheel_speed: .inf``.
MAX_STEP_ARC = 1000.0
Array = npt.NDArray[np.float64]


def implausible(config: EstimatorConfig, inc: WheelIncrement, arcs: tuple[float, float]) -> str:
    """Why a step cannot be real wheel motion ('' if it can): the one definition.

    A joint faster than ``max_wheel_speed`` over the step's interval (which the gap
    rule bounds by ``max_reading_gap``, so a bogus stamp never licenses more travel),
    or, whatever the settings (``max_wheel_speed: .inf`` included), a wheel rolling
    more than ``MAX_STEP_ARC`` metres, or a value that is not a finite number.
    ``arcs`` are the step's :func:`kinematics.wheel_arcs`.
    """
    left, right, peak = abs(inc.d_left), abs(inc.d_right), abs(inc.peak)
    limit = config.max_wheel_speed * inc.dt
    if not (left <= limit and right <= limit and peak <= limit):  # NaN fails
        return (f"wheel moved {_largest((left, right, peak)):.4g} rad in {inc.dt:.4g} s, "
                f"over max_wheel_speed {config.max_wheel_speed:g} rad/s")
    s_left, s_right = abs(arcs[0]), abs(arcs[1])
    if not (s_left <= MAX_STEP_ARC and s_right <= MAX_STEP_ARC):
        return (f"a wheel rolled {_largest((s_left, s_right)):.4g} m in one step, "
                f"over {MAX_STEP_ARC:g} m")
    return ""


def counter_wrap(encoders: EncoderConfig, config: EstimatorConfig,
                 inc: WheelIncrement) -> tuple[int, float]:
    """The likely cause of an implausible step of counts: a counter wrapping unseen.

    Returns the counter's width in bits and its span [rad] when the step's largest
    movement is one such span (:data:`COUNTER_WIDTHS`, not the ``encoder_counter_bits``
    set) give or take what the wheel may really move in the step (``max_wheel_speed``
    over its interval), else ``(0, 0.0)``: a 16-bit counter read with
    ``encoder_counter_bits`` unset jumps by 65536 counts, 100.5 rad at 4096 a turn.
    """
    unit = encoders.radians_per_unit
    if encoders.ticks_per_revolution <= 0.0 or not math.isfinite(inc.peak):
        return 0, 0.0
    moved = abs(inc.peak)
    allowed = config.max_wheel_speed * inc.dt
    for bits in COUNTER_WIDTHS:
        span = 2.0**bits * unit
        if bits != encoders.counter_bits and abs(moved - span) <= allowed:
            return bits, span
    return 0, 0.0


def plausible_steps(
    config: EstimatorConfig, dt: Array, d_left: Array, d_right: Array, peak: Array,
    arcs: tuple[Array, Array], margin: float = 1.0,
) -> npt.NDArray[np.bool_]:
    """The array form of :func:`implausible` (True: plausible), every limit times ``margin``.

    The fast lane passes a ``margin`` just below 1, so a borderline step goes the
    scalar way and gets its verdict (and text) from :func:`implausible`.
    """
    limit = config.max_wheel_speed * dt * margin
    arc = MAX_STEP_ARC * margin
    return ((np.abs(d_left) <= limit) & (np.abs(d_right) <= limit) & (np.abs(peak) <= limit)
            & (np.abs(arcs[0]) <= arc) & (np.abs(arcs[1]) <= arc))


def _largest(values: Sequence[float]) -> float:
    """The largest of ``values``, NaN if any is (``max`` would depend on the order)."""
    return math.nan if any(math.isnan(v) for v in values) else max(values)
