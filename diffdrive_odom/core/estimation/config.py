"""The settings of one reading's path: the estimator's rules and the whole pipeline's.

Pure Python, defined in the core so the core imports nothing above it
(``settings.odometry`` builds them from ROS parameters). :class:`EstimatorConfig`: what
the estimator's rules (:mod:`~diffdrive_odom.core.estimation.estimator`) need besides
geometry and encoders; :class:`OdometrySettings`: everything the odometry node and
``replay`` are configured with, including whether bulk integration may be used
(:attr:`OdometrySettings.takes_bulk`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from diffdrive_odom.core.errors import ConfigError
from diffdrive_odom.core.estimation.encoders import EncoderConfig
from diffdrive_odom.core.estimation.gyro import GyroConfig
from diffdrive_odom.core.estimation.online_geometry import OnlineConfig
from diffdrive_odom.core.estimation.open_loop import OpenLoopConfig
from diffdrive_odom.core.estimation.stamps import StampSource
from diffdrive_odom.core.geometry.kinematics import Geometry
from diffdrive_odom.core.uncertainty.noise import NoiseModel

ONLINE_NEEDS_IMU = ("online_calibration is monitor or apply but use_imu is false: online "
                    "calibration disabled (it needs the gyro)")


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
        if not (math.isfinite(self.time_jump_threshold) and self.time_jump_threshold >= 0.0):
            raise EstimatorConfigError(
                "time_jump_threshold", f"must be finite and >= 0, got {self.time_jump_threshold!r}"
            )
        if not (self.max_reading_gap > 0.0):
            raise EstimatorConfigError(
                "max_reading_gap", f"must be > 0 (inf = no check), got {self.max_reading_gap!r}"
            )


@dataclass(frozen=True)
class OdometrySettings:
    """All validated settings of the odometry node / replay tool.

    Defined in the core so the core imports nothing above it; ``settings.odometry``
    builds it from ROS parameters.
    """

    geometry: Geometry
    encoders: EncoderConfig
    estimator: EstimatorConfig
    odom_frame_id: str
    base_frame_id: str
    enable_odom_tf: bool
    publish_rate: float
    pose_covariance_diagonal: tuple[float, ...]
    twist_covariance_diagonal: tuple[float, ...]
    noise: NoiseModel | None  # None: covariance_model static (the diagonals above)
    stamp_source: StampSource = StampSource.HEADER
    gyro: GyroConfig | None = None  # use_imu false: None (wheels only, as before)
    open_loop: OpenLoopConfig | None = None  # open_loop true: from commands, not encoders
    # online_calibration: monitor or apply (None: disabled; without use_imu: nothing).
    online: OnlineConfig | None = None

    @property
    def online_note(self) -> str:
        """Why online calibration does nothing though asked for ('' when it runs or is off)."""
        return ONLINE_NEEDS_IMU if self.online is not None and self.gyro is None else ""

    @property
    def takes_bulk(self) -> bool:
        """True when stretches of readings may be integrated in bulk (the one place it is said).

        With the gyro (``use_imu``) each step's heading is decided per reading from the
        IMU samples between its stamps, so every reading goes through the pipeline:
        :mod:`~diffdrive_odom.core.bulk.fastlane` marks none plain, and ``replay`` neither
        takes the fast lane nor reads runs of alike messages as blocks.
        """
        return self.gyro is None
