"""Gyrodometry: wheels for distance, a gyro for turning, slip named when it happens.

After Borenstein and Feng, "Gyrodometry: A New Method for Combining Data from Gyros
and Odometry in Mobile Robots" (ICRA 1996): per wheel step, compare the heading change
the wheels report with the gyro's. While they agree the two are fused, each weighted by
the inverse of its variance; where they disagree beyond ``slip_sigmas`` combined sigmas
a wheel slipped: the gyro's heading is used and a slip counted
(:mod:`~diffdrive_odom.core.estimation.gyro.slips`; the distance:
:mod:`~diffdrive_odom.core.estimation.gyro.slipstep`). The wheels' turn and its variance are
a real robot's (:mod:`~diffdrive_odom.core.estimation.gyro.wheelturn`): with the online
configured ratios and the noise model's sigmas, the encoders' and the gyro's
quantization, and the stamps' timing error measured while turning.
Readings a driver holds (no motion within ``HOLD_S`` of the last that moved, or later
while the gyro turns faster than standing wheels could, within ``max_reading_gap``: a
logger's hold) take the gyro's turn for now and the next step is judged over the
interval since the last reading that moved, as the wheels judge it
(:mod:`~.wheels.counts`). The bias is estimated whenever the wheels stand still for longer
(:mod:`~diffdrive_odom.core.estimation.gyro.standstill`).

Time: the yaw rate is integrated over exactly each step's interval by header stamps
(:mod:`~diffdrive_odom.core.estimation.gyro.gyrosamples`). An IMU on its own clock gives no
order, so each step is decided at once on the samples that came (the part past the
newest filled with the wheels' turn), kept pending, and judged again when the samples
covering it have come; what the final judgement changes is added to the next step, so
the provisional part leaves no error in the pose. A step the samples never cover is
given up ``imu_timeout`` after its end; a hole longer than ``imu_timeout`` makes the step
wheels-only (IMU silent): each step takes its heading from one source or the other, so
switching never makes the pose jump. Pure Python: the pipeline feeds samples
(:meth:`GyroHeading.add`) and the estimator asks for each step's heading
(:meth:`GyroHeading.step`).
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, replace

from diffdrive_odom.core.estimation.gyro.config import GyroConfig
from diffdrive_odom.core.estimation.gyro.gyrosamples import GyroSamples
from diffdrive_odom.core.estimation.gyro.imulag import ImuLag
from diffdrive_odom.core.estimation.gyro.slips import SlipEvents, SlipStats
from diffdrive_odom.core.estimation.gyro.slipstep import SPIN_SIGMAS, slip_step
from diffdrive_odom.core.estimation.gyro.standstill import Standstill
from diffdrive_odom.core.estimation.gyro.wheelturn import (
    HOLD_S,
    RatioModel,
    StampJitter,
    turn_variance,
)
from diffdrive_odom.core.geometry.kinematics import Geometry
from diffdrive_odom.core.geometry.mat3 import Matrix
from diffdrive_odom.core.uncertainty.noise import NoiseModel, joint_variances
from diffdrive_odom.core.uncertainty.propagation import GyroStep, wheel_jacobian

# A step judged for good: (geometry, t0, t1, arcs, gyro angle or None, slip, standing).
Observer = Callable[[Geometry, int, int, tuple[float, float], "float | None", bool, bool],
                    None]
__all__ = ["GyroHeading"]


@dataclass(frozen=True, slots=True)
class _Judged:
    """One step's decision: slipped or not, the wheels' heading error, the step."""

    slip: bool
    error: float  # rad: the wheels' heading change minus the gyro's
    step: GyroStep
    excess: float = 0.0  # m: what the spinning wheel read beyond what it rolled


@dataclass(frozen=True, slots=True)
class _Interval:
    """What a step was decided on, so it can be judged again once its samples came."""

    geometry: Geometry
    t0: int
    t1: int
    d_left: float
    d_right: float
    arcs: tuple[float, float]
    bias: float
    bias_variance: float
    standing: bool
    decided: _Judged


class GyroHeading:
    """The sample buffer, the bias estimate and the per-step gyrodometry decision."""

    def __init__(self, config: GyroConfig, noise: NoiseModel | None = None,
                 time_jump_threshold: float = 1.0, max_reading_gap: float = 1.0,
                 quantization: float = 0.0) -> None:
        self.config = config
        self.quantization = quantization  # rad^2: a joint's variance per reading (ticks)
        self.jitter = StampJitter()  # the wheel stamps' timing error, measured turning
        self.lag = ImuLag(config.time_offset)  # how much later the IMU's stamps are
        self._moved_ns: int | None = None  # the last wheel stamp that moved
        self._held_from: int | None = None  # start of the readings held since then
        self._held_turn = 0.0  # the gyro's turn handed out over them (provisional)
        self._spun = 0.0  # m: the excess a run of flagged steps read so far (slipstep)
        # The wheels' model the decision weighs them by (the default one when the
        # published covariance is static: the decision must not depend on that choice).
        self.noise = noise or NoiseModel()
        self._axis = config.yaw_axis
        self._jump_ns = time_jump_threshold * 1e9
        self._future_ns = max_reading_gap * 1e9  # inf: no check
        self.samples = GyroSamples()
        self.standstill = Standstill(config.bias, config.bias_stddev)
        self._slips = SlipEvents(config.slip_min_angle)
        # Steps decided before the samples covering them came, oldest first.
        self._pending: deque[_Interval] = deque()
        self._judged_to: int | None = None  # end of the last step judged for good
        self._debt = (0.0, 0.0)  # (ds, dtheta) the final judgements add to the next step
        self.wheel_stamp_ns: int | None = None  # newest wheel stamp (future check)
        self.wheel_receive_ns: int | None = None  # when its reading came (None: unknown)
        self.silent = True  # no usable samples for the last step (or none yet)
        self.steps = 0  # wheel steps asked about
        self._per_geometry: tuple[Geometry, NoiseModel, Matrix, RatioModel] | None = None
        # Told of each step judged for good (online calibration), None: nobody listens.
        self.observer: Observer | None = None

    def set_config(self, config: GyroConfig) -> None:
        """New settings at runtime; the bias estimate carries on (its start value is for starts)."""
        if config.time_offset != self.config.time_offset:
            self.lag.clear(config.time_offset)
        self.config = config
        self._axis = config.yaw_axis
        self._slips.min_angle = config.slip_min_angle

    @property
    def bias(self) -> float:
        """The bias estimate [rad/s]."""
        return self.standstill.bias

    @bias.setter
    def bias(self, value: float) -> None:
        self.standstill.bias = value

    @property
    def bias_variance(self) -> float:
        """Its variance [(rad/s)^2]."""
        return self.standstill.variance

    @property
    def zero_velocity_updates(self) -> int:
        """Bias updates so far (steps standing still, their samples in)."""
        return self.standstill.updates

    @property
    def slips(self) -> SlipStats:
        """Slip events so far (:mod:`~diffdrive_odom.core.estimation.gyro.slips`)."""
        return self._slips.stats

    @property
    def slip_events(self) -> list[tuple[int, float]]:
        """Each slip event's (stamp of its first step, size [rad]), oldest first."""
        return self._slips.events

    @property
    def slip_spans(self) -> list[tuple[int, int]]:
        """Each slip event's (stamp of its first step, of its last step), oldest first."""
        return self._slips.spans

    # --- samples -------------------------------------------------------------------

    def add(self, stamp_ns: int, wx: float, wy: float, wz: float,
            receive_ns: int | None = None) -> str:
        """Offer one IMU sample (rates in the IMU frame); '' if kept, else the drop code.

        ``receive_ns``: when it came (None: unknown). A sample further than
        ``max_reading_gap`` ahead of the newest wheel stamp is refused (``future_stamp``),
        that stamp moved on by the time the receiver saw pass since its reading came: the
        IMU goes on through a gap in the wheels' readings, a clock that jumped does not.
        """
        ax, ay, az = self._axis
        w = float(ax * wx + ay * wy + az * wz)  # a Python float whatever the caller gave
        if not math.isfinite(w):
            return "non_finite"
        if max(abs(wx), abs(wy), abs(wz)) >= self.config.max_rate:
            return "saturated"
        if stamp_ns <= 0:
            return "zero_stamp"
        last = self.samples.last
        if last is not None and stamp_ns < last - self._jump_ns:
            self._start_over()  # the IMU's clock went back (a bag loop)
        elif self._judged_to is not None and stamp_ns <= self._judged_to:
            return "stale_stamp"  # that part of the timeline is judged already
        wheel = self.wheel_stamp_ns
        since = self.wheel_receive_ns
        elapsed = 0 if receive_ns is None or since is None else max(0, receive_ns - since)
        if wheel is not None and stamp_ns - wheel - elapsed > self._future_ns:
            return "future_stamp"
        if not self.samples.insert(stamp_ns, w):
            return "stale_stamp"  # a duplicate
        self.lag.gyro(stamp_ns, w)
        if self._pending and stamp_ns >= self._pending[0].t1:
            self._settle(wheel if wheel is not None else stamp_ns)
        return ""

    def _start_over(self) -> None:
        self._moved_ns = self._held_from = None
        self._held_turn = 0.0
        self.samples.clear()
        self.lag.clear()
        self._pending.clear()
        self._judged_to = None
        self._debt = (0.0, 0.0)

    def covers(self, a: int, b: int) -> bool:
        """True when samples reach within ``imu_timeout`` of both ends and no hole is longer."""
        return self.samples.covers(a, b, self.config.timeout * 1e9)

    def skip(self, t1: int) -> None:
        """The wheels took ``t1`` as a reference without a step: the next step starts there.

        Samples up to ``t1`` that come later are still taken: nothing was judged on them,
        and an IMU lagging more than a wheel period must not have every sample refused.
        """
        self.wheel_stamp_ns = t1
        self._prune(t1)

    def _prune(self, t1: int) -> None:
        keep = self._pending[0].t0 if self._pending else t1
        self.samples.prune(keep if self._held_from is None else min(keep, self._held_from))

    # --- one wheel step ------------------------------------------------------------

    def step(self, geometry: Geometry, t0: int, t1: int,
             d_left: float, d_right: float, arcs: tuple[float, float]) -> GyroStep | None:
        """Heading (and distance) of the step ``t0 -> t1``; None: wheels only (IMU silent).

        A held reading (see the module) takes the gyro's turn; the next step is judged
        since the last that moved, less what the held steps handed out.
        """
        self.wheel_stamp_ns = t1
        self.steps += 1
        cfg = self.config
        dt_ns = t1 - t0
        still = dt_ns > 0 and (max(abs(arcs[0]), abs(arcs[1]))
                               <= cfg.zero_velocity_speed * dt_ns * 1e-9)
        moved = self._moved_ns
        held = still and moved is not None and t1 - moved < HOLD_S * 1e9
        if dt_ns > 0 and not still:
            self._moved_ns = t1
        self._settle(t1)
        if dt_ns <= 0 or not self.covers(t0, t1):
            self._held_from, self._held_turn = None, 0.0
            self._silent(geometry, t0, t1, arcs, still and not held, dt_ns)
            return None
        self.silent = False
        gyro = self.standstill
        gyro.grow(t1, cfg.bias_random_walk)
        turn = 0.0
        if held or (still and moved is not None and t1 - moved < self._future_ns):
            turn = self._provisional(geometry, t0, t1, arcs) - gyro.bias * dt_ns * 1e-9
            # Past a driver's repeats, within the wheels' own interval (max_reading_gap):
            # still held while the gyro turns faster than standing wheels could (a
            # logger's hold, not a standstill).
            held = held or (abs(turn) * 0.5 * geometry.separation
                            > cfg.zero_velocity_speed * dt_ns * 1e-9)
        if held:
            if self._held_from is None:
                self._held_from = t0
            self._held_turn += turn
            self._prune(t1)
            return GyroStep(ds=0.0, dtheta=turn, b=((0.0, 0.0), (0.0, 0.0)), c=(0.0, 1.0),
                            var_gyro=cfg.noise_density ** 2 * dt_ns * 1e-9, dt=dt_ns * 1e-9,
                            geometry=((0.0, 0.0, 0.0), (0.0, 0.0, 0.0)), slip=False)
        standing = still and self._held_from is None
        handed_out = self._held_turn
        if self._held_from is not None:  # the interval since the last reading that moved
            t0, self._held_from, self._held_turn = self._held_from, None, 0.0
            dt_ns = t1 - t0
        if standing:
            gyro.stood(dt_ns)
        raw = self._provisional(geometry, t0, t1, arcs)
        decided = self._judge(geometry, dt_ns * 1e-9, d_left, d_right, arcs, raw,
                              gyro.bias, gyro.variance, t0, t1, standing)
        interval = _Interval(geometry, t0, t1, d_left, d_right, arcs, gyro.bias,
                             gyro.variance, standing, decided)
        last = self.samples.last
        if not self._pending and last is not None and last >= t1:
            self._judged(interval, decided, raw)  # its samples are all in: final now
        else:
            self._pending.append(interval)
        out = decided.step
        ds, dtheta = self._debt
        if ds or dtheta or handed_out:
            out = replace(out, ds=out.ds + ds, dtheta=out.dtheta + dtheta - handed_out,
                          merged=handed_out)
            self._debt = (0.0, 0.0)
        self._prune(t1)
        return out

    def _silent(self, geometry: Geometry, t0: int, t1: int, arcs: tuple[float, float],
                standing: bool, dt_ns: int) -> None:
        """No samples cover the step: wheels only, the pending steps given up."""
        self.silent = True
        if standing:
            self.standstill.stood(dt_ns)
            self.standstill.miss("silent")
        self._give_up()  # the pending steps first: the observers see steps in time order
        if self.observer is not None:
            self.observer(geometry, t0, t1, arcs, None, False, standing)
        self.skip(t1)

    def _provisional(self, geometry: Geometry, t0: int, t1: int,
                     arcs: tuple[float, float]) -> float:
        """The gyro angle over ``[t0, t1]`` as far as samples came; the wheels' beyond.

        The part past the newest sample is filled with the wheels' turn over it (plus
        the bias the gyro would add): the step is judged on what the gyro saw, and a
        late IMU does not hold an old rate for long. The final judgement replaces it.
        """
        last = self.samples.last
        if last is None or last >= t1:
            return self.samples.integrate(t0, t1)
        cut = max(last, t0)
        rate = (arcs[1] - arcs[0]) / geometry.separation / ((t1 - t0) * 1e-9) + self.bias
        return self.samples.integrate(t0, cut) + rate * (t1 - cut) * 1e-9

    def _settle(self, now: int) -> None:
        """Judge for good the pending steps the samples now cover; give up stale ones."""
        pending = self._pending
        last = self.samples.last
        limit = self.config.timeout * 1e9
        while pending:
            p = pending[0]
            if last is not None and last >= p.t1:
                raw = self.samples.integrate(p.t0, p.t1)
                final = self._judge(p.geometry, (p.t1 - p.t0) * 1e-9, p.d_left, p.d_right,
                                    p.arcs, raw, p.bias, p.bias_variance, p.t0, p.t1,
                                    p.standing)
                ds, dtheta = self._debt
                self._debt = (ds + final.step.ds - p.decided.step.ds,
                              dtheta + final.step.dtheta - p.decided.step.dtheta)
                self._judged(p, final, raw)
            elif now - p.t1 > limit:
                self._judged(p, p.decided, None)
            else:
                break
            pending.popleft()

    def _give_up(self) -> None:
        """The IMU fell silent: the pending steps stay as decided, nothing more is owed."""
        while self._pending:
            p = self._pending.popleft()
            self._judged(p, p.decided, None)
        self._debt = (0.0, 0.0)

    def _timing(self) -> float:
        """How far [s] the two streams' stamps may be apart: the jitter at both ends, the lag."""
        return math.hypot(math.sqrt(2.0) * self.jitter.sigma, self.lag.seconds)

    def _judged(self, p: _Interval, judged: _Judged, raw: float | None) -> None:
        """A step judged for good: its slip counted, a standstill's bias update."""
        self._slips.step(judged.slip, p.t1, judged.error)
        self._spun = self._spun + judged.excess if judged.slip else 0.0
        self.lag.wheels(p.t0, p.t1, (p.arcs[1] - p.arcs[0]) / p.geometry.separation)
        if raw is not None and not p.standing and not judged.slip and p.arcs != (0.0, 0.0):
            dt = (p.t1 - p.t0) * 1e-9
            self.jitter.offer(-judged.error, (raw - p.bias * dt) / dt)
        self._judged_to = p.t1
        if self.observer is not None:
            self.observer(p.geometry, p.t0, p.t1, p.arcs, raw, judged.slip, p.standing)
        if not p.standing:
            return
        if raw is None:
            self.standstill.miss("unmeasured")
        else:  # unless the gyro turned while the wheels stood (by hand): no bias
            dt = (p.t1 - p.t0) * 1e-9
            self.standstill.offer(raw / dt, dt, self.config.noise_density,
                                  self.config.slip_sigmas)

    def _judge(self, geometry: Geometry, dt: float, d_left: float, d_right: float,
               arcs: tuple[float, float], raw: float, bias: float,
               bias_variance: float, t0: int, t1: int, standing: bool) -> _Judged:
        """The step's decision on the gyro angle ``raw`` [rad] (no state changes).

        The wheels' turn and its variance as a real robot's
        (:mod:`~diffdrive_odom.core.estimation.gyro.wheelturn`): a slip is what remains beyond
        the geometry's uncertainty, the encoders' and the gyro's quantization and the
        stamps' jitter (which moves nothing while the wheels stand).
        """
        cfg = self.config
        s_l, s_r = arcs
        phi_r, phi_l = s_r / geometry.right_radius, s_l / geometry.left_radius
        cached = self._per_geometry  # the Jacobian and ratios: per geometry, not per step
        if cached is None or cached[0] is not geometry or cached[1] is not self.noise:
            cached = self._per_geometry = (
                geometry, self.noise, wheel_jacobian(geometry), RatioModel.of(geometry, self.noise))
        _, _, b, model = cached
        u, v, dth_w = model.u, model.v, model.turn(phi_r, phi_l)
        var_white = cfg.noise_density ** 2 * dt
        g = raw - bias * dt
        var_g = var_white + bias_variance * dt * dt + self.samples.rounding_variance(dt)
        var_l, var_r = joint_variances(self.noise, geometry, d_left, d_right)
        rates = ((0.0, 0.0) if standing
                 else (self.samples.rate(t0) - bias, self.samples.rate(t1) - bias))
        var_w = turn_variance(model, phi_r, phi_l, (var_r, var_l), self.quantization,
                              self.jitter.sigma, rates)
        diff = g - dth_w
        slip = diff * diff > cfg.slip_sigmas ** 2 * (var_w + var_g)
        geo_ds = (0.5 * s_l, 0.5 * s_r, 0.0)
        geo_th = (-s_l / geometry.separation, s_r / geometry.separation, -dth_w)
        if not slip:
            w_g = var_w / (var_w + var_g) if var_w + var_g > 0.0 else 0.0
            w_w = 1.0 - w_g
            return _Judged(False, -diff, GyroStep(
                ds=0.5 * (s_l + s_r), dtheta=w_w * dth_w + w_g * g,
                b=(b[0], (-w_w * v, w_w * u)), c=(0.0, w_g), var_gyro=var_white,
                dt=dt, geometry=(geo_ds, tuple(w_w * e for e in geo_th)), slip=False))
        step, excess = slip_step(geometry, (u, v), arcs, g, dt, b, var_white, self._spun,
                                 SPIN_SIGMAS * self._timing(),
                                 cfg.slip_distance_from_other_wheel)
        return _Judged(True, -diff, step, excess)
