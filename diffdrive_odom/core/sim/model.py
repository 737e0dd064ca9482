"""A simulated differential-drive base: wheel commands in, encoder readings and true pose out.

Pure Python (no rclpy), so its physics is tested against closed forms in
microseconds and reused by ``sim_node``, tests and benchmarks. What it models, each
switchable, all random draws from one seeded ``numpy.random.Generator``:

- the robot's TRUE geometry (a :class:`~diffdrive_odom.core.geometry.kinematics.Geometry`), which
  may differ from the nominal one the odometry and cmd_vel nodes are given: that
  difference is the systematic odometry error calibration has to find. The joint
  signs in it are the hardware's (a flipped joint counts backwards when driving
  forward, and turns backwards for a positive rate command);
- a first-order motor response per joint (time constant ``tau``), integrated exactly
  for a command held over a step;
- encoders that count whole ticks (``ticks_per_revolution``) in a fixed-width
  counter that wraps (``counter_bits``), starting from any count;
- wheel slip: the ground arc of each side differs from the arc its wheel rolled by
  Gaussian noise whose variance grows in proportion to the distance rolled (Carroll
  and Jha, "Differential Drive Kinematics", section 2.3, add unit Gaussian noise to
  the wheel speeds; scaling it with distance makes it independent of the step size
  and zero at rest). Encoders see the wheel,
  the pose follows the ground, so slip is invisible to odometry, as on a real robot;
- a command timeout: no command for ``command_timeout`` seconds -> the wheels are
  commanded to stop (what a real motor driver's watchdog does).

Motion is integrated with the core's CIR step (:func:`integration.compose` on the
increments given by :func:`kinematics.body_increment`), which is exact for a
constant pair of wheel rates, so with an instant motor the true pose is exact.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from diffdrive_odom.core.errors import ConfigError, require_finite_min
from diffdrive_odom.core.geometry.integration import Pose2D, compose
from diffdrive_odom.core.geometry.kinematics import Geometry, body_increment

TWO_PI = 2.0 * math.pi
Array = npt.NDArray[np.float64]


class SimConfigError(ConfigError):
    """A simulator setting that cannot work (names the field)."""


@dataclass(frozen=True)
class SlipEvent:
    """A scripted slip: one side's wheels spin ``rate`` rad/s more than they roll.

    From ``start`` for ``duration`` seconds of simulated time the encoders of ``side``
    ("left" or "right") count the extra turn; the ground (the true pose) does not see
    it: a wheel spinning on a smooth patch.
    """

    side: str
    start: float
    duration: float
    rate: float

    def extra(self, t0: float, t1: float) -> float:
        """Extra joint angle [rad] over simulated ``[t0, t1]`` seconds."""
        a, b = max(t0, self.start), min(t1, self.start + self.duration)
        return self.rate * (b - a) if b > a else 0.0


@dataclass(frozen=True)
class SimConfig:
    """The simulated robot's physics and sensors."""

    geometry: Geometry
    wheels_per_side: int = 1
    motor_time_constant: float = 0.0  # s; 0 = wheels follow commands instantly
    ticks_per_revolution: float = 0.0  # 0 = ideal encoder (no quantization)
    counter_bits: int = 0  # 0 = counter never wraps
    initial_count: float = 0.0  # counter value at the start (put the wrap close)
    slip_stddev: float = 0.0  # m: std of one side's slip after 1 m rolled
    command_timeout: float = 0.5  # s without a command -> stop; 0 = never
    substeps: int = 1  # motion steps per advance() call (only matters with a motor lag)
    seed: int = 0
    slip_events: tuple[SlipEvent, ...] = ()
    gyro_bias: float = 0.0  # rad/s added to the simulated gyro's yaw rate
    gyro_noise_density: float = 0.0  # rad/s/sqrt(Hz) of its white noise
    # The gyro reads this times the true yaw rate (1: exact). Its error maps one for one
    # into the ratios the gyro estimates online (online_geometry), unless a reference
    # measures it (online_scale).
    gyro_scale: float = 1.0

    def __post_init__(self) -> None:
        if not isinstance(self.wheels_per_side, int) or self.wheels_per_side < 1:
            raise SimConfigError("wheels_per_side", f"must be >= 1, got {self.wheels_per_side!r}")
        for name in ("motor_time_constant", "slip_stddev", "command_timeout"):
            require_finite_min(SimConfigError, name, getattr(self, name))
        tpr = self.ticks_per_revolution
        if not (math.isfinite(tpr) and tpr >= 0.0):
            raise SimConfigError("ticks_per_revolution", f"must be 0 or > 0, got {tpr!r}")
        if not isinstance(self.counter_bits, int) or not 0 <= self.counter_bits <= 64:
            raise SimConfigError(
                "encoder_counter_bits", f"must be 0 (no wrap) to 64, got {self.counter_bits!r}")
        if self.counter_bits > 0 and tpr == 0.0:
            raise SimConfigError(
                "encoder_counter_bits", "a wrapping counter needs ticks_per_revolution > 0")
        if not math.isfinite(self.initial_count):
            raise SimConfigError("encoder_initial_count", "must be finite")
        if not isinstance(self.substeps, int) or self.substeps < 1:
            raise SimConfigError("substeps", f"must be >= 1, got {self.substeps!r}")
        for e in self.slip_events:
            if e.side not in ("left", "right") or not (
                    math.isfinite(e.start) and e.start >= 0.0 and math.isfinite(e.duration)
                    and e.duration > 0.0 and math.isfinite(e.rate)):
                raise SimConfigError("slip_events", f"cannot use {e!r}: side left or right, "
                                     "start >= 0, duration > 0, a finite rate")
        if not math.isfinite(self.gyro_bias):
            raise SimConfigError("sim_gyro_bias", "must be finite")
        if not (math.isfinite(self.gyro_noise_density) and self.gyro_noise_density >= 0.0):
            raise SimConfigError("sim_gyro_noise_density", "must be finite and >= 0")
        if not (math.isfinite(self.gyro_scale) and self.gyro_scale > 0.0):
            raise SimConfigError("sim_gyro_scale", "must be finite and > 0")

    @property
    def joints(self) -> int:
        """Number of wheel joints (left ones first, then right)."""
        return 2 * self.wheels_per_side


@dataclass(frozen=True)
class Twist2D:
    """Body velocity: ``linear`` m/s along x, ``angular`` rad/s about z."""

    linear: float = 0.0
    angular: float = 0.0


@dataclass
class _Joints:
    """The joints' command, rates and angles as Python floats, while :meth:`advance` runs."""

    target: list[float]
    rate: list[float]
    angle: list[float]


@dataclass
class _State:
    time_ns: int = 0
    pose: Pose2D = field(default_factory=Pose2D)
    twist: Twist2D = field(default_factory=Twist2D)
    distance: float = 0.0  # path length of the axle centre on the ground [m]
    yaw: float = 0.0  # heading turned since the start, not wrapped [rad]
    last_command_ns: int | None = None


class DiffDriveSim:
    """The simulated base. Feed :meth:`command`, call :meth:`advance`, read the outputs.

    Commands and readings are per joint in the joint's own convention (the same
    arrays a ros2_control hardware interface takes and gives), left wheels first.
    """

    def __init__(self, config: SimConfig) -> None:
        self.config = config
        self.rng = np.random.default_rng(config.seed)
        n = config.joints
        self._command: Array = np.zeros(n)
        self._rate: Array = np.zeros(n)  # joint rates now [rad/s]
        self._angle: Array = np.zeros(n)  # true joint angles [rad], continuous
        self._state = _State()
        # The gyro's own stream, so turning it on does not change the slip noise's.
        self._gyro_rng = np.random.default_rng([config.seed, 1])
        self._gyro_read = (0, 0.0)  # (time, yaw) at the gyro's previous read

    def reconfigure(self, config: SimConfig) -> None:
        """New physics/sensors from now on; pose, wheel angles and rates carry on."""
        if config.joints != self.config.joints:
            raise ValueError("the number of wheels cannot change at runtime")
        if config.seed != self.config.seed:
            self.rng = np.random.default_rng(config.seed)
        self.config = config

    # -- inputs -------------------------------------------------------------------

    def command(self, rates: Sequence[float], now_ns: int | None = None) -> None:
        """Set new joint rate targets [rad/s] (left..., right...); restarts the timeout."""
        if len(rates) != self.config.joints:
            raise ValueError(f"expected {self.config.joints} wheel rates, got {len(rates)}")
        values = np.asarray(rates, dtype=np.float64)
        if not np.all(np.isfinite(values)):
            raise ValueError("wheel rate command is NaN or infinite")
        self._command = values
        self._state.last_command_ns = self._state.time_ns if now_ns is None else now_ns

    def stop(self) -> None:
        """Command zero rates (the motors still decelerate with their time constant)."""
        self._command = np.zeros(self.config.joints)

    # -- physics ------------------------------------------------------------------

    def advance(self, dt_ns: int) -> None:
        """Move the simulation ``dt_ns`` nanoseconds forward.

        The joints are Python floats inside (a few per robot: numpy's per-call cost was
        most of the sim's time at every substep), the same arithmetic element by element.
        """
        if dt_ns <= 0:
            return
        k = self.config.substeps
        joints = _Joints(self._command.tolist(), self._rate.tolist(), self._angle.tolist())
        for i in range(k):
            sub_ns = dt_ns * (i + 1) // k - dt_ns * i // k
            self._check_timeout(joints)
            self._step(joints, sub_ns * 1e-9)
            self._state.time_ns += sub_ns
        self._rate = np.array(joints.rate, dtype=np.float64)
        self._angle = np.array(joints.angle, dtype=np.float64)

    def _check_timeout(self, joints: _Joints) -> None:
        timeout = self.config.command_timeout
        last = self._state.last_command_ns
        expired = last is None or self._state.time_ns - last >= timeout * 1e9
        if timeout > 0.0 and expired and any(t != 0.0 for t in joints.target):
            self.stop()
            joints.target = [0.0] * len(joints.target)

    def _step(self, joints: _Joints, dt: float) -> None:
        cfg = self.config
        tau = cfg.motor_time_constant
        target, rate = joints.target, joints.rate
        if tau > 0.0:
            decay = math.exp(-dt / tau)
            lag = tau * (1.0 - decay)
            # Exact solution of tau * rate' = target - rate with target held over dt.
            d_angle = [t * dt + (r - t) * lag for t, r in zip(target, rate, strict=True)]
            joints.rate = [t + (r - t) * decay for t, r in zip(target, rate, strict=True)]
        else:
            d_angle = [t * dt for t in target]
            joints.rate = list(target)
        angle = joints.angle = [a + d for a, d in zip(joints.angle, d_angle, strict=True)]
        n = cfg.wheels_per_side
        if cfg.slip_events:  # the encoders see the spin, the ground does not
            t0 = self._state.time_ns * 1e-9
            for e in cfg.slip_events:
                extra = e.extra(t0, t0 + dt)
                if extra:
                    first = 0 if e.side == "left" else n
                    sign = (cfg.geometry.left_wheel_sign if e.side == "left"
                            else cfg.geometry.right_wheel_sign)
                    for j in range(first, first + n):
                        angle[j] += sign * extra
        d_left = sum(d_angle[:n]) / n
        d_right = sum(d_angle[n:]) / n
        if cfg.slip_stddev > 0.0:
            d_left, d_right = self._slip(d_left, d_right)
        ds, dtheta = body_increment(cfg.geometry, d_left, d_right)
        st = self._state
        st.pose = compose(st.pose, ds, dtheta)
        st.distance += abs(ds)
        st.yaw += dtheta
        if dt > 0.0:
            st.twist = Twist2D(ds / dt, dtheta / dt)

    def _slip(self, d_left: float, d_right: float) -> tuple[float, float]:
        """Ground angle increments: each side's arc plus N(0, sigma^2 * |arc|) metres."""
        g = self.config.geometry
        sigma = self.config.slip_stddev
        # Python floats: numpy's scalars would carry into the pose, the gyro and every
        # consumer's arithmetic (several times slower, the same values)
        z0, z1 = (float(z) for z in self.rng.standard_normal(2))
        left = d_left + z0 * sigma * math.sqrt(abs(d_left) * g.left_radius) / g.left_radius
        right = d_right + z1 * sigma * math.sqrt(abs(d_right) * g.right_radius) / g.right_radius
        return left, right

    # -- outputs ------------------------------------------------------------------

    def gyro(self, sample_rate: float) -> float:
        """A gyro's yaw rate [rad/s]: scale x the true mean since its last read, bias, noise.

        The mean over the sample's period, as an integrating (or anti-aliased) gyro
        gives it, so its samples add up to the turn the ground truth made: the rate of
        the last physics substep alone would carry that substep's slip noise
        (``slip_stddev``), which grows as one over the root of the substep's length,
        many times the gyro's own noise, and which standing still never shows. With no
        time passed since the last read: the last substep's rate. The noise of one
        sample read at ``sample_rate`` Hz is ``density * sqrt(rate)`` (a rate noise
        density integrated over the sample's bandwidth).
        """
        cfg = self.config
        st = self._state
        t_read, yaw_read = self._gyro_read
        self._gyro_read = (st.time_ns, st.yaw)
        rate = ((st.yaw - yaw_read) / ((st.time_ns - t_read) * 1e-9)
                if st.time_ns > t_read else st.twist.angular)
        noise = 0.0
        if cfg.gyro_noise_density > 0.0:
            sigma = cfg.gyro_noise_density * math.sqrt(sample_rate)
            noise = sigma * float(self._gyro_rng.standard_normal())
        return cfg.gyro_scale * rate + cfg.gyro_bias + noise

    @property
    def time_ns(self) -> int:
        """Simulated time since the start [ns]."""
        return self._state.time_ns

    @property
    def pose(self) -> Pose2D:
        """True pose of the robot in the world frame (starts at the origin)."""
        return self._state.pose

    @property
    def twist(self) -> Twist2D:
        """True body velocity over the last step."""
        return self._state.twist

    @property
    def last_command_ns(self) -> int | None:
        """Simulated time of the last wheel command (None: never commanded)."""
        return self._state.last_command_ns

    @property
    def distance(self) -> float:
        """Path length driven on the ground [m]."""
        return self._state.distance

    @property
    def joint_angles(self) -> Array:
        """True continuous joint angles [rad] (what an ideal encoder would read)."""
        return self._angle.copy()

    @property
    def joint_rates(self) -> Array:
        """Current joint rates [rad/s]."""
        return self._rate.copy()

    def encoder_counts(self) -> Array:
        """Counter values: whole ticks since the start plus the initial count, wrapped.

        A real counter is an integer register: it truncates (floor) towards the
        previous edge and wraps modulo ``2**counter_bits`` (reported unsigned).
        """
        cfg = self.config
        if cfg.ticks_per_revolution <= 0.0:
            raise ValueError("encoder_counts needs ticks_per_revolution > 0")
        counts = np.floor(cfg.initial_count + self._angle * (cfg.ticks_per_revolution / TWO_PI))
        if cfg.counter_bits > 0:
            counts = np.mod(counts, float(2**cfg.counter_bits))
        return counts

    def encoder_radians(self) -> Array:
        """Joint angles as a quantizing encoder reports them in radians (no wrap)."""
        cfg = self.config
        if cfg.ticks_per_revolution <= 0.0:
            return self.joint_angles
        scale = cfg.ticks_per_revolution / TWO_PI
        return np.floor(self._angle * scale) / scale
