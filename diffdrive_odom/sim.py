"""A simulated differential-drive base: wheel commands in, encoder readings and true pose out.

Pure Python (no rclpy), so its physics is tested against closed forms in
microseconds and reused by ``sim_node``, tests and benchmarks. What it models, each
switchable, all random draws from one seeded ``numpy.random.Generator``:

- the robot's TRUE geometry (a :class:`~diffdrive_odom.kinematics.Geometry`), which
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
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from diffdrive_odom.encoders import EncoderConfig
from diffdrive_odom.errors import ConfigError, as_parameter_error
from diffdrive_odom.integration import Pose2D, compose
from diffdrive_odom.kinematics import Geometry, body_increment
from diffdrive_odom.params import ParameterError, ParamSpec, ParamValue, coerce_all

TWO_PI = 2.0 * math.pi
Array = npt.NDArray[np.float64]


class SimConfigError(ConfigError):
    """A simulator setting that cannot work (names the field)."""


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

    def __post_init__(self) -> None:
        if not isinstance(self.wheels_per_side, int) or self.wheels_per_side < 1:
            raise SimConfigError("wheels_per_side", f"must be >= 1, got {self.wheels_per_side!r}")
        for name in ("motor_time_constant", "slip_stddev", "command_timeout"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise SimConfigError(name, f"must be finite and >= 0, got {value!r}")
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
class _State:
    time_ns: int = 0
    pose: Pose2D = field(default_factory=Pose2D)
    twist: Twist2D = field(default_factory=Twist2D)
    distance: float = 0.0  # path length of the axle centre on the ground [m]
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
        """Move the simulation ``dt_ns`` nanoseconds forward."""
        if dt_ns <= 0:
            return
        cfg = self.config
        k = cfg.substeps
        for i in range(k):
            sub_ns = dt_ns * (i + 1) // k - dt_ns * i // k
            self._check_timeout()
            self._step(sub_ns * 1e-9)
            self._state.time_ns += sub_ns

    def _check_timeout(self) -> None:
        timeout = self.config.command_timeout
        last = self._state.last_command_ns
        expired = last is None or self._state.time_ns - last >= timeout * 1e9
        if timeout > 0.0 and expired and np.any(self._command != 0.0):
            self.stop()

    def _step(self, dt: float) -> None:
        cfg = self.config
        tau = cfg.motor_time_constant
        target = self._command
        if tau > 0.0:
            decay = math.exp(-dt / tau)
            # Exact solution of tau * rate' = target - rate with target held over dt.
            d_angle = target * dt + (self._rate - target) * (tau * (1.0 - decay))
            self._rate = target + (self._rate - target) * decay
        else:
            d_angle = target * dt
            self._rate = target.copy()
        self._angle += d_angle
        n = cfg.wheels_per_side
        d_left = float(np.mean(d_angle[:n]))
        d_right = float(np.mean(d_angle[n:]))
        if cfg.slip_stddev > 0.0:
            d_left, d_right = self._slip(d_left, d_right)
        ds, dtheta = body_increment(cfg.geometry, d_left, d_right)
        st = self._state
        st.pose = compose(st.pose, ds, dtheta)
        st.distance += abs(ds)
        if dt > 0.0:
            st.twist = Twist2D(ds / dt, dtheta / dt)

    def _slip(self, d_left: float, d_right: float) -> tuple[float, float]:
        """Ground angle increments: each side's arc plus N(0, sigma^2 * |arc|) metres."""
        g = self.config.geometry
        sigma = self.config.slip_stddev
        z = self.rng.standard_normal(2)
        left = d_left + z[0] * sigma * math.sqrt(abs(d_left) * g.left_radius) / g.left_radius
        right = d_right + z[1] * sigma * math.sqrt(abs(d_right) * g.right_radius) / g.right_radius
        return left, right

    # -- outputs ------------------------------------------------------------------

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


# --- parameters of sim_node (pure, so the README table and tests read them too) ------

RADIANS = "radians"
TICKS = "ticks"
AUTO = "auto"
JOINT_STATE_UNITS = (AUTO, RADIANS, TICKS)
# The cmd_vel node's output formats (cmd_vel_settings.WHEEL_COMMAND_FORMATS), repeated
# here so this module stays free of the node's settings.
FLOAT64_ARRAY = "float64_array"
JOINT_STATE = "joint_state"
TICKS_PER_SECOND = "ticks_per_second"
WHEEL_COMMAND_FORMATS = (FLOAT64_ARRAY, JOINT_STATE, TICKS_PER_SECOND)

SIM_PARAMS: tuple[ParamSpec, ...] = (
    ParamSpec("wheel_radius", "double", 0.033,
              "Nominal wheel radius [m] (the robot's drawing; shared with the other nodes)."),
    ParamSpec("wheel_separation", "double", 0.160,
              "Nominal wheel separation [m] (shared with the other nodes)."),
    ParamSpec("true_left_wheel_radius", "double", 0.0,
              "TRUE left wheel radius [m] the base moves with; 0 = wheel_radius."),
    ParamSpec("true_right_wheel_radius", "double", 0.0,
              "TRUE right wheel radius [m]; 0 = wheel_radius."),
    ParamSpec("true_wheel_separation", "double", 0.0,
              "TRUE wheel separation [m]; 0 = wheel_separation."),
    ParamSpec("left_wheel_sign", "integer", 1,
              "Hardware joint sign: -1 = the left joint counts (and turns) backwards "
              "when the robot drives forward."),
    ParamSpec("right_wheel_sign", "integer", 1,
              "Hardware joint sign of the right joint (-1 = flipped)."),
    ParamSpec("left_wheel_names", "string_array", ["left_wheel_joint"],
              "Joint names of the left wheels, in wheel command order.", read_only=True),
    ParamSpec("right_wheel_names", "string_array", ["right_wheel_joint"],
              "Joint names of the right wheels (same count as left).", read_only=True),
    ParamSpec("ticks_per_revolution", "double", 0.0,
              "Encoder counts per wheel turn; 0 = ideal encoder (no quantization)."),
    ParamSpec("encoder_counter_bits", "integer", 0,
              "Width of the wrapping encoder counter (e.g. 16); 0 = no wrap."),
    ParamSpec("encoder_initial_count", "double", 0.0,
              "Counter value at start (e.g. 65530 to cross a 16-bit wrap at once)."),
    ParamSpec("joint_state_units", "string", AUTO,
              "Position units on joint_states: ticks, radians, or auto (ticks when "
              "ticks_per_revolution > 0).", read_only=True),
    ParamSpec("motor_time_constant", "double", 0.0,
              "First-order motor response [s]; 0 = wheels follow commands at once."),
    ParamSpec("slip_stddev", "double", 0.0,
              "Wheel slip [m]: std of one side's ground-arc error after 1 m rolled "
              "(variance grows with distance; Carroll and Jha, sec. 2.3)."),
    ParamSpec("random_seed", "integer", 0,
              "Seed of the slip noise (same seed, same run).", read_only=True),
    ParamSpec("command_timeout", "double", 0.5,
              "No wheel command for this long [s, simulated] -> wheels stop; 0 = never."),
    ParamSpec("wheel_command_format", "string", FLOAT64_ARRAY,
              "Input on wheel_commands: float64_array (rad/s), joint_state (velocity by "
              "name, rad/s) or ticks_per_second (Float64MultiArray, counts/s).",
              read_only=True),
    ParamSpec("publish_rate", "double", 50.0,
              "joint_states and ground truth rate [Hz of simulated time].", read_only=True),
    ParamSpec("physics_substeps", "integer", 10,
              "Motion steps per published step (exactness with a motor lag)."),
    ParamSpec("publish_clock", "bool", False,
              "Own the time: publish /clock and run at real_time_factor (run the other "
              "nodes with use_sim_time:=true).", read_only=True),
    ParamSpec("real_time_factor", "double", 1.0,
              "Simulated seconds per wall second when publish_clock is true.", read_only=True),
    ParamSpec("world_frame_id", "string", "world", "Frame of ground_truth/odom."),
    ParamSpec("base_frame_id", "string", "base_link",
              "Child frame of ground_truth/odom (the robot)."),
)


@dataclass(frozen=True)
class SimSettings:
    """Validated settings of ``sim_node``."""

    config: SimConfig
    left_wheel_names: tuple[str, ...]
    right_wheel_names: tuple[str, ...]
    joint_state_units: str  # RADIANS or TICKS (AUTO resolved)
    wheel_command_format: str
    publish_rate: float
    publish_clock: bool
    real_time_factor: float
    world_frame_id: str
    base_frame_id: str

    @property
    def wheel_names(self) -> tuple[str, ...]:
        """Left joints then right joints: the order of commands and readings."""
        return self.left_wheel_names + self.right_wheel_names


def _true(nominal: float, value: float) -> float:
    return nominal if value == 0.0 else value


def sim_settings(values: Mapping[str, ParamValue]) -> SimSettings:
    """Validate every sim_node parameter; the first bad one raises ParameterError."""
    v = coerce_all(SIM_PARAMS, values)
    for name in ("wheel_radius", "wheel_separation"):
        if not (math.isfinite(v[name]) and v[name] > 0.0):
            raise ParameterError(name, f"must be a finite number > 0, got {v[name]!r}")
    for name in ("true_left_wheel_radius", "true_right_wheel_radius", "true_wheel_separation"):
        if not (math.isfinite(v[name]) and v[name] >= 0.0):
            raise ParameterError(name, f"must be 0 (= nominal) or > 0, got {v[name]!r}")
    r = v["wheel_radius"]
    with as_parameter_error():
        geometry = Geometry(
            wheel_radius=r,
            wheel_separation=_true(v["wheel_separation"], v["true_wheel_separation"]),
            left_wheel_radius_multiplier=_true(r, v["true_left_wheel_radius"]) / r,
            right_wheel_radius_multiplier=_true(r, v["true_right_wheel_radius"]) / r,
            left_wheel_sign=v["left_wheel_sign"],
            right_wheel_sign=v["right_wheel_sign"],
        )
        encoders = EncoderConfig(v["left_wheel_names"], v["right_wheel_names"],
                                 v["ticks_per_revolution"], v["encoder_counter_bits"])
    units = v["joint_state_units"]
    if units not in JOINT_STATE_UNITS:
        raise ParameterError("joint_state_units",
                             f"must be one of {', '.join(JOINT_STATE_UNITS)}, got {units!r}")
    tpr = encoders.ticks_per_revolution
    if units == AUTO:
        units = TICKS if tpr > 0.0 else RADIANS
    if units == TICKS and tpr <= 0.0:
        raise ParameterError("ticks_per_revolution", "must be > 0 to publish ticks")
    if units == RADIANS and encoders.counter_bits > 0:
        raise ParameterError("encoder_counter_bits",
                             "a wrapping counter needs joint_state_units ticks")
    fmt = v["wheel_command_format"]
    if fmt not in WHEEL_COMMAND_FORMATS:
        raise ParameterError("wheel_command_format",
                             f"must be one of {', '.join(WHEEL_COMMAND_FORMATS)}, got {fmt!r}")
    if fmt == TICKS_PER_SECOND and tpr <= 0.0:
        raise ParameterError("ticks_per_revolution",
                             f"must be > 0 when wheel_command_format is {TICKS_PER_SECOND}")
    rate = v["publish_rate"]
    if not (math.isfinite(rate) and 0.0 < rate <= 2000.0):
        raise ParameterError("publish_rate", f"must be > 0 and <= 2000 [Hz], got {rate!r}")
    rtf = v["real_time_factor"]
    if not (math.isfinite(rtf) and 0.0 < rtf <= 100.0):
        raise ParameterError("real_time_factor", f"must be > 0 and <= 100, got {rtf!r}")
    for name in ("world_frame_id", "base_frame_id"):
        if not v[name].strip("/"):
            raise ParameterError(name, "must not be empty")
    try:
        config = SimConfig(
            geometry=geometry,
            wheels_per_side=len(encoders.left_wheel_names),
            motor_time_constant=v["motor_time_constant"],
            ticks_per_revolution=tpr,
            counter_bits=encoders.counter_bits,
            initial_count=v["encoder_initial_count"],
            slip_stddev=v["slip_stddev"],
            command_timeout=v["command_timeout"],
            substeps=v["physics_substeps"],
            seed=v["random_seed"],
        )
    except SimConfigError as err:
        raise ParameterError(err.field if err.field != "substeps" else "physics_substeps",
                             err.reason) from err
    return SimSettings(
        config=config,
        left_wheel_names=encoders.left_wheel_names,
        right_wheel_names=encoders.right_wheel_names,
        joint_state_units=units,
        wheel_command_format=fmt,
        publish_rate=rate,
        publish_clock=v["publish_clock"],
        real_time_factor=rtf,
        world_frame_id=v["world_frame_id"],
        base_frame_id=v["base_frame_id"],
    )
