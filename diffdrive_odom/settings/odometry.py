"""The odometry node's parameters and their validation (no rclpy import).

The same settings drive the node, ``replay``, ``calibrate`` and the demo, so a bag
replayed offline is processed exactly as the node would have processed it live.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from diffdrive_odom.core.errors import require_finite_min
from diffdrive_odom.core.estimation.config import OdometrySettings
from diffdrive_odom.core.estimation.gyro.config import GyroConfig
from diffdrive_odom.core.estimation.online.online_geometry import OnlineConfig
from diffdrive_odom.core.estimation.online.online_scale import ReferenceConfig
from diffdrive_odom.core.estimation.open_loop import (
    DEFAULT_OPEN_LOOP_NOISE,
    OPEN_LOOP_SOURCES,
    OpenLoopConfig,
)
from diffdrive_odom.core.estimation.stamps import StampSource
from diffdrive_odom.core.estimation.wheels.config import EstimatorConfig
from diffdrive_odom.core.geometry.mount import Mount
from diffdrive_odom.core.uncertainty.noise import (
    DEFAULT_K,
    DEFAULT_RADIUS_STDDEV_RATIO,
    DEFAULT_ROTATION_K,
    DEFAULT_SEPARATION_STDDEV_RATIO,
    NoiseModel,
)
from diffdrive_odom.settings.errors import ParameterError, as_parameter_error, one_of
from diffdrive_odom.settings.geometry import (
    CMD_VEL_TIMEOUT_PARAM,
    GEOMETRY_PARAMS,
    LOCKSTEP_PARAM,
    STAMPED_CMD_VEL_PARAM,
    build_encoders,
    build_geometry,
)
from diffdrive_odom.settings.params import (
    AT_LEAST_ONE,
    INF,
    NON_NEGATIVE,
    POSITIVE,
    POSITIVE_OR_INF,
    ParamSpec,
    ParamValue,
    Range,
    coerce_all,
    from_fields,
)

_G = GyroConfig()
_E = EstimatorConfig()  # the estimator's defaults, declared there once
GYRO_PARAMS: tuple[ParamSpec, ...] = (
    ParamSpec("use_imu", "bool", False,
              "Gyrodometry: subscribe sensor_msgs/Imu on 'imu'; the wheels give distance, "
              "their heading is checked against the gyro's (slip) and fused with it.",
              read_only=True),
    ParamSpec("imu_orientation", "double_array", list(_G.orientation),
              "Roll, pitch, yaw [rad] of the IMU's frame in the base frame (the mounting; "
              "upside down: [3.14159265, 0, 0])."),
    ParamSpec("gyro_noise_density", "double", _G.noise_density,
              "Gyro white noise [rad/s/sqrt(Hz)] (its datasheet's rate noise density); "
              "the heading variance grows by its square times the time.", range=POSITIVE),
    ParamSpec("gyro_bias", "double", _G.bias,
              "Start value of the yaw-rate bias estimate [rad/s] (updated while standing "
              "still).", range=Range(-INF, INF, "finite")),
    ParamSpec("gyro_bias_stddev", "double", _G.bias_stddev,
              "1-sigma uncertainty of gyro_bias [rad/s] at the start.", range=NON_NEGATIVE),
    ParamSpec("gyro_bias_random_walk", "double", _G.bias_random_walk,
              "How fast the bias wanders [rad/s/sqrt(s)]: its variance grows by the square "
              "per second.", range=NON_NEGATIVE),
    ParamSpec("gyro_max_rate", "double", _G.max_rate,
              "An angular rate at or above this [rad/s] is saturated: the sample is "
              "refused (2000 deg/s by default).", range=POSITIVE),
    ParamSpec("imu_timeout", "double", _G.timeout,
              "No IMU sample for this long [s] over a wheel step: wheels only (WARN) "
              "until samples come again.", range=POSITIVE),
    ParamSpec("slip_threshold_sigmas", "double", _G.slip_sigmas,
              "Wheel and gyro heading changes differing by more than this many combined "
              "sigmas: a slip (the gyro's heading is used).", range=POSITIVE),
    ParamSpec("zero_velocity_speed", "double", _G.zero_velocity_speed,
              "Both wheels slower than this [m/s] over a step: standing still, the gyro's "
              "mean rate updates its bias.", range=NON_NEGATIVE),
    ParamSpec("slip_distance_from_other_wheel", "bool", _G.slip_distance_from_other_wheel,
              "On a slip, take the distance from the wheel with the shorter arc and the "
              "gyro (the spinning wheel read more than it rolled)."),
    ParamSpec("slip_min_angle", "double", _G.slip_min_angle,
              "A slip event is a run of slipping steps whose wheels got the heading wrong "
              "by at least this much [rad] (0.5 deg); smaller ones are fused, not named.",
              range=NON_NEGATIVE),
    ParamSpec("imu_time_offset", "double", _G.time_offset,
              "How much later [s] the IMU's stamps are than the wheels' for the same motion "
              "(clocks only roughly aligned): subtracted from each IMU stamp. replay and "
              "/diagnostics print the lag measured from the two turns."),
    ParamSpec("imu_stamp_source", "string", "header",
              "header: each Imu sample at its header stamp (the measurement time); "
              "receive_time: at the time it arrived on this node's clock (an IMU stamping "
              "on its own device clock), as stamp_source does for the wheels."),
)

OPEN_LOOP_PARAMS: tuple[ParamSpec, ...] = (
    ParamSpec("open_loop", "bool", False,
              "Odometry from the commanded velocity, not the encoders (a robot without "
              "them, as diff_drive_controller's open_loop): joint_states is not read; "
              "each command on open_loop_source is held until the next or cmd_vel_timeout.",
              read_only=True),
    ParamSpec("open_loop_source", "string", OPEN_LOOP_SOURCES[0],
              "With open_loop: cmd_vel (the commands as cmd_vel_node takes them: Twist, or "
              "TwistStamped with enable_stamped_cmd_vel) or cmd_vel_out (cmd_vel_node's "
              "limited output, TwistStamped: publish_limited_velocity true).",
              read_only=True),
    ParamSpec("open_loop_noise", "double", DEFAULT_OPEN_LOOP_NOISE,
              "With open_loop: relative 1-sigma of each wheel's executed travel against the "
              "commanded one (and of the turn, through the separation); the pose covariance "
              "grows with distance squared.", range=NON_NEGATIVE),
)

_O = OnlineConfig()
_R = ReferenceConfig("/reference")
REFERENCE_PARAMS: tuple[ParamSpec, ...] = (
    ParamSpec("online_calibration_reference_topic", "string", "",
              "A reference pose for the online estimate's scale (the mean radius, the "
              "separation) and the gyro's scale factor: a lidar odometry, motion capture, "
              "AMCL; '' = none (the scale stays the configured one).", read_only=True),
    ParamSpec("online_calibration_reference_type", "string", _R.kind,
              "Its message type: odometry (nav_msgs/Odometry) or pose_stamped "
              "(geometry_msgs/PoseStamped).", read_only=True),
    ParamSpec("online_calibration_reference_position_stddev", "double", _R.position_stddev,
              "1-sigma of each reference position [m] (its frame is never aligned with "
              "odom: only distances are compared).", read_only=True, range=POSITIVE),
    ParamSpec("online_calibration_reference_heading_stddev", "double", _R.heading_stddev,
              "1-sigma of each reference heading [rad].", read_only=True, range=POSITIVE),
    ParamSpec("online_calibration_reference_offset", "double_array", [0.0, 0.0, 0.0],
              "Where the reference is mounted: the pose of its frame in the base frame, "
              "x, y [m], yaw [rad] (a marker body, camera or antenna off the axle or "
              "turned); each pose is moved onto the base frame by it.", read_only=True),
    ParamSpec("online_calibration_reference_frame", "string", "",
              "The reference's frame: its mount read from /tf_static (base_frame_id -> "
              "this frame) instead of online_calibration_reference_offset; reference "
              "poses wait for it. '' = the offset.", read_only=True),
)
ONLINE_MODES = ("disabled", "monitor", "apply")
ONLINE_PARAMS: tuple[ParamSpec, ...] = (
    ParamSpec("online_calibration", "string", "monitor",
              "monitor: estimate the wheel geometry from the gyro while driving (use_imu "
              "only), publish it on ~/geometry_estimate and /diagnostics, warn when the "
              "configured one leaves its 3-sigma region; apply: the same, and integrate "
              "with the estimate once determined and below online_calibration_apply_sigma "
              "(the parameters stay as set); disabled: not at all."),
    ParamSpec("online_calibration_min_turn", "double", _O.min_turn,
              "Radians to turn each way before the online estimate is determined (and "
              "the configured geometry tested against it).", range=NON_NEGATIVE),
    ParamSpec("online_calibration_random_walk", "double", _O.random_walk,
              "How fast the wheel geometry may change [1/sqrt(s)], relative: each ratio's "
              "variance grows by its square times the ratio squared per second.",
              range=NON_NEGATIVE),
    ParamSpec("online_calibration_apply_sigma", "double", _O.apply_sigma,
              "With apply: the relative 1-sigma both wheel ratios (radius / separation) "
              "must be below before the estimate is integrated with (0.002 = 0.2 %).",
              range=POSITIVE),
    *REFERENCE_PARAMS,
)

ODOMETRY_OWN_PARAMS: tuple[ParamSpec, ...] = (
    ParamSpec("odom_frame_id", "string", "odom", "Frame of the published pose."),
    ParamSpec("base_frame_id", "string", "base_link", "Child frame (the robot)."),
    ParamSpec("tf_frame_prefix_enable", "bool", True,
              "Prefix both frame ids with tf_frame_prefix (multi-robot)."),
    ParamSpec("tf_frame_prefix", "string", "",
              "Frame prefix; empty = the node's namespace (as diff_drive_controller)."),
    ParamSpec("enable_odom_tf", "bool", True, "Publish odom -> base_link on /tf."),
    ParamSpec("stamp_source", "string", "header",
              "header: stamp odometry with each JointState's header stamp (the measurement "
              "time); receive_time: with the time it arrived on this node's clock, as "
              "diff_drive_controller (a driver whose clock is not synced)."),
    ParamSpec("publish_rate", "double", 0.0,
              "Odometry publish rate [Hz], kept on average in stamp time: min(this, the "
              "reading rate), real readings only; 0 = publish every reading.",
              range=NON_NEGATIVE),
    ParamSpec("covariance_model", "string", "propagated",
              "propagated: covariance from wheel noise through each step (grows with "
              "distance); static: the two diagonals below, as diff_drive_controller."),
    *(ParamSpec(f"wheel_noise_k_{side}", "double", DEFAULT_K,
                f"{side.capitalize()} wheel-travel noise [m]: a step's arc d has variance "
                "k * abs(d) (propagated).", range=NON_NEGATIVE)
      for side in ("left", "right")),
    ParamSpec("rotation_noise_k", "double", DEFAULT_ROTATION_K,
              "Rotation noise [rad]: a step's heading change dtheta has its own variance "
              "k * abs(dtheta), slip while turning (propagated, wheels only); calibrate "
              "prints a fitted value.", range=NON_NEGATIVE),
    ParamSpec("wheel_radius_stddev_ratio", "double", DEFAULT_RADIUS_STDDEV_RATIO,
              "Relative 1-sigma uncertainty of each effective wheel radius (propagated: "
              "its pose term grows with distance squared); calibrate prints it.",
              range=NON_NEGATIVE),
    ParamSpec("wheel_separation_stddev_ratio", "double", DEFAULT_SEPARATION_STDDEV_RATIO,
              "Relative 1-sigma uncertainty of the effective wheel separation (propagated); "
              "calibrate prints it.", range=NON_NEGATIVE),
    ParamSpec("pose_covariance_diagonal", "double_array",
              [0.001, 0.001, 1.0e6, 1.0e6, 1.0e6, 0.01],
              "Diagonal of the pose covariance (x, y, z, roll, pitch, yaw); "
              "covariance_model static only."),
    ParamSpec("twist_covariance_diagonal", "double_array",
              [0.001, 1.0e-6, 1.0e6, 1.0e6, 1.0e6, 0.01],
              "Diagonal of the twist covariance (vx, vy, vz, wx, wy, wz); "
              "covariance_model static only."),
    ParamSpec("velocity_rolling_window_size", "integer", _E.velocity_rolling_window_size,
              "Readings in the rolling mean of the twist (never applied to the pose).",
              range=AT_LEAST_ONE),
    ParamSpec("max_wheel_speed", "double", _E.max_wheel_speed,
              "Fastest plausible joint speed [rad/s], over the time since the counts last "
              "changed; faster steps are skipped (.inf = no speed check; a wheel rolling "
              "over 1 km in one step still is).",
              range=POSITIVE_OR_INF),
    ParamSpec("time_jump_threshold", "double", _E.time_jump_threshold,
              "A stamp this far [s] behind the last restarts odometry (bag loop).",
              range=NON_NEGATIVE),
    ParamSpec("max_reading_gap", "double", _E.max_reading_gap,
              "A reading this long [s] after the last usable one is held; if the next "
              "continues from it, the gap's motion is integrated from the counts as one "
              "arc, unless they show a driver restart (then it is the new reference), else "
              "it is dropped (future_stamp); also the longest interval a step is judged "
              "over; .inf = off.",
              range=POSITIVE_OR_INF),
    ParamSpec("max_wheel_acceleration", "double", _E.max_wheel_acceleration,
              "Fastest plausible change of a joint's speed [rad/s^2]: a wheel's mean speed "
              "over a gap beyond what it showed before and after allows is a driver "
              "restart, not motion (.inf = no bound).",
              range=POSITIVE_OR_INF),
    *GYRO_PARAMS,
    *OPEN_LOOP_PARAMS,
    *ONLINE_PARAMS,
)


# Everything the node declares: the shared geometry rows, then its own, then the command
# rows it shares with cmd_vel_node (open_loop reads the commands as that node does).
ODOMETRY_PARAMS: tuple[ParamSpec, ...] = (
    GEOMETRY_PARAMS + ODOMETRY_OWN_PARAMS
    + (STAMPED_CMD_VEL_PARAM, CMD_VEL_TIMEOUT_PARAM, LOCKSTEP_PARAM))


COVARIANCE_MODELS = ("propagated", "static")


def _stamp_source(value: str, name: str = "stamp_source") -> StampSource:
    """The ``stamp_source`` (or ``name``) value, or ParameterError naming the choices."""
    return StampSource(one_of(name, value, StampSource))


def _noise_model(v: Mapping[str, Any]) -> NoiseModel | None:
    """The wheel noise model, or None for ``covariance_model: static``."""
    model = one_of("covariance_model", v["covariance_model"], COVARIANCE_MODELS)
    with as_parameter_error():
        noise = NoiseModel(v["wheel_noise_k_left"], v["wheel_noise_k_right"],
                           v["wheel_radius_stddev_ratio"], v["wheel_separation_stddev_ratio"],
                           v["rotation_noise_k"])
    return noise if model == "propagated" else None




def _covariance(name: str, diag: tuple[float, ...]) -> tuple[float, ...]:
    if len(diag) != 6:
        raise ParameterError(name, f"needs 6 values, got {len(diag)}")
    if not all(math.isfinite(d) and d >= 0.0 for d in diag):
        raise ParameterError(name, "values must be finite and >= 0")
    return diag


def frame_prefix(enable: bool, prefix: str, namespace: str) -> str:
    """diff_drive_controller's rule: empty prefix = namespace; a '/' is appended if missing."""
    if not enable:
        return ""
    p = prefix if prefix else namespace.strip("/")
    p = p.strip("/")
    return f"{p}/" if p else ""


def odometry_settings(values: Mapping[str, ParamValue], namespace: str = "/") -> OdometrySettings:
    """Validate every odometry parameter; the first bad one raises ParameterError."""
    v = coerce_all(ODOMETRY_PARAMS, values)
    rate = v["publish_rate"]
    require_finite_min(ParameterError, "publish_rate", rate)
    prefix = frame_prefix(v["tf_frame_prefix_enable"], v["tf_frame_prefix"], namespace)
    for name in ("odom_frame_id", "base_frame_id"):
        if not v[name].strip("/"):
            raise ParameterError(name, "must not be empty")
    odom_frame = prefix + v["odom_frame_id"].lstrip("/")
    base_frame = prefix + v["base_frame_id"].lstrip("/")
    if odom_frame == base_frame:
        raise ParameterError("base_frame_id", "must differ from odom_frame_id")
    geometry, encoders = build_geometry(v), build_encoders(v)
    estimator = from_fields(EstimatorConfig, v)
    pose_diag = _covariance("pose_covariance_diagonal", v["pose_covariance_diagonal"])
    twist_diag = _covariance("twist_covariance_diagonal", v["twist_covariance_diagonal"])
    noise = _noise_model(v)
    return OdometrySettings(
        geometry=geometry,
        encoders=encoders,
        estimator=estimator,
        odom_frame_id=odom_frame,
        base_frame_id=base_frame,
        enable_odom_tf=v["enable_odom_tf"],
        publish_rate=rate,
        pose_covariance_diagonal=pose_diag,
        twist_covariance_diagonal=twist_diag,
        noise=noise,
        stamp_source=_stamp_source(v["stamp_source"]),
        gyro=_gyro_config(v),
        open_loop=_open_loop_config(v, pose_diag, twist_diag),
        online=_online_config(v),
    )


def _open_loop_config(v: Mapping[str, Any], pose_diag: tuple[float, ...],
                      twist_diag: tuple[float, ...]) -> OpenLoopConfig | None:
    """The open-loop settings with ``open_loop`` true (checked even when false), else None."""
    static = (pose_diag, twist_diag) if v["covariance_model"] == "static" else None
    with as_parameter_error():
        cfg = OpenLoopConfig(source=v["open_loop_source"], timeout=v["cmd_vel_timeout"],
                             noise=v["open_loop_noise"],
                             stamped_cmd_vel=v["enable_stamped_cmd_vel"], static=static)
    if v["open_loop"] and v["use_imu"]:
        raise ParameterError("use_imu", "cannot be true with open_loop: open loop integrates "
                             "commands, not wheel readings, so there is no wheel heading for "
                             "the gyro to aid; set one of them false")
    return cfg if v["open_loop"] else None


def _online_config(v: Mapping[str, Any]) -> OnlineConfig | None:
    """``online_calibration``'s settings with ``monitor`` or ``apply``, None with ``disabled``."""
    mode = one_of("online_calibration", v["online_calibration"], ONLINE_MODES)
    with as_parameter_error():
        cfg = OnlineConfig(min_turn=v["online_calibration_min_turn"],
                           random_walk=v["online_calibration_random_walk"],
                           apply=mode == "apply",
                           apply_sigma=v["online_calibration_apply_sigma"],
                           reference=_reference_config(v))
    return None if mode == "disabled" else cfg


APPLY_NEEDS_IMU = ("online_calibration is apply but use_imu is false: nothing is estimated "
                   "or applied (the estimate needs the gyro); set use_imu: true, or "
                   "online_calibration: monitor or disabled")


def online_warning(settings: OdometrySettings) -> str:
    """The start's warning about online calibration ('' for none).

    ``monitor`` is the default and means "while the gyro is on": without ``use_imu``
    there is nothing to monitor, which is no news to log at every start. ``apply``
    asks for odometry integrated with an estimate that cannot exist without the gyro:
    that is said.
    """
    online = settings.online
    return APPLY_NEEDS_IMU if settings.gyro is None and online and online.apply else ""


def _reference_config(v: Mapping[str, Any]) -> ReferenceConfig | None:
    """The reference pose's settings (checked even without a topic), None without one."""
    topic = v["online_calibration_reference_topic"]
    offset = v["online_calibration_reference_offset"]
    if len(offset) != 3 or not all(math.isfinite(o) for o in offset):
        raise ParameterError("online_calibration_reference_offset",
                             f"needs 3 finite values (x, y [m], yaw [rad]), got {list(offset)}")
    cfg = ReferenceConfig(topic or "/none", v["online_calibration_reference_type"],
                          v["online_calibration_reference_position_stddev"],
                          v["online_calibration_reference_heading_stddev"],
                          Mount(offset[0], offset[1], offset[2]),
                          v["online_calibration_reference_frame"].strip("/"))
    return cfg if topic else None


def _gyro_config(v: Mapping[str, Any]) -> GyroConfig | None:
    """The gyro's settings with ``use_imu`` true (checked even when false), else None."""
    orientation = v["imu_orientation"]
    if len(orientation) != 3:
        raise ParameterError("imu_orientation",
                             f"needs 3 values (roll, pitch, yaw), got {len(orientation)}")
    with as_parameter_error():
        cfg = GyroConfig(
            orientation=(orientation[0], orientation[1], orientation[2]),
            noise_density=v["gyro_noise_density"], bias=v["gyro_bias"],
            bias_stddev=v["gyro_bias_stddev"], bias_random_walk=v["gyro_bias_random_walk"],
            max_rate=v["gyro_max_rate"], timeout=v["imu_timeout"],
            slip_sigmas=v["slip_threshold_sigmas"],
            zero_velocity_speed=v["zero_velocity_speed"],
            slip_distance_from_other_wheel=v["slip_distance_from_other_wheel"],
            slip_min_angle=v["slip_min_angle"],
            stamp_source=_stamp_source(v["imu_stamp_source"], "imu_stamp_source"),
            time_offset=v["imu_time_offset"])
    return cfg if v["use_imu"] else None
