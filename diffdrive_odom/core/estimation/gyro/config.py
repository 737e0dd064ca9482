"""The gyro's settings (``use_imu`` true): its mounting, noise and the fusion's thresholds.

Apart from :mod:`~.gyro.gyrodometry`, the decision that reads them, as the wheels'
settings are apart from the estimator (:mod:`~.wheels.config`): the shell's
:class:`~diffdrive_odom.core.estimation.config.OdometrySettings` holds each concern's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from diffdrive_odom.core.errors import ConfigError, require_finite_min
from diffdrive_odom.core.estimation.stamps import StampSource

__all__ = ["GyroConfig", "GyroConfigError"]


class GyroConfigError(ConfigError):
    """A gyro setting that cannot work (names the parameter)."""


@dataclass(frozen=True)
class GyroConfig:
    """The gyro's mounting, noise and the fusion's thresholds (``use_imu`` true)."""

    # Roll, pitch, yaw [rad] of the IMU frame in the base frame (upside down: roll pi).
    orientation: tuple[float, float, float] = (0.0, 0.0, 0.0)
    noise_density: float = 3.0e-4  # rad/s/sqrt(Hz): white rate noise (angle random walk)
    bias: float = 0.0  # rad/s: the bias estimate's start value
    bias_stddev: float = 0.005  # rad/s: its 1-sigma uncertainty at the start
    bias_random_walk: float = 2.0e-5  # rad/s/sqrt(s): how fast the bias wanders
    max_rate: float = 34.9  # rad/s: |yaw rate| at or above this is saturated (2000 deg/s)
    timeout: float = 0.5  # s without samples: wheels only
    slip_sigmas: float = 5.0  # disagreement (in combined sigmas) that is a slip
    zero_velocity_speed: float = 0.001  # m/s: both wheels slower = standing still
    slip_distance_from_other_wheel: bool = True
    slip_min_angle: float = math.radians(0.5)  # rad: a smaller slip is no slip event
    stamp_source: StampSource = StampSource.HEADER  # imu_stamp_source
    time_offset: float = 0.0  # s the IMU's stamps are later than the wheels': taken out

    def __post_init__(self) -> None:
        if len(self.orientation) != 3 or not all(math.isfinite(a) for a in self.orientation):
            raise GyroConfigError("imu_orientation",
                                  f"needs 3 finite angles (roll, pitch, yaw), got "
                                  f"{list(self.orientation)!r}")
        if abs(self.yaw_axis[2]) < 0.5:
            raise GyroConfigError("imu_orientation",
                                  "puts the gyro's z axis over 60 deg from the base's z "
                                  "(its yaw rate would be mostly another axis)")
        for name, value, positive in (
            ("gyro_noise_density", self.noise_density, True),
            ("gyro_bias_stddev", self.bias_stddev, False),
            ("gyro_bias_random_walk", self.bias_random_walk, False),
            ("gyro_max_rate", self.max_rate, True),
            ("imu_timeout", self.timeout, True),
            ("slip_threshold_sigmas", self.slip_sigmas, True),
            ("zero_velocity_speed", self.zero_velocity_speed, False),
            ("slip_min_angle", self.slip_min_angle, False),
            ("imu_time_offset", abs(self.time_offset), False),
        ):
            require_finite_min(GyroConfigError, name, value, exclusive=positive)
        if not math.isfinite(self.bias):
            raise GyroConfigError("gyro_bias", f"must be finite, got {self.bias!r}")

    @property
    def yaw_axis(self) -> tuple[float, float, float]:
        """Row z of the mounting rotation ``Rz(yaw) Ry(pitch) Rx(roll)``: base wz from IMU w."""
        roll, pitch, _ = self.orientation
        return (-math.sin(pitch), math.cos(pitch) * math.sin(roll),
                math.cos(pitch) * math.cos(roll))
