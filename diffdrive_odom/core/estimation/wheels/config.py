"""The settings of the wheels' rules: what the estimator and plausibility read.

Besides geometry and encoders: the speed check, the twist's rolling window, the stamp
rules' thresholds, the acceleration bound a gap's motion is judged by. Apart from
:mod:`~.wheels.estimator` because :mod:`~.wheels.plausibility` and
:mod:`~.wheels.counts`, which the estimator imports, read them too.
"""

from __future__ import annotations

from dataclasses import dataclass

from diffdrive_odom.core.errors import ConfigError, require_finite_min

__all__ = ["EstimatorConfig", "EstimatorConfigError"]


class EstimatorConfigError(ConfigError):
    """An estimator setting that cannot work (names the parameter)."""


@dataclass(frozen=True)
class EstimatorConfig:
    """Everything the estimator needs besides geometry and encoders."""

    max_wheel_speed: float = 200.0  # rad/s of a joint; faster steps are implausible
    velocity_rolling_window_size: int = 1
    time_jump_threshold: float = 1.0  # s; a stamp further back than this restarts
    # s; a reading this long after the last usable one is held, then a new reference
    # or an outlier (inf = off). 1 s: a 5 Hz driver (0.2 s) keeps integrating, a
    # restart pause does not.
    max_reading_gap: float = 1.0
    # rad/s^2 of a joint: how far a wheel's mean speed over a gap may be from what it
    # showed before and after (:mod:`~.wheels.counts`); inf = any (gaps judged by speed).
    max_wheel_acceleration: float = 20.0

    def __post_init__(self) -> None:
        if not (self.max_wheel_speed > 0.0):
            raise EstimatorConfigError(
                "max_wheel_speed", f"must be > 0 (inf = no check), got {self.max_wheel_speed!r}"
            )
        w = self.velocity_rolling_window_size
        if not isinstance(w, int) or w < 1:
            raise EstimatorConfigError(
                "velocity_rolling_window_size", f"must be an integer >= 1, got {w!r}"
            )
        require_finite_min(EstimatorConfigError, "time_jump_threshold", self.time_jump_threshold)
        if not (self.max_wheel_acceleration > 0.0):
            raise EstimatorConfigError(
                "max_wheel_acceleration",
                f"must be > 0 (inf = no bound), got {self.max_wheel_acceleration!r}")
        if not (self.max_reading_gap > 0.0):
            raise EstimatorConfigError(
                "max_reading_gap", f"must be > 0 (inf = no check), got {self.max_reading_gap!r}"
            )
