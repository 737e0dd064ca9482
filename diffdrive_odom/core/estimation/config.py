"""The settings of one reading's path: the whole pipeline's, each concern's among them.

Pure Python, defined in the core so the core imports nothing above it
(``settings.odometry`` builds them from ROS parameters). :class:`OdometrySettings`:
everything the odometry node and ``replay`` are configured with (the wheels' rules:
:class:`~.wheels.config.EstimatorConfig`), including whether bulk integration may be
used (:attr:`OdometrySettings.takes_bulk`).
"""

from __future__ import annotations

from dataclasses import dataclass

from diffdrive_odom.core.estimation.gyro.config import GyroConfig
from diffdrive_odom.core.estimation.online.online_geometry import OnlineConfig
from diffdrive_odom.core.estimation.open_loop import OpenLoopConfig
from diffdrive_odom.core.estimation.stamps import StampSource
from diffdrive_odom.core.estimation.wheels.config import EstimatorConfig
from diffdrive_odom.core.estimation.wheels.encoders import EncoderConfig
from diffdrive_odom.core.geometry.kinematics import Geometry
from diffdrive_odom.core.uncertainty.noise import NoiseModel


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
    def takes_bulk(self) -> bool:
        """True when stretches of readings may be integrated in bulk (the one place it is said).

        With the gyro (``use_imu``) each step's heading is decided per reading from the
        IMU samples between its stamps, so every reading goes through the pipeline:
        :mod:`~diffdrive_odom.core.bulk.fastlane` marks none plain, and ``replay`` neither
        takes the fast lane nor reads runs of alike messages as blocks.
        """
        return self.gyro is None
