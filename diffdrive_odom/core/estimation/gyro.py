"""Gyrodometry: wheels for distance, a gyro for turning, slip named when it happens.

After Borenstein and Feng, "Gyrodometry: A New Method for Combining Data from Gyros
and Odometry in Mobile Robots" (ICRA 1996): per wheel step, compare the heading
change the wheels report with the one the gyro reports. While they agree the wheels
are fine (here the two are fused, each weighted by the inverse of its variance);
where they disagree by more than ``slip_sigmas`` times their combined standard
deviation a wheel slipped, so the gyro's heading is used and a slip event counted.
Beyond the paper: when a wheel slipped, the distance comes from the other wheel and
the gyro (a spinning wheel reads more than it rolled, so the wheel with the shorter
arc is trusted), and the gyro's bias is estimated online whenever the wheels stand
still (a zero-velocity update: a scalar Kalman filter on the bias, whose variance
grows by the bias random walk between updates).

Time: the yaw rate is integrated over exactly each wheel step's interval by header
stamps, linear between samples, the rate held at the ends. A step whose end lies
past the newest sample (the IMU's next message still in flight) is extrapolated
with the newest rate; the next step subtracts what was extrapolated and integrates
the samples that arrived meanwhile, so the headings telescope and no extrapolation
error stays in the pose. A hole in the samples longer than ``imu_timeout`` makes the
step wheels-only (IMU silent): each step takes its heading change from one source or
the other, so switching never makes the pose jump.

Pure Python: the pipeline feeds samples (:meth:`GyroHeading.add`) and the estimator
asks for each step's heading (:meth:`GyroHeading.step`).
"""

from __future__ import annotations

import math
from bisect import bisect_left, bisect_right, insort
from dataclasses import dataclass
from itertools import pairwise

from diffdrive_odom.core.errors import ConfigError
from diffdrive_odom.core.geometry.kinematics import Geometry
from diffdrive_odom.core.uncertainty.noise import NoiseModel, joint_variances
from diffdrive_odom.core.uncertainty.propagation import GyroStep, wheel_jacobian

Matrix = tuple[tuple[float, ...], ...]

# Samples kept at most (wheels silent while the IMU goes on): 10 s at 1 kHz.
MAX_SAMPLES = 10_000


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
        ):
            if not (math.isfinite(value) and (value > 0.0 if positive else value >= 0.0)):
                raise GyroConfigError(name, f"must be finite and {'>' if positive else '>='} 0, "
                                            f"got {value!r}")
        if not math.isfinite(self.bias):
            raise GyroConfigError("gyro_bias", f"must be finite, got {self.bias!r}")

    @property
    def yaw_axis(self) -> tuple[float, float, float]:
        """Row z of the mounting rotation ``Rz(yaw) Ry(pitch) Rx(roll)``: base wz from IMU w."""
        roll, pitch, _ = self.orientation
        return (-math.sin(pitch), math.cos(pitch) * math.sin(roll),
                math.cos(pitch) * math.cos(roll))


@dataclass(frozen=True, slots=True)
class SlipStats:
    """Slip events so far: a run of consecutive slipping steps is one event.

    ``size``: the heading the wheels got wrong over the last event [rad];
    ``last_stamp_ns``: when it last slipped (None: never).
    """

    events: int = 0
    steps: int = 0
    last_stamp_ns: int | None = None
    last_size: float = 0.0
    total_size: float = 0.0


def _interp(ts: list[int], ws: list[float], t: int) -> float:
    """The rate at ``t``: linear between samples, held beyond the ends."""
    i = bisect_right(ts, t)
    if i == 0:
        return ws[0]
    if i == len(ts):
        return ws[-1]
    t0, t1 = ts[i - 1], ts[i]
    f = (t - t0) / (t1 - t0)
    return ws[i - 1] + f * (ws[i] - ws[i - 1])


def integrate(ts: list[int], ws: list[float], a: int, b: int) -> float:
    """``integral of w dt`` [rad] over ``[a, b]`` (stamps in ns), trapezoids on the samples."""
    if b <= a or not ts:
        return 0.0
    lo = bisect_right(ts, a)
    hi = bisect_left(ts, b)
    total = 0.0
    t_prev, w_prev = a, _interp(ts, ws, a)
    for i in range(lo, hi):
        t, w = ts[i], ws[i]
        total += 0.5 * (w + w_prev) * (t - t_prev)
        t_prev, w_prev = t, w
    total += 0.5 * (w_prev + _interp(ts, ws, b)) * (b - t_prev)
    return total * 1e-9


class GyroHeading:
    """The sample buffer, the bias estimate and the per-step gyrodometry decision."""

    def __init__(self, config: GyroConfig, noise: NoiseModel | None = None,
                 time_jump_threshold: float = 1.0, max_reading_gap: float = 1.0) -> None:
        self.config = config
        # The wheels' model the decision weighs them by (the default one when the
        # published covariance is static: the decision must not depend on that choice).
        self.noise = noise or NoiseModel()
        self._axis = config.yaw_axis
        self._jump_ns = time_jump_threshold * 1e9
        self._future_ns = max_reading_gap * 1e9  # inf: no check
        self._ts: list[int] = []
        self._ws: list[float] = []
        self.bias = config.bias
        self.bias_variance = config.bias_stddev ** 2
        self._bias_t: int | None = None  # stamp the bias variance was last grown to
        # The last step's end, how far real samples covered it, what was extrapolated.
        self._mark: int | None = None
        self._real = 0
        self._extra = 0.0
        self.wheel_stamp_ns: int | None = None  # newest wheel stamp (future check)
        self.slips = SlipStats()
        self._slipping = False
        self.silent = True  # no usable samples for the last step (or none yet)
        self.zero_velocity_updates = 0
        self.steps = 0  # wheel steps asked about
        self._geometry: Geometry | None = None
        self._b: Matrix = ()

    def set_config(self, config: GyroConfig) -> None:
        """New settings at runtime; the bias estimate carries on (its start value is for starts)."""
        self.config = config
        self._axis = config.yaw_axis

    # --- samples -------------------------------------------------------------------

    def add(self, stamp_ns: int, wx: float, wy: float, wz: float) -> str:
        """Offer one IMU sample (rates in the IMU frame); '' if kept, else the drop code."""
        ax, ay, az = self._axis
        w = ax * wx + ay * wy + az * wz
        if not math.isfinite(w):
            return "non_finite"
        if max(abs(wx), abs(wy), abs(wz)) >= self.config.max_rate:
            return "saturated"
        if stamp_ns <= 0:
            return "zero_stamp"
        ts = self._ts
        if ts and stamp_ns < ts[-1] - self._jump_ns:
            self._ts.clear()  # the IMU's clock went back (a bag loop): start over
            self._ws.clear()
            self._mark = None
        elif self._mark is not None and stamp_ns <= self._real:
            return "stale_stamp"  # that part of the timeline is integrated already
        wheel = self.wheel_stamp_ns
        if wheel is not None and stamp_ns - wheel > self._future_ns:
            return "future_stamp"
        if ts and stamp_ns == ts[-1]:
            return "stale_stamp"  # a duplicate
        if not ts or stamp_ns > ts[-1]:
            ts.append(stamp_ns)
            self._ws.append(w)
        else:
            i = bisect_left(ts, stamp_ns)
            if ts[i] == stamp_ns:
                return "stale_stamp"
            insort(ts, stamp_ns)
            self._ws.insert(i, w)
        if len(ts) > MAX_SAMPLES:
            del ts[0], self._ws[0]
        return ""

    def _prune(self, keep_from: int) -> None:
        """Drop samples no later step needs (keep the last one at or before ``keep_from``)."""
        i = bisect_right(self._ts, keep_from) - 1
        if i > 0:
            del self._ts[:i], self._ws[:i]

    def covers(self, a: int, b: int) -> bool:
        """True when samples reach within ``imu_timeout`` of both ends and no hole is longer."""
        ts = self._ts
        limit = self.config.timeout * 1e9
        pts = ts[bisect_left(ts, a - limit):bisect_right(ts, b + limit)]
        if not pts or pts[0] > a + limit or pts[-1] < b - limit:
            return False
        return all(q - p <= limit for p, q in pairwise(pts) if q > a and p < b)

    # --- one wheel step ------------------------------------------------------------

    def _angle(self, t0: int, t1: int) -> tuple[float, bool]:
        """Raw gyro angle over ``[t0, t1]`` (telescoping); True if all of it was measured."""
        ts, ws = self._ts, self._ws
        if self._mark != t0:
            self._mark, self._real, self._extra = t0, t0, 0.0
        start = min(self._real, t0)
        last = ts[-1]
        real_end = max(self._real, min(t1, last))
        measured = integrate(ts, ws, start, real_end)
        extra = integrate(ts, ws, real_end, t1) if t1 > real_end else 0.0
        angle = measured + extra - self._extra
        self._mark, self._real, self._extra = t1, real_end, extra
        self._prune(min(real_end, t1))
        return angle, t1 <= last

    def skip(self, t1: int) -> None:
        """The wheels took ``t1`` as a reference without a step: the next step starts there."""
        self._mark, self._real, self._extra = t1, t1, 0.0
        self.wheel_stamp_ns = t1
        self._prune(t1)

    def _grow_bias(self, t1: int) -> None:
        last = self._bias_t
        if last is not None and t1 > last:
            rw = self.config.bias_random_walk
            self.bias_variance += rw * rw * (t1 - last) * 1e-9
        self._bias_t = t1 if last is None or t1 > last else last

    def step(self, geometry: Geometry, t0: int, t1: int,
             d_left: float, d_right: float, arcs: tuple[float, float]) -> GyroStep | None:
        """Heading (and distance) of the step ``t0 -> t1``; None: wheels only (IMU silent)."""
        self.wheel_stamp_ns = t1
        self.steps += 1
        dt = (t1 - t0) * 1e-9
        if dt <= 0.0 or not self.covers(self._real if self._mark == t0 else t0, t1):
            self.silent = True
            self.skip(t1)
            self._slipping = False
            return None
        self.silent = False
        self._grow_bias(t1)
        raw, measured = self._angle(t0, t1)
        cfg = self.config
        s_l, s_r = arcs
        sep = geometry.separation
        ds_w, dth_w = 0.5 * (s_l + s_r), (s_r - s_l) / sep
        var_white = cfg.noise_density ** 2 * dt
        g = raw - self.bias * dt
        var_g = var_white + self.bias_variance * dt * dt
        if geometry is not self._geometry:
            self._geometry, self._b = geometry, wheel_jacobian(geometry)
        b = self._b
        noise = self.noise
        var_l, var_r = joint_variances(noise, geometry, d_left, d_right)
        rr, sr = noise.radius_stddev_ratio ** 2, noise.separation_stddev_ratio ** 2
        var_w = (b[1][0] ** 2 * var_l + b[1][1] ** 2 * var_r
                 + rr * (s_l * s_l + s_r * s_r) / (sep * sep) + sr * dth_w * dth_w)
        diff = g - dth_w
        slip = diff * diff > cfg.slip_sigmas ** 2 * (var_w + var_g)
        self._count_slip(slip, t1, abs(diff))
        if measured and not slip and max(abs(s_l), abs(s_r)) <= cfg.zero_velocity_speed * dt:
            # Standing still and the gyro agrees (a robot turned by hand is no bias).
            self._zero_velocity_update(raw / dt, dt)
        geo_ds = (0.5 * s_l, 0.5 * s_r, 0.0)
        geo_th = (-s_l / sep, s_r / sep, -dth_w)
        if not slip:
            w_g = var_w / (var_w + var_g) if var_w + var_g > 0.0 else 0.0
            w_w = 1.0 - w_g
            return GyroStep(ds=ds_w, dtheta=w_w * dth_w + w_g * g,
                            b=(b[0], (w_w * b[1][0], w_w * b[1][1])), c=(0.0, w_g),
                            var_gyro=var_white, dt=dt,
                            geometry=(geo_ds, tuple(w_w * v for v in geo_th)), slip=False)
        if not cfg.slip_distance_from_other_wheel:
            return GyroStep(ds=ds_w, dtheta=g, b=(b[0], (0.0, 0.0)), c=(0.0, 1.0),
                            var_gyro=var_white, dt=dt, geometry=(geo_ds, (0.0, 0.0, 0.0)),
                            slip=True)
        half = 0.5 * sep
        if abs(s_l) <= abs(s_r):  # the right wheel spun: the left one and the gyro
            return GyroStep(ds=s_l + half * g, dtheta=g, b=((2.0 * b[0][0], 0.0), (0.0, 0.0)),
                            c=(half, 1.0), var_gyro=var_white, dt=dt,
                            geometry=((s_l, 0.0, half * g), (0.0, 0.0, 0.0)), slip=True)
        return GyroStep(ds=s_r - half * g, dtheta=g, b=((0.0, 2.0 * b[0][1]), (0.0, 0.0)),
                        c=(-half, 1.0), var_gyro=var_white, dt=dt,
                        geometry=((0.0, s_r, -half * g), (0.0, 0.0, 0.0)), slip=True)

    def _zero_velocity_update(self, z: float, dt: float) -> None:
        """The wheels stand still: the mean rate ``z`` over ``dt`` measures the bias."""
        r = self.config.noise_density ** 2 / dt
        p = self.bias_variance
        k = p / (p + r) if p + r > 0.0 else 0.0
        self.bias += k * (z - self.bias)
        self.bias_variance = (1.0 - k) * p
        self.zero_velocity_updates += 1

    def _count_slip(self, slip: bool, stamp_ns: int, size: float) -> None:
        s = self.slips
        if not slip:
            self._slipping = False
            return
        new = not self._slipping
        self._slipping = True
        self.slips = SlipStats(
            events=s.events + (1 if new else 0),
            steps=s.steps + 1,
            last_stamp_ns=stamp_ns,
            last_size=size if new else s.last_size + size,
            total_size=s.total_size + size,
        )
