"""One IMU sample's path to the gyro: its stamp, the checks on its clock and its noise.

Why apart from :mod:`~diffdrive_odom.core.estimation.pipeline`: the IMU has rules of
its own, as the wheels have (``imu_stamp_source``: the header stamp or the receive
time; an IMU stamping on its own device clock named once with the offset and the
fix, as the wheels' clock is; the message's own ``angular_velocity_covariance``
(REP-145) compared with ``gyro_noise_density``), and the node, ``replay`` and the
demo must apply them alike. A one-off warning waits in :meth:`ImuInput.take_warning`
until the pipeline hands it out with the next reading's outcome.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from statistics import median
from types import MappingProxyType

from diffdrive_odom.core.estimation.gyro.gyrodometry import GyroHeading
from diffdrive_odom.core.estimation.stamps import (
    CLOCK_OFFSET_WARN_S,
    ClockOffsetCheck,
    StampSource,
)

# Samples whose stamps give the IMU's period before its covariance is judged.
COVARIANCE_AFTER = 50
# The noise density the message's covariance implies and gyro_noise_density may differ
# by this factor either way before it is said.
COVARIANCE_RATIO = 2.0


def implied_density(variance: float, period_s: float) -> float:
    """The noise density [rad/s/sqrt(Hz)] of samples of ``variance`` [(rad/s)^2].

    Samples every ``period_s``: white noise of density n averaged over a period T has
    variance n^2 / T.
    """
    return math.sqrt(variance * period_s)


class ImuInput:
    """The IMU's stamps, counters and one-off warnings in front of a :class:`GyroHeading`."""

    def __init__(self, gyro: GyroHeading) -> None:
        self.gyro = gyro
        self.samples = 0
        self._dropped: dict[str, int] = {}
        # Named from imu_timeout on where that is shorter than the wheels' limit: samples
        # further off than it cover no wheel step (the IMU would only seem silent).
        self._clock = ClockOffsetCheck("imu", min(CLOCK_OFFSET_WARN_S, gyro.config.timeout))
        self._warnings: list[str] = []
        self._stamps: list[int] = []  # the first samples' stamps (the period)
        self._covariance_judged = False
        self._lag_said = False  # the IMU's lag named once, when it matters

    @property
    def dropped(self) -> Mapping[str, int]:
        """Samples refused, by code."""
        return MappingProxyType(dict(self._dropped))

    def feed(self, stamp_ns: int, wx: float, wy: float, wz: float,
             receive_ns: int | None = None, check_clock: bool = True,
             covariance: tuple[float, ...] = ()) -> str:
        """One sample; '' when kept, else the drop code.

        ``receive_ns``: when it arrived on the receiver's clock (None: unknown);
        ``covariance``: the message's angular_velocity_covariance (9 values, row-major).
        """
        self.samples += 1
        if receive_ns is not None and receive_ns > 0:
            if self.gyro.config.stamp_source is StampSource.RECEIVE_TIME:
                stamp_ns = receive_ns
            elif check_clock and stamp_ns > 0:
                said = self._clock.check(stamp_ns, receive_ns)
                if said:
                    self._warnings.append(said)
        if stamp_ns > 0:  # the lag the user measured between the two clocks, taken out
            stamp_ns -= round(self.gyro.config.time_offset * 1e9)
        code = self.gyro.add(stamp_ns, wx, wy, wz, receive_ns)
        if code:
            self._dropped[code] = self._dropped.get(code, 0) + 1
        elif not self._covariance_judged:
            self._judge_covariance(stamp_ns, covariance)
        return code

    def _judge_covariance(self, stamp_ns: int, covariance: tuple[float, ...]) -> None:
        """Compare the message's yaw-rate variance with gyro_noise_density, once."""
        if len(covariance) != 9 or not covariance[0] >= 0.0 or not any(covariance):
            self._covariance_judged = True  # REP-145: -1 not provided, zeros unknown
            return
        a = self.gyro.config.yaw_axis
        var = sum(a[i] * covariance[3 * i + j] * a[j] for i in range(3) for j in range(3))
        self._stamps.append(stamp_ns)
        if len(self._stamps) < COVARIANCE_AFTER:
            return
        self._covariance_judged = True
        steps = [q - p for p, q in zip(self._stamps, self._stamps[1:], strict=False) if q > p]
        if not steps or not (var > 0.0 and math.isfinite(var)):
            return
        period = median(steps) * 1e-9
        implied = implied_density(var, period)
        declared = self.gyro.config.noise_density
        if 1.0 / COVARIANCE_RATIO <= implied / declared <= COVARIANCE_RATIO:
            return
        self._warnings.append(
            f"the Imu messages' angular_velocity_covariance ({var:.3g} (rad/s)^2 about the "
            f"yaw axis, every {period * 1e3:.3g} ms) means a noise density of "
            f"{implied:.3g} rad/s/sqrt(Hz), gyro_noise_density is {declared:.3g}: the slip "
            "test and the heading's weights use gyro_noise_density; set it to the "
            "datasheet's rate noise density (or the covariance right)")

    def take_warning(self) -> str:
        """A one-off warning not yet said ('' if none).

        The IMU's clock, its covariance, its noise seen standing still, or no
        zero-velocity update though the robot stood.
        """
        if self._warnings:
            return self._warnings.pop(0)
        still = self.gyro.standstill
        if still.noise_warning:
            said, still.noise_warning = still.noise_warning, ""
            return said
        lag = self.gyro.lag.estimate
        if lag is not None and not self._lag_said and lag.matters(self.gyro.jitter.sigma):
            self._lag_said = True
            return lag.line(self.gyro.jitter.sigma)
        return still.warning()
