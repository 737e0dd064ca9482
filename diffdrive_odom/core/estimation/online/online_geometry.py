"""The wheel geometry estimated while driving, from the gyro (``online_calibration``).

Over a stretch of wheel steps the gyro measures the turn the wheels claim:
``dtheta_gyro = (r_R/b) dphi_R - (r_L/b) dphi_L + bias dt + noise``, linear in the
two ratios ``u = r_R/b``, ``v = r_L/b`` and the gyro's bias (Censi, Franchi,
Marchionni and Oriolo, "Simultaneous calibration of odometry and sensor parameters
for mobile robots", IEEE T-RO 2013, first step, with a gyro in place of the scan
matcher). A small Kalman filter on ``(u, v, bias)`` with a random walk on each
estimates them recursively. The absolute scale (the mean radius, so ``b`` itself) is
not observable from rotation: it is held at the configured one, unless a reference pose
measures it (:mod:`~diffdrive_odom.core.estimation.online.online_scale`, which also divides the
ratios by the gyro's scale factor it measures).

Which steps count: only those the gyro judged for good (after the deferred judgement
of :mod:`~diffdrive_odom.core.estimation.gyro.gyrodometry`, so on any IMU timing) whose slip test
passed. A slipping step, one the IMU never covered, or one the wheels stood through
(no information on the ratios; it still measures the bias) is counted by reason.
Contiguous counted steps are summed into windows of ``WINDOW_S`` before an update: the
equation is additive, the gyro's white noise adds up over the window and the wheels'
quantization, a per-reading error, enters once per window end instead of once per
step (per-step differences of it are not independent). The noise of one window: the
gyro's noise density squared times its length, each wheel's quantization (two
readings) and the wheels' travel noise (``k |d|`` of the noise model) scaled by the
ratio squared (the gyro's noise density: the declared one or the one it shows standing
still, whichever is larger), and the turn rate's change over the window times
``TIMING_STDDEV`` and the IMU's lag behind the wheels the gyro measured (an IMU
stamping off the wheels gets the turn of a shifted interval: while the turn rate
changes, that is a systematic error the filter must not take for geometry;
``imu_time_offset`` takes a known lag out).

The estimate is "determined" once the robot turned ``min_turn`` rad each way (a run
turning one way only cannot tell the ratios from the bias and a gyro scale error).
Then the configured geometry is tested against it: a Mahalanobis distance over the
two (correlated) ratios beyond chi-square's 2-dof quantile at the 3-sigma level
(99.73 %) says the robot changed (a warning, once, then at most every
``WARN_INTERVAL_S`` while it stays outside). Pure Python, no numpy: a window update
is a 3x3 filter step, a few microseconds, at most a few per second.

``apply``: once determined and each ratio's relative 1-sigma is below ``apply_sigma``,
:attr:`OnlineGeometry.applied` is the geometry to integrate with (the estimate's
multipliers, the configured mean radius held), refreshed at every window update while
that holds and kept when it no longer does; the pipeline swaps it in between two
steps (:mod:`~diffdrive_odom.core.estimation.online.online_apply`), so the pose never jumps,
and the covariance takes its uncertainty (:mod:`~diffdrive_odom.core.estimation.online.ratios`).
The configured geometry stays the reference of the test above and the scale.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, replace
from types import MappingProxyType

from diffdrive_odom.core.errors import ConfigError, require_finite_min
from diffdrive_odom.core.estimation.online.kalman import kalman_update, quadratic
from diffdrive_odom.core.estimation.online.online_estimate import CHI2_2DOF_3SIGMA, OnlineEstimate
from diffdrive_odom.core.estimation.online.online_scale import OnlineScale, ReferenceConfig
from diffdrive_odom.core.estimation.online.ratios import (
    mean_radius_stddev_ratio,
    multipliers,
    ratio_geometry_covariance,
)
from diffdrive_odom.core.geometry.kinematics import Geometry
from diffdrive_odom.core.geometry.mat3 import Matrix
from diffdrive_odom.core.uncertainty.noise import NoiseModel

__all__ = ["OnlineConfig", "OnlineGeometry"]

WINDOW_S = 0.5  # s: contiguous counted steps summed into one update
NIS_AFTER = 20  # windows before their mean NIS scales the covariance
TRACE_MAX = 4096  # estimates kept over a run (halved, every other dropped, when full)
WARN_INTERVAL_S = 60.0  # s of stamp time between repeated warnings while outside
PRIOR_RATIO = 0.05  # relative 1-sigma of each ratio's start value (the configured one)
GATE_SIGMAS = 5.0  # a window whose innovation is beyond this many sigmas is refused
# s: how far the IMU's stamps may be off the wheels' (1 sigma). A window whose turn rate
# changed by dw between its ends is off by dw times the offset: its variance says so.
TIMING_STDDEV = 0.01
# Why a step did not count; the counter's keys and what they mean.
EXCLUDED = {
    "slip": "the slip test flagged it",
    "standstill": "the wheels stood still (it measures the bias only)",
    "no_gyro": "the IMU's samples never covered it",
    "outlier": f"its window disagreed with the estimate by over {GATE_SIGMAS:g} sigma",
}


class OnlineConfigError(ConfigError):
    """An online calibration setting that cannot work (names the parameter)."""


@dataclass(frozen=True)
class OnlineConfig:
    """``online_calibration: monitor`` or ``apply`` (None in the settings when disabled)."""

    min_turn: float = 3.0  # rad turned each way before the estimate is determined
    random_walk: float = 1.0e-5  # 1/sqrt(s): relative random walk of each ratio
    apply: bool = False  # integrate with the estimate once determined and precise enough
    apply_sigma: float = 0.002  # relative 1-sigma each ratio must be below to be applied
    reference: ReferenceConfig | None = None  # the scale's reference pose (online_scale)

    def __post_init__(self) -> None:
        require_finite_min(OnlineConfigError, "online_calibration_min_turn", self.min_turn)
        require_finite_min(OnlineConfigError, "online_calibration_random_walk", self.random_walk)
        require_finite_min(OnlineConfigError, "online_calibration_apply_sigma", self.apply_sigma,
                           exclusive=True)


class OnlineGeometry:
    """The filter on ``(r_R/b, r_L/b, bias)``, its windows, counters and warning."""

    def __init__(self, config: OnlineConfig, geometry: Geometry, noise_density: float,
                 bias: float, bias_stddev: float, bias_random_walk: float,
                 noise: NoiseModel, quantization: float = 0.0,
                 measured_density: Callable[[], float] = lambda: 0.0,
                 trace: bool = False, jitter: Callable[[], float] = lambda: 0.0,
                 lag: Callable[[], float] = lambda: 0.0) -> None:
        self.config = config
        # The wheel stamps' timing error [s] (the gyro's measure of it): a window's ends.
        self.jitter = jitter
        # The IMU's stamps later than the wheels' [s] (measured, imu_time_offset taken out):
        # a shift common to both ends, so a window is off by it times the rate's change.
        self.lag = lag
        # The gyro's noise seen standing still (0: not yet): the larger one is used, so a
        # gyro noisier than declared does not make the estimate overconfident.
        self.measured_density = measured_density
        self.geometry = geometry  # the configured one: the test's reference, the scale
        self.noise_density = noise_density
        self.bias_random_walk = bias_random_walk
        self.noise = noise
        self.quantization = quantization  # rad^2 per reading per side
        u0, v0 = _ratios(geometry)
        self.x = [u0, v0, bias]
        p = PRIOR_RATIO
        self.p = [[(p * u0) ** 2, 0.0, 0.0], [0.0, (p * v0) ** 2, 0.0],
                  [0.0, 0.0, bias_stddev ** 2]]
        self.excluded: Counter[str] = Counter()
        self.steps = 0
        self.windows = 0
        self.turned = [0.0, 0.0]
        self.distance = 0.0
        self._updated_ns: int | None = None
        self._nis = (0.0, 0)  # sum of the windows' normalized innovations squared, count
        self._warned_ns: int | None = None
        self._warning = ""
        # (stamp, estimate) after updates, thinned to at most TRACE_MAX: replay prints it
        # (kept only with ``trace``: an estimate is built for it at each update).
        self.keep_trace = trace
        self.trace: list[tuple[int, OnlineEstimate]] = []
        self._trace_every = 1
        # apply: the geometry the odometry integrates with (None: the configured one) and
        # its S over (ln r_l, ln r_r, ln b) (core.estimation.online.ratios).
        self.applied: Geometry | None = None
        self.applied_covariance: Matrix | None = None
        self.in_use: Geometry | None = None  # what online_apply.geometry_in_use handed out
        # Whether the applied geometry's scale is the reference's k (else the configured
        # mean radius), and as handed out: a change of source folds the covariance.
        self.applied_scaled = self.in_use_scaled = False
        self._applied_scale_sd = 0.0
        self._open()
        ref = config.reference  # the scale and the gyro's scale factor (online_scale)
        self.scale = None if ref is None else OnlineScale(
            ref, geometry, noise_density, noise, config.min_turn, config.random_walk,
            measured_density)

    def _open(self) -> None:
        self._w0: int | None = None
        self._w1: int | None = None
        self._sum = [0.0, 0.0, 0.0, 0.0, 0.0]  # phi_R, phi_L, gyro angle, var_R, var_L
        self._n = 0  # steps in it, standing ones not counted
        self._dist = 0.0
        self._rates = (0.0, 0.0)  # the turn rate of its first and of its last step

    def set_geometry(self, geometry: Geometry) -> None:
        """The configured geometry changed (a parameter at runtime): the reference and scale."""
        self.geometry = geometry
        if self.scale is not None:
            self.scale.geometry = geometry
        if self.applied is not None:
            self._apply(refresh=True)

    def set_config(self, config: OnlineConfig) -> None:
        """New settings at runtime; from apply to monitor the estimate is no longer used."""
        self.config = config
        if self.scale is not None:  # the reference's filter turns and wanders alike
            self.scale.min_turn, self.scale.random_walk = config.min_turn, config.random_walk
        if not config.apply:
            self.applied = self.applied_covariance = None

    def observe(self, geometry: Geometry, t0: int, t1: int, arcs: tuple[float, float],
                raw: float | None, slip: bool, standing: bool) -> None:
        """One step judged for good: its wheel arcs, the gyro's angle ``raw`` (None: none)."""
        if t1 <= t0:
            return
        r_r, r_l = geometry.right_radius, geometry.left_radius
        phi_r, phi_l = arcs[1] / r_r, arcs[0] / r_l
        if self.scale is not None:
            self.scale.observe(t0, t1, phi_r, phi_l, 0.5 * (arcs[0] + arcs[1]), raw, slip,
                               self.x)
        if raw is None or slip:
            self.excluded["no_gyro" if raw is None else "slip"] += 1
            self._flush()
            return
        if self._w1 is not None and t0 != self._w1:
            self._flush()
        rate = (self.x[0] * phi_r - self.x[1] * phi_l) / ((t1 - t0) * 1e-9)
        if self._w0 is None:
            self._w0 = t0
            self._rates = (rate, rate)
        self._w1 = t1
        self._rates = (self._rates[0], rate)
        s = self._sum
        s[0] += phi_r
        s[1] += phi_l
        s[2] += raw
        noise = self.noise
        s[3] += noise.k_right * abs(phi_r) / r_r
        s[4] += noise.k_left * abs(phi_l) / r_l
        self._dist += 0.5 * abs(arcs[0] + arcs[1])
        if standing:
            self.excluded["standstill"] += 1
        else:
            self._n += 1
        if (t1 - self._w0) * 1e-9 >= WINDOW_S:
            self._flush()

    def _flush(self) -> None:
        """One filter update on the open window, if any."""
        w0, w1, n = self._w0, self._w1, self._n
        phi_r, phi_l, angle, var_r, var_l = self._sum
        dist = self._dist
        r0, r1 = self._rates
        change = r1 - r0
        self._open()
        if w0 is None or w1 is None or w1 <= w0:
            return
        dt = (w1 - w0) * 1e-9
        x, p = self.x, self.p
        if self._updated_ns is not None and w1 > self._updated_ns:
            grow = (w1 - self._updated_ns) * 1e-9
            rw = self.config.random_walk
            p[0][0] += (rw * x[0]) ** 2 * grow
            p[1][1] += (rw * x[1]) ** 2 * grow
            p[2][2] += self.bias_random_walk ** 2 * grow
        self._updated_ns = w1
        h = [phi_r, -phi_l, dt]
        u2, v2 = x[0] * x[0], x[1] * x[1]
        q = self.quantization
        turn = x[0] * phi_r - x[1] * phi_l
        density = max(self.noise_density, self.measured_density())
        r = (density ** 2 * dt + 2.0 * q * (u2 + v2) + u2 * var_r + v2 * var_l
             + self.noise.k_rotation * abs(turn)
             + change * change * (TIMING_STDDEV ** 2 + self.lag() ** 2)
             + self.jitter() ** 2 * (r0 * r0 + r1 * r1))
        innovation = angle - (turn + x[2] * dt)
        if innovation * innovation > GATE_SIGMAS ** 2 * (quadratic(p, h) + r):
            self.excluded["outlier"] += n
            return
        self._nis = (self._nis[0] + innovation * innovation / (quadratic(p, h) + r),
                     self._nis[1] + 1)
        kalman_update(x, p, h, innovation, r)
        net = angle - x[2] * dt
        self.turned[0 if net > 0.0 else 1] += abs(net)
        self.steps += n
        self.windows += 1
        self.distance += dist
        if self.config.apply:
            self._apply(refresh=self.determined and self._precise())
        self._check(w1)

    @property
    def variance_factor(self) -> float:
        """The windows' mean normalized innovation squared, at least 1 (after NIS_AFTER).

        A window's noise is modelled, not known: on a real base (phil_train) the turn the
        wheels claim also depends on how the robot turns (on the spot or in an arc, 1.5
        to 5 % apart), and the mean NIS is 1.6-2.9, not 1. The covariance as printed,
        tested and applied is scaled by it (an a-posteriori variance factor), so runs
        agree within their sigmas; a filter whose model holds (NIS near 1) is unchanged.
        """
        total, n = self._nis
        return max(1.0, total / n) if n >= NIS_AFTER else 1.0

    def _corrected(self) -> tuple[tuple[float, float], tuple[float, float, float, float]]:
        """The ratios and their covariance as printed (over the gyro's scale factor, if any)."""
        p, f = self.p, self.variance_factor
        ratios, cov = ((self.x[0], self.x[1]),
                       (f * p[0][0], f * p[0][1], f * p[1][0], f * p[1][1]))
        return (ratios, cov) if self.scale is None else self.scale.correct(ratios, cov)

    def _precise(self) -> bool:
        """Each ratio's relative 1-sigma below ``apply_sigma``."""
        (u, v), cov = self._corrected()
        limit = self.config.apply_sigma
        return cov[0] < (limit * u) ** 2 and cov[3] < (limit * v) ** 2

    def _apply(self, refresh: bool) -> None:
        """The geometry to integrate with: refreshed at each update while precise enough.

        Once taken it is kept when the sigma grows above the threshold again (a long
        stretch turning one way: the random walk), not dropped for the worse configured
        one; its ``S`` follows the filter's covariance either way.
        """
        (u, v), cov = self._corrected()
        if refresh:
            # The scale: the reference's mean radius once it is determined (all three
            # scaled by k, its sigma the scale's), else the configured one with its sigma;
            # S keeps the sigma of the k the applied geometry was made with.
            k, scale_sd = 1.0, mean_radius_stddev_ratio(self.noise.radius_stddev_ratio)
            self.applied_scaled = self.scale is not None and self.scale.determined
            if self.scale is not None and self.applied_scaled:
                k, vk = self.scale.x[0], self.scale.p[0][0]
                scale_sd = math.sqrt(max(vk, 0.0)) / k
            self._applied_scale_sd = scale_sd
            (ml, mr, mb), _ = multipliers(self.geometry, (u, v), (0.0, 0.0, 0.0, 0.0))
            self.applied = replace(self.geometry, left_wheel_radius_multiplier=k * ml,
                                   right_wheel_radius_multiplier=k * mr,
                                   wheel_separation_multiplier=k * mb)
        if self.applied is not None:
            self.applied_covariance = ratio_geometry_covariance((u, v), cov,
                                                                self._applied_scale_sd)

    def _check(self, stamp_ns: int) -> None:
        """After an update: the trace, and the warning when it is due.

        The estimate with its printed fields is built only for those (updates come twice
        a second).
        """
        traced = self.keep_trace and self.windows % self._trace_every == 0
        last = self._warned_ns  # throttled whether or not it came back inside meanwhile
        due = (self.determined and (last is None or stamp_ns - last >= WARN_INTERVAL_S * 1e9)
               and _mahalanobis2(*self._corrected(), _ratios(self.geometry))
               > CHI2_2DOF_3SIGMA)
        if not (traced or due):
            return
        est = self.estimate()
        if traced:
            self.trace.append((stamp_ns, est))
            if len(self.trace) >= TRACE_MAX:
                self.trace = self.trace[::2]
                self._trace_every *= 2
        if due:
            self._warned_ns = stamp_ns
            self._warning = (
                "online calibration: the configured geometry is outside the estimate's "
                f"3-sigma region (Mahalanobis d^2 {est.mahalanobis2:.1f} > "
                f"{CHI2_2DOF_3SIGMA:.2f}): the robot changed, recalibrate; estimate: "
                + est.line())

    def take_warning(self) -> str:
        """The warning due (once, then throttled), '' if none; taking it clears it."""
        w, self._warning = self._warning, ""
        return w

    @property
    def determined(self) -> bool:
        """Turned ``min_turn`` each way over counted windows."""
        m = self.config.min_turn
        return self.turned[0] >= m and self.turned[1] >= m

    def estimate(self) -> OnlineEstimate:
        """The estimate now (see :class:`OnlineEstimate`)."""
        bias, p = self.x[2], self.p
        (u, v), cov = self._corrected()  # over the gyro's scale factor, with a reference
        d2 = _mahalanobis2((u, v), cov, _ratios(self.geometry))
        determined = self.determined
        mult, sig = multipliers(self.geometry, (u, v), cov)
        return OnlineEstimate(
            determined=determined, ratios=(u, v), covariance=cov, bias=bias,
            bias_stddev=math.sqrt(max(p[2][2], 0.0)), multipliers=mult, stddevs=sig,
            mahalanobis2=d2, outside=determined and d2 > CHI2_2DOF_3SIGMA,
            turned=(self.turned[0], self.turned[1]), distance=self.distance,
            steps=self.steps, windows=self.windows,
            excluded=MappingProxyType(dict(self.excluded)), applied=self.applied is not None,
            scale=None if self.scale is None else self.scale.estimate(mult, sig))


def _ratios(g: Geometry) -> tuple[float, float]:
    return g.right_radius / g.separation, g.left_radius / g.separation


def _mahalanobis2(ratios: tuple[float, float], cov: tuple[float, float, float, float],
                  configured: tuple[float, float]) -> float:
    """The configured ratios' squared Mahalanobis distance from the estimate (0: singular)."""
    du, dv = ratios[0] - configured[0], ratios[1] - configured[1]
    det = cov[0] * cov[3] - cov[1] * cov[2]
    return ((cov[3] * du * du - 2.0 * cov[1] * du * dv + cov[0] * dv * dv) / det
            if det > 0.0 else 0.0)
