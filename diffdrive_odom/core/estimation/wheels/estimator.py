"""The wheel odometry estimator: readings in, pose / twist out.

Pure Python, shared by the odometry node, offline replay and the benchmarks. A
reading flows one way: decode (encoders) -> increment -> kinematics -> CIR step
(integration). Every reading gets a verdict (:class:`Status`) so the caller can log
or count without the estimator knowing about ROS logging (the verdicts and their
texts: :mod:`diffdrive_odom.core.estimation.wheels.timeline`).

Rules that make it safe to feed anything (no exception escapes, no state is ever
non-finite):

- the first reading (and the first after a reset or a re-anchor) is the reference:
  it is never integrated as motion, whatever its value;
- a reading that cannot be used (bad arrays, NaN, a count outside the counter's range,
  same or slightly older stamp) is dropped and the reference kept. After older stamps
  (reordering, a driver's clock stepping back less than ``time_jump_threshold``) the
  next newer reading still integrates from the reference, so no motion is lost; the
  step's interval is rebuilt from the older stamps and the twist comes from the last
  of them, so it does not spike;
- a step of positions is judged over the time since the counts last changed, capped
  at ``max_reading_gap`` (:mod:`~.wheels.counts`): a reading held (counts repeated) and
  released with a stamp just after the last adds the whole hold's motion. The twist,
  its covariance and the gyro's comparison take the same interval;
- an implausible step is skipped and the reading becomes the new reference, so one
  glitch costs one step instead of freezing. Implausible is defined once
  (:mod:`~diffdrive_odom.core.estimation.wheels.plausibility`, with its array form): a wheel
  faster than ``max_wheel_speed`` over the step's interval (which the gap rule bounds),
  a wheel rolling more than :data:`MAX_STEP_ARC` whatever the settings, or a step
  that is not finite;
- a reading more than ``max_reading_gap`` after the last usable one is held: if the
  next reading continues from it (within ``max_reading_gap``), the pause was real and
  the counts decide (:mod:`~.wheels.counts`): a driver restart is a new reference
  (``gap``), counts that went on are integrated as one arc (``gap_integrated``, the
  covariance grown: :func:`~diffdrive_odom.core.uncertainty.noise.unknown_path`). If
  the next is back near the old timeline, the held one was a lone outlier and is
  dropped (``future_stamp``), so a bogus stamp neither licenses travel nor fakes a bag
  loop;
- a timeline taken after a gap is on trial until it has lasted
  :data:`~diffdrive_odom.core.estimation.wheels.timeline.ADOPT_CLOCK_AFTER_S` of its own stamps: a
  reading back on the old timeline (after its last reading, by no more than the new
  one has run) shows the new one was a burst of outlier stamps, which is discarded
  (``future_stamp``, every reading of it counted) and the pose integrated from the
  old timeline's last reading (positions are cumulative: no motion is lost). When
  receive times are known, a jump into the future that the receiver's clock did not
  see elapse (not a pause: the driver's clock jumped) is not published while on
  trial, so no far-future pose leaks out; one that lasts is the driver's new clock,
  taken (``gap``) once it has lasted that long;
- a stamp far in the past (a bag played in a loop) starts over at the origin.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Protocol

from diffdrive_odom.core.estimation.wheels import timeline
from diffdrive_odom.core.estimation.wheels.config import EstimatorConfig
from diffdrive_odom.core.estimation.wheels.counts import CountTrack, gap_motion
from diffdrive_odom.core.estimation.wheels.encoders import (
    EncoderConfig,
    JointLookup,
    Reason,
    WheelIncrement,
    WheelReading,
    decode,
    increment,
)
from diffdrive_odom.core.estimation.wheels.plausibility import counter_wrap, implausible
from diffdrive_odom.core.estimation.wheels.timeline import ON_TRIAL, UPDATED, Status, Trial, Verdict
from diffdrive_odom.core.estimation.wheels.twist import RollingTwist
from diffdrive_odom.core.geometry.integration import Pose2D, compose
from diffdrive_odom.core.geometry.kinematics import Geometry, body_from_arcs, wheel_arcs
from diffdrive_odom.core.geometry.mat3 import Matrix, add3
from diffdrive_odom.core.uncertainty.noise import NoiseModel, unknown_path
from diffdrive_odom.core.uncertainty.propagation import (
    ZERO3,
    ZERO_VEC,
    GyroStep,
    PoseUncertainty,
)


class HeadingSource(Protocol):
    """Each step's heading from elsewhere (the gyro's, which the pipeline wires in)."""

    @property
    def bias_variance(self) -> float:
        """The heading rate's bias variance [(rad/s)^2], for the step's covariance."""
        ...

    def step(self, geometry: Geometry, t0: int, t1: int, d_left: float, d_right: float,
             arcs: tuple[float, float]) -> GyroStep | None:
        """The step ``t0 -> t1`` (its joint increments, arcs); None: the wheels' own."""
        ...


@dataclass(frozen=True)
class Step:
    """One integrated step: what replay and covariance propagation need to know."""

    dt: float
    ds: float
    dtheta: float


class OdometryEstimator:
    """Integrates wheel encoder readings into a pose in the odom frame."""

    def __init__(
        self,
        geometry: Geometry,
        encoders: EncoderConfig,
        config: EstimatorConfig | None = None,
        noise: NoiseModel | None = None,
    ) -> None:
        self.encoders = encoders
        self.config = config or EstimatorConfig()
        self._lookup = JointLookup(encoders)
        self.geometry = geometry
        self.pose = Pose2D()
        self.linear = 0.0  # m/s along base x, smoothed
        self.angular = 0.0  # rad/s about base z, smoothed
        self.last_step: Step | None = None
        # Geometry-free joint increments of the last integrated step (for batch replay).
        self.last_increment: WheelIncrement | None = None
        self._reference: WheelReading | None = None
        self.counts = CountTrack()  # what the reference's counts did lately
        self.last_gap: tuple[int, WheelIncrement] | None = None  # end stamp, step
        # A reading far ahead of the reference, kept until the next one decides.
        self._held: WheelReading | None = None
        # First and last stale (older) readings since the last step, same input mode.
        self._stale: tuple[WheelReading, WheelReading] | None = None
        # The timeline taken after the last gap, while on trial.
        self._trial: Trial | None = None
        self._twist = RollingTwist(self.config.velocity_rolling_window_size)
        # Pose / twist covariance propagated through each step; None = not modelled
        # (covariance_model static: the caller publishes fixed diagonals).
        self.uncertainty: PoseUncertainty | None = None
        self.set_noise(noise)
        # Gyrodometry (``use_imu``): the heading of each step, None = wheels only.
        self.heading: HeadingSource | None = None

    @property
    def stamp_ns(self) -> int | None:
        """Stamp of the reading the current pose refers to (None before the first)."""
        return None if self._reference is None else self._reference.stamp_ns

    @property
    def on_trial(self) -> bool:
        """True while the timeline taken after the last gap may still be discarded."""
        return self._trial is not None

    def place(self, pose: Pose2D, covariance: Matrix) -> None:
        """``~/set_pose``'s overwrite (:mod:`~.setpose`): the pose where it stands.

        The propagated covariance too (the geometry and bias terms start again from zero).
        """
        self.pose = pose
        if self.uncertainty is not None:
            self.uncertainty.covariance = covariance
            self.uncertainty.sensitivity, self.uncertainty.bias_sensitivity = ZERO3, ZERO_VEC

    @property
    def from_velocity(self) -> bool:
        """True when the reference reading came from wheel velocities, not positions."""
        return self._reference is not None and self._reference.from_velocity

    def set_geometry(self, geometry: Geometry) -> None:
        """Swap geometry at runtime (a parameter change); the pose carries on from here."""
        self.geometry = geometry

    def set_noise(self, noise: NoiseModel | None) -> None:
        """Swap the noise model (None = no covariance propagation); the covariance carries on."""
        if noise is None:
            self.uncertainty = None
            return
        if self.uncertainty is not None:
            self.uncertainty.model = noise
            return
        self.uncertainty = PoseUncertainty(
            noise,
            self.encoders.ticks_per_revolution,
            len(self.encoders.left_wheel_names),
            self.config.velocity_rolling_window_size,
        )

    def reset(self) -> None:
        """Pose and twist to zero; the last reading stays the reference, so no jump follows."""
        self.pose = Pose2D()
        self.last_step = None
        self._trial = None  # its saved pose is from before the reset
        self._forget_twist()
        if self.uncertainty is not None:
            self.uncertainty.reset()

    def _forget_twist(self) -> None:
        self.linear = self.angular = 0.0
        self._twist.clear()
        if self.uncertainty is not None:
            self.uncertainty.forget_twist()

    def restart(self) -> None:
        """Forget everything, including the reference reading."""
        self.reset()
        self._reference = None
        self._held = None
        self._stale = None
        self._trial = None

    def _anchor(self, reading: WheelReading) -> None:
        """``reading`` is the first of a timeline: the reference, its counts the start."""
        self._reference = reading
        self.counts.anchor(reading)

    def handover(self) -> WheelReading | None:
        """The reference if no rule has anything pending (held, stale, trial), else None.

        Only then may a bulk integrator (:mod:`diffdrive_odom.core.bulk.fastlane`) carry on.
        """
        pending = self._held is not None or self._stale is not None or self._trial is not None
        return None if pending else self._reference

    def twist_windows(self) -> tuple[tuple[float, ...], tuple[float, ...]]:
        """The rolling means' windows (linear, angular), oldest first."""
        return self._twist.windows()

    def take_over(self, reference: WheelReading, pose: Pose2D,
                  windows: tuple[Sequence[float], Sequence[float]], inc: WheelIncrement,
                  step: Step, counts: tuple[int, WheelIncrement | None]) -> None:
        """Install what a bulk integrator reached, as if its readings had been fed here.

        ``counts``: :attr:`counts`' ``changed_ns`` and ``moved``.
        """
        self._reference, self.pose, self.last_increment, self.last_step = (
            reference, pose, inc, step)
        self.counts.changed_ns, self.counts.moved = counts
        self.linear, self.angular = self._twist.install(windows)

    def update(
        self,
        stamp_ns: int,
        names: Sequence[str],
        position: Sequence[float],
        velocity: Sequence[float] = (),
        receive_ns: int | None = None,
    ) -> Verdict:
        """Feed one JointState's content; returns what was done with it.

        ``receive_ns``: when it arrived on the receiver's clock (the node's, a bag's log
        time), if known: it tells a real pause from a driver's clock that jumped.
        """
        reading = decode(self._lookup, stamp_ns, names, position, velocity,
                         self.encoders.counter_bits, receive_ns)
        if not isinstance(reading, WheelReading):
            return Verdict(Status.DROPPED, reading.code, str(reading))
        ref = self._reference
        if ref is None:
            self._anchor(reading)
            return Verdict(Status.REFERENCE, Reason.FIRST, "first reading taken as reference")
        age_ns = ref.stamp_ns - reading.stamp_ns
        gap = self.config.max_reading_gap
        trial = self._trial
        if age_ns >= 0:
            if trial is not None and trial.returned_to(reading, ref.stamp_ns, gap * 1e9):
                return self._discard_trial(trial, reading)
            if age_ns > self.config.time_jump_threshold * 1e9:
                self.restart()
                self._anchor(reading)
                return timeline.time_reset(age_ns)
            if age_ns > 0 and reading.from_velocity == ref.from_velocity:
                # Kept for the next step's interval and twist (a clock stepped back).
                self._stale = (self._stale[0] if self._stale else reading, reading)
            return timeline.stale(age_ns)
        held = self._held
        if -age_ns * 1e-9 > gap:
            if held is not None and 0 < reading.stamp_ns - held.stamp_ns <= gap * 1e9:
                return self._continue_after_gap(ref, held, reading)
            # Far ahead: a pause (the next reading will continue from it) or a lone
            # outlier (the next is back near the old timeline); wait and see.
            self._held = reading
            return timeline.held(-age_ns, None if held is None else held.stamp_ns - ref.stamp_ns)
        verdict = self._step(ref, reading)
        if held is not None:
            self._held = None
            if verdict.status is Status.UPDATED:
                verdict = timeline.lone_outlier(held.stamp_ns - ref.stamp_ns)
        return verdict if trial is None else self._on_trial(trial, reading, verdict)

    def _on_trial(self, trial: Trial, reading: WheelReading, verdict: Verdict) -> Verdict:
        """``verdict`` for a reading on a timeline on trial: taken for good once it lasted."""
        trial.readings += 1
        if not trial.lasted(reading):
            return ON_TRIAL if trial.suspect and verdict.status is Status.UPDATED else verdict
        self._trial = None
        if not trial.suspect or verdict.status is not Status.UPDATED:
            return verdict
        return timeline.clock_adopted(trial)

    def _discard_trial(self, trial: Trial, reading: WheelReading) -> Verdict:
        """The old timeline is back: the trial's readings were outliers; integrate from it.

        Pose and covariance go back to what the old timeline left; the step from its
        last reading covers every motion since (positions are cumulative).
        """
        self._trial = self._held = self._stale = None
        self.pose = trial.pose
        unc = self.uncertainty
        if unc is not None and trial.covariance is not None:
            unc.covariance, unc.sensitivity = trial.covariance
        self._forget_twist()
        verdict = self._step(trial.before, reading, trial.before.stamp_ns)
        return timeline.burst_discarded(trial) if verdict.status is Status.UPDATED else verdict

    def _continue_after_gap(
        self, ref: WheelReading, held: WheelReading, reading: WheelReading
    ) -> Verdict:
        """A held reading is continued: the pause was real; the counts say what it held.

        A restart keeps the pose, motion that went on is one arc
        (:func:`~.wheels.counts.gap_motion`); then this reading is integrated from the
        held one, the twist forgotten. The new timeline is on trial
        (:class:`~.wheels.timeline.Trial`), not published while on it if the driver's
        clock jumped (:func:`~.wheels.timeline.suspect_jump`).
        """
        unc, cfg = self.uncertainty, self.config
        self._trial = trial = Trial(
            ref, held, self.pose, None if unc is None else (unc.covariance, unc.sensitivity),
            timeline.suspect_jump(ref, held, cfg.max_reading_gap))
        self._held = self._stale = None
        gap = gap_motion(self.encoders, cfg, self.geometry, ref, held, reading, self.counts)
        self._forget_twist()
        if isinstance(gap, WheelIncrement):
            gap = "" if self._integrate_gap(gap, ref.stamp_ns, held.stamp_ns) else (
                "its integration is not a finite number")
        verdict = self._step(held, reading, held.stamp_ns)
        if verdict.status is not Status.UPDATED:
            return verdict
        return timeline.gap_taken(trial, cfg.max_reading_gap, gap)

    def _integrate_gap(self, gap: WheelIncrement, t0_ns: int, t1_ns: int) -> bool:
        """The gap's step as one arc, no twist; the covariance grown for the unknown path."""
        theta = self.pose.theta
        arcs = wheel_arcs(self.geometry, gap.d_left, gap.d_right)
        if not self._integrate(gap, arcs, gap, arcs, t0_ns, t1_ns, twist=False):
            return False
        unc, step = self.uncertainty, self.last_step
        if unc is not None and step is not None:
            unc.covariance = add3(unc.covariance, unknown_path(theta, step.ds, step.dtheta))
        self.last_gap = t1_ns, gap
        return True

    def _step(self, ref: WheelReading, reading: WheelReading,
              changed_ns: int | None = None) -> Verdict:
        """Integrate ``reading`` from the reference ``ref`` if the step is plausible.

        Whatever happens, ``reading`` is the reference afterwards. A step of positions
        is judged over the time since the counts last changed (``changed_ns``, default
        the reference's), capped at ``max_reading_gap``. After stale readings (a clock
        stepped back by less than ``time_jump_threshold``) the step still starts at
        ``ref``, so no motion is lost; its interval is rebuilt from the stale stamps and
        the twist comes from the last stale reading, the true local rate.
        """
        stale, self._stale = self._stale, None
        self._reference = reading
        counts = self.counts
        if reading.from_velocity != ref.from_velocity:
            counts.stepped(reading, None)
            return Verdict(Status.REFERENCE, Reason.INPUT_SWITCH,
                           "switched between position and velocity input")
        inc = counts.judged(ref, reading, increment(self.encoders, ref, reading),
                            counts.changed_ns if changed_ns is None else changed_ns,
                            self.config)
        rate = inc
        if stale is not None and stale[1].from_velocity == reading.from_velocity:
            rate = increment(self.encoders, stale[1], reading)
            # Stale readings s1..sk each one period apart, then this one: k + 1 periods
            # since ref. An upper bound for a late-delivered (truly old) reading too.
            span = (reading.stamp_ns - stale[0].stamp_ns) * 1e-9 + rate.dt
            inc = replace(inc, dt=max(inc.dt, min(span, self.config.max_reading_gap)))
        # Each increment's arcs are computed once, for the check and the integration.
        arcs = wheel_arcs(self.geometry, inc.d_left, inc.d_right)
        why = implausible(self.config, inc, arcs)
        rate_arcs = arcs
        if rate is not inc:
            rate_arcs = wheel_arcs(self.geometry, rate.d_left, rate.d_right)
            why = why or implausible(self.config, rate, rate_arcs)
        if not why and not self._integrate(inc, arcs, rate, rate_arcs,
                                           ref.stamp_ns, reading.stamp_ns):
            why = "its integration is not a finite number"
        counts.stepped(reading, None if why else inc)
        if why:
            return timeline.too_fast(why, counter_wrap(self.encoders, self.config, inc))
        return UPDATED

    def _integrate(
        self,
        inc: WheelIncrement,
        arcs: tuple[float, float],
        rate: WheelIncrement,
        rate_arcs: tuple[float, float],
        t0_ns: int,
        t1_ns: int,
        twist: bool = True,
    ) -> bool:
        """Apply the step ``inc``, the twist from ``rate``; False if it cannot be applied.

        ``arcs``, ``rate_arcs``: their wheel arcs; ``t0_ns``, ``t1_ns``: the step's
        stamps (the gyro's interval); ``twist`` False: the twist is not pushed (a gap's
        step, whose mean speed is no rate). Nothing changes when pose, twist or step
        would not be finite: no state is NaN.
        """
        ds, dtheta = body_from_arcs(self.geometry, *arcs)
        rate_ds, rate_dtheta = (
            (ds, dtheta) if rate_arcs is arcs else body_from_arcs(self.geometry, *rate_arcs)
        )
        linear, angular = rate_ds / rate.dt, rate_dtheta / rate.dt
        gyro, start = None, self.pose
        if self.heading is not None:
            gyro = self.heading.step(self.geometry, t0_ns, t1_ns, inc.d_left, inc.d_right, arcs)
            if gyro is not None:  # held readings only turned the pose: one arc from before
                ds, dtheta = gyro.ds, gyro.dtheta + gyro.merged
                start = Pose2D(start.x, start.y, start.theta - gyro.merged)
                angular = dtheta / inc.dt
                linear = ds / inc.dt if gyro.slip else linear
        isfinite = math.isfinite
        if not (isfinite(ds) and isfinite(dtheta) and isfinite(linear) and isfinite(angular)):
            return False
        pose = compose(start, ds, dtheta)
        if not (isfinite(pose.x) and isfinite(pose.y) and isfinite(pose.theta)):
            return False
        if self.uncertainty is not None and gyro is not None and self.heading is not None:
            self.uncertainty.propagate_gyro(
                self.pose, gyro, d_left=inc.d_left, d_right=inc.d_right,
                geometry=self.geometry, bias_variance=self.heading.bias_variance)
        elif self.uncertainty is not None:
            self.uncertainty.propagate(
                self.pose, self.geometry, ds=ds, dtheta=dtheta,
                d_left=inc.d_left, d_right=inc.d_right, dt=inc.dt)
        self.pose = pose
        self.last_step = Step(inc.dt, ds, dtheta)
        self.last_increment = inc
        if twist:  # constant-velocity motion about the CIR has exactly this body twist
            self.linear, self.angular = self._twist.push(linear, angular)
        return True
