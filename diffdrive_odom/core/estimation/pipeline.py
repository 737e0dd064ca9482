"""One reading's path, shared by the odometry node, ``replay`` and the demo.

Every rule for one JointState reading is applied here, in this order: the stamp is
chosen (``stamp_source``: the header's, or the receive time) and a header stamp far
from the receiver's clock is named once (:mod:`diffdrive_odom.core.estimation.stamps`); a zero or
negative stamp is dropped (output is stamped with the measurement time, so an
unstamped reading cannot be placed); the estimator decides (decode, stale stamps,
time reset, gap, speed check, integration); the ``publish_rate`` gate decides whether
the pose goes out. The outcome and a set of counters come back, so the node logs,
replay summarises and diagnostics report from the same numbers. With ``use_imu`` the
IMU's samples come in through :meth:`ReadingPipeline.feed_imu` and the estimator takes
each step's heading from :mod:`~diffdrive_odom.core.estimation.gyro.gyrodometry` and its
geometry from :func:`~.online_apply.geometry_in_use` (``apply``). Pure Python.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from types import MappingProxyType

from diffdrive_odom.core.estimation.config import OdometrySettings
from diffdrive_odom.core.estimation.gate import PublishGate
from diffdrive_odom.core.estimation.gyro.gyrodometry import GyroHeading
from diffdrive_odom.core.estimation.gyro.imuinput import ImuInput
from diffdrive_odom.core.estimation.online.online_apply import geometry_in_use
from diffdrive_odom.core.estimation.online.online_geometry import OnlineGeometry
from diffdrive_odom.core.estimation.results import GyroStats, Handover, Outcome, PipelineStats
from diffdrive_odom.core.estimation.setpose import (
    PoseRefusal,
    PoseRequest,
    SetPoseRule,
    check_request,
)
from diffdrive_odom.core.estimation.stamps import ClockOffsetCheck, StampSource
from diffdrive_odom.core.estimation.wheels.encoders import (
    Reason,
    WheelIncrement,
)
from diffdrive_odom.core.estimation.wheels.estimator import OdometryEstimator, Step
from diffdrive_odom.core.estimation.wheels.timeline import Status, Verdict
from diffdrive_odom.core.geometry.mount import Mount
from diffdrive_odom.core.uncertainty.noise import quantization_variance
from diffdrive_odom.core.uncertainty.propagation import (
    covariance_matrix,
    pose_message_covariance,
    twist_message_covariance,
)

ZERO_STAMP = Verdict(
    Status.DROPPED, Reason.ZERO_STAMP,
    "header stamp is zero (odometry is stamped with the measurement time, so the driver "
    "must stamp its readings)",
)
VELOCITY_ON = (
    "wheel positions are empty or NaN for every wheel: integrating wheel velocities instead "
    "(ros2_control without a position state interface); odometry drifts faster this way"
)
VELOCITY_OFF = "wheel positions are available again: integrating positions"
IMU_SILENT = ("IMU silent (no usable yaw rate within imu_timeout of a wheel step): wheels "
              "only, the heading covariance grows with the wheels' model again")
IMU_BACK = "IMU samples again: gyro-aided heading"
SET_POSE_DROPPED = "set_pose: the held pose is dropped (odometry restarted)"


class ReadingPipeline:
    """The estimator and the publish gate behind one ``feed`` call, with counters."""

    def __init__(self, settings: OdometrySettings, trace: bool = False) -> None:
        """``trace``: keep ``online.trace``, the estimate's history (replay, the demo)."""
        self._settings = settings
        self._trace = trace
        self._estimator = OdometryEstimator(
            settings.geometry, settings.encoders, settings.estimator, settings.noise
        )
        self._static = _static_covariances(settings)
        self._gate = PublishGate(settings.publish_rate)
        self._readings = 0
        self._published = 0
        self._dropped: dict[str, int] = {}
        self._reanchors = 0
        self._causes: dict[str, int] = {}
        self._gap_reanchors = 0
        self._gaps_integrated = 0
        self._time_resets = 0
        self._last_usable_ns: int | None = None
        self._velocity = False
        self._clock = ClockOffsetCheck()
        self._gyro: GyroHeading | None = None
        self._imu: ImuInput | None = None
        self._online: OnlineGeometry | None = None
        self._imu_silent = False  # so a missing IMU is named (see _imu_note)
        self._first_usable_ns: int | None = None
        self._setpose = SetPoseRule()
        self._attach_gyro(settings)

    def _attach_gyro(self, settings: OdometrySettings) -> None:
        """Give the estimator the gyro's heading (``use_imu``), keeping its state if any."""
        cfg = settings.gyro
        if cfg is None:
            self._gyro = None
        elif self._gyro is None:
            est = settings.estimator
            enc = settings.encoders
            self._gyro = GyroHeading(cfg, settings.noise, est.time_jump_threshold,
                                     est.max_reading_gap, quantization_variance(
                                         enc.ticks_per_revolution, len(enc.left_wheel_names)))
            self._imu = ImuInput(self._gyro)
        else:
            self._gyro.set_config(cfg)
            self._gyro.noise = self._gyro.noise if settings.noise is None else settings.noise
        self._estimator.heading = self._gyro
        if self._gyro is not None:
            self._gyro.wheel_stamp_ns = self._estimator.stamp_ns
        self._attach_online(settings)

    def _attach_online(self, settings: OdometrySettings) -> None:
        """Let the online geometry estimate listen to the gyro's judged steps (monitor)."""
        gyro, cfg = self._gyro, settings.gyro
        if gyro is None or cfg is None or settings.online is None:
            self._online = None
        elif self._online is None:
            enc = settings.encoders
            self._online = OnlineGeometry(
                settings.online, settings.geometry, cfg.noise_density, gyro.bias,
                math.sqrt(gyro.bias_variance), cfg.bias_random_walk, gyro.noise,
                quantization_variance(enc.ticks_per_revolution, len(enc.left_wheel_names)),
                gyro.standstill.measured_density, trace=self._trace,
                jitter=lambda: gyro.jitter.sigma, lag=lambda: gyro.lag.seconds)
        else:
            self._online.set_config(settings.online)
            self._online.set_geometry(settings.geometry)
        if gyro is not None:
            gyro.observer = None if self._online is None else self._online.observe

    @property
    def online(self) -> OnlineGeometry | None:
        """The online geometry estimate (its trace), None unless it runs."""
        return self._online

    @property
    def gyro(self) -> GyroHeading | None:
        """The gyro's state (bias, slips), None with ``use_imu`` false."""
        return self._gyro

    def feed_imu(self, stamp_ns: int, wx: float, wy: float, wz: float,
                 receive_ns: int | None = None, check_clock: bool = True,
                 covariance: tuple[float, ...] = ()) -> str:
        """Offer one IMU sample (angular velocity in the IMU's frame, header stamp).

        Returns '' when kept, else the drop code (counted in ``stats.gyro.dropped``).
        With ``use_imu`` false nothing happens (''). ``receive_ns``, ``check_clock``: as
        :meth:`feed`'s, for ``imu_stamp_source``; ``covariance``: the message's
        angular_velocity_covariance (:mod:`~diffdrive_odom.core.estimation.gyro.imuinput`).
        """
        imu = self._imu
        if imu is None or self._gyro is None:
            return ""
        return imu.feed(stamp_ns, wx, wy, wz, receive_ns, check_clock, covariance)

    def feed_reference(self, stamp_ns: int, x: float, y: float, yaw: float) -> str:
        """Offer one reference pose (a lidar odometry, AMCL) to the online estimate's scale.

        The node and replay both give it here; '' if kept or not used (no online
        estimate, no reference topic), else the code it was refused with
        (:mod:`~diffdrive_odom.core.estimation.online.online_scale`).
        """
        scale = None if self._online is None else self._online.scale
        return "" if scale is None else scale.feed(stamp_ns, x, y, yaw)

    def set_reference_mount(self, mount: Mount) -> None:
        """Where the reference is mounted, once found (the node's /tf_static, a bag's)."""
        scale = None if self._online is None else self._online.scale
        if scale is not None:
            scale.set_mount(mount)

    def _imu_note(self, silent: bool, stamp_ns: int) -> bool:
        """True when the IMU's silence (or its end) is to be said for this step.

        Before the IMU's first sample the wheels only wait imu_timeout before it is
        named: an IMU that starts a little after the wheels (the TurtleBot3 bag's 0.3 s;
        its topic matched after joint_states at a node's start) is no silence, and "IMU
        silent" then "IMU samples again" at every start told nothing.
        """
        if silent == self._imu_silent:
            return False
        if not silent or self._imu is None or self._imu.samples or self._gyro is None:
            return True
        first = self._first_usable_ns
        return first is None or stamp_ns - first >= self._gyro.config.timeout * 1e9

    @property
    def estimator(self) -> OdometryEstimator:
        """The estimator (pose, twist, last step); feed readings through :meth:`feed` only."""
        return self._estimator

    @property
    def settings(self) -> OdometrySettings:
        """The settings in force."""
        return self._settings

    @property
    def stats(self) -> PipelineStats:
        """A read-only snapshot of the counters."""
        return PipelineStats(
            readings=self._readings,
            published=self._published,
            dropped=MappingProxyType(dict(self._dropped)),
            reanchors=self._reanchors,
            causes=MappingProxyType(dict(self._causes)),
            gap_reanchors=self._gap_reanchors,
            gaps_integrated=self._gaps_integrated,
            time_resets=self._time_resets,
            last_usable_stamp_ns=self._last_usable_ns,
            velocity_fallback=self._velocity,
            gyro=None if (g := self._gyro) is None or (imu := self._imu) is None else GyroStats(
                imu.samples, imu.dropped, g.silent and g.steps > 0,
                g.bias, g.bias_variance ** 0.5, g.zero_velocity_updates, g.slips,
                g.standstill.standing_ns * 1e-9, g.jitter.sigma, g.lag.estimate),
            online=None if self._online is None else self._online.estimate(),
        )

    def feed(
        self,
        stamp_ns: int,
        names: Sequence[str],
        position: Sequence[float],
        velocity: Sequence[float] = (),
        receive_ns: int | None = None,
        check_clock: bool = True,
    ) -> Outcome:
        """Apply every rule to one reading (a JointState's stamp and arrays).

        ``receive_ns``: when it arrived on the receiver's clock (the node's clock, a
        bag's log time; None: unknown). ``check_clock``: False where that clock is not
        the one drivers stamp with (simulated time), so no offset is named.
        """
        self._readings += 1
        warning = ""
        if receive_ns is not None and receive_ns > 0:
            if self._settings.stamp_source is StampSource.RECEIVE_TIME:
                stamp_ns = receive_ns
            elif check_clock and stamp_ns > 0:
                warning = self._clock.check(stamp_ns, receive_ns)
        else:
            receive_ns = None
        gyro, est = self._gyro, self._estimator
        steps = 0 if gyro is None else gyro.steps
        geometry, switched = geometry_in_use(self._online, self._settings.geometry, est.uncertainty)
        est.set_geometry(geometry)
        verdict = (
            self._estimator.update(stamp_ns, names, position, velocity, receive_ns)
            if stamp_ns > 0 else ZERO_STAMP
        )
        status = verdict.status
        dropped = verdict.dropped_code
        if dropped is not None:
            self._dropped[dropped] = self._dropped.get(dropped, 0) + verdict.count
        if gyro is not None and self._estimator.stamp_ns is not None:
            gyro.wheel_stamp_ns = max(gyro.wheel_stamp_ns or 0, self._estimator.stamp_ns)
            if status is Status.TIME_RESET:
                gyro.wheel_stamp_ns = self._estimator.stamp_ns
            if self._estimator.stamp_ns == stamp_ns:  # the newest wheel stamp's arrival
                gyro.wheel_receive_ns = receive_ns
        if status in (Status.DROPPED, Status.HELD):
            return Outcome(verdict, False, "", warning, stamp_ns)
        self._last_usable_ns = stamp_ns
        if self._first_usable_ns is None:
            self._first_usable_ns = stamp_ns
        if status is Status.REANCHORED:
            self._reanchors += 1
            if verdict.cause:
                self._causes[verdict.cause] = self._causes.get(verdict.cause, 0) + 1
        elif status is Status.TIME_RESET:
            self._time_resets += 1
        elif verdict.code is Reason.GAP:
            self._gap_reanchors += 1
        elif verdict.code is Reason.GAP_INTEGRATED:
            self._gaps_integrated += 1
        note = switched
        if self._estimator.from_velocity != self._velocity:
            self._velocity = not self._velocity
            note = VELOCITY_ON if self._velocity else VELOCITY_OFF
        elif gyro is not None and gyro.steps != steps and self._imu_note(gyro.silent, stamp_ns):
            self._imu_silent = gyro.silent
            note = IMU_SILENT if gyro.silent else IMU_BACK
        if self._imu is not None and not warning:
            warning = self._imu.take_warning()
        if self._online is not None and not warning:
            warning = self._online.take_warning()
        if self._setpose.pending is not None:  # ~/set_pose held for this reading's stamp
            if status is Status.TIME_RESET:
                self._setpose.pending, note = None, note or SET_POSE_DROPPED
            elif self._setpose.reached(stamp_ns, self._estimator):
                self._gate.forget()
        publish = verdict.has_new_pose and self._gate.due(stamp_ns)
        if publish:
            self._published += 1
        return Outcome(verdict, publish, note, warning, stamp_ns)

    def handover(self) -> Handover:
        """The state a bulk integrator starts from (see :class:`Handover`)."""
        est, unc = self._estimator, self._estimator.uncertainty
        return Handover(
            reference=None if self._setpose.pending else est.handover(),
            counts=(est.counts.changed_ns, est.counts.moved), pose=est.pose,
            windows=est.twist_windows(),
            covariance=() if unc is None else unc.covariance,
            sensitivity=() if unc is None else unc.sensitivity,
            rates=() if unc is None else unc.rates, gate=self._gate.state,
            clock_named=self._clock.offset_ns is not None)

    def take_back(self, state: Handover, readings: int, published: int,
                  inc: WheelIncrement, step: Step) -> None:
        """Install the state a bulk integrator reached after ``readings`` updates.

        ``state.reference``: the last of them; ``inc``, ``step``: its step; ``published``:
        how many of them passed the gate. Counters go on as if each had been fed.
        """
        assert state.reference is not None
        est, unc = self._estimator, self._estimator.uncertainty
        est.take_over(state.reference, state.pose, state.windows, inc, step, state.counts)
        if unc is not None:
            unc.covariance, unc.sensitivity = state.covariance, state.sensitivity
            unc.set_rates(state.rates)
        self._gate.state = state.gate
        self._readings += readings
        self._published += published
        self._last_usable_ns = state.reference.stamp_ns

    def covariances(self) -> tuple[list[float], list[float]]:
        """Pose and twist covariance (6x6 row-major) of the current estimate.

        ``covariance_model`` propagated: the estimator's propagated model; static: the
        configured diagonals. The node and replay both publish exactly this.
        """
        est = self._estimator
        unc = est.uncertainty
        if unc is None:
            return self._static
        return (pose_message_covariance(unc.pose_covariance(est.pose, est.geometry)),
                twist_message_covariance(unc.twist_covariance()))

    def reset(self) -> None:
        """Pose and twist to the origin; the next reading is published whatever the rate."""
        self._estimator.reset()
        self._gate.forget()
        self._setpose.pending = None

    def set_pose(self, request: PoseRequest) -> str | PoseRefusal:
        """``~/set_pose`` (:mod:`~diffdrive_odom.core.estimation.setpose`), checked and set.

        Returns the line that names it in the log, or why it is refused. The next pose
        published is the first after the pose is set, whatever ``publish_rate``.
        """
        accepted = check_request(request, self._settings.odom_frame_id)
        if isinstance(accepted, PoseRefusal):
            return accepted
        line = self._setpose.offer(accepted, self._estimator, self._estimator.uncertainty is None)
        if self._setpose.pending is None:
            self._gate.forget()
        return line

    def reconfigure(self, settings: OdometrySettings) -> None:
        """Install validated settings at runtime; the pose carries on without a jump.

        A new encoder or estimator config changes the units of the reference reading
        (a new ``stamp_source`` its time), so the pose is kept and the next reading
        becomes the reference. Counters go on.
        """
        old = self._settings
        self._settings = settings
        self._static = _static_covariances(settings)
        if settings.publish_rate != old.publish_rate:
            self._gate.rate = settings.publish_rate
        if (settings.encoders != old.encoders or settings.estimator != old.estimator
                or settings.stamp_source != old.stamp_source):
            before = self._estimator
            self._estimator = OdometryEstimator(
                settings.geometry, settings.encoders, settings.estimator, settings.noise
            )
            self._estimator.pose = before.pose
            if before.uncertainty is not None and self._estimator.uncertainty is not None:
                self._estimator.uncertainty.carry_on_from(before.uncertainty)
        else:
            self._estimator.set_geometry(settings.geometry)
            self._estimator.set_noise(settings.noise)
        self._attach_gyro(settings)


def _static_covariances(settings: OdometrySettings) -> tuple[list[float], list[float]]:
    return (covariance_matrix(settings.pose_covariance_diagonal),
            covariance_matrix(settings.twist_covariance_diagonal))
