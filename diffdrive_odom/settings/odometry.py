"""The odometry node's parameters and their validation (no rclpy import).

The same settings drive the node, ``replay``, ``calibrate`` and the demo, so a bag
replayed offline is processed exactly as the node would have processed it live.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from diffdrive_odom.core.errors import as_parameter_error
from diffdrive_odom.core.estimator import EstimatorConfig
from diffdrive_odom.core.pipeline import OdometrySettings as OdometrySettings
from diffdrive_odom.core.stamps import StampSource
from diffdrive_odom.core.uncertainty import (
    DEFAULT_K,
    DEFAULT_RADIUS_STDDEV_RATIO,
    DEFAULT_SEPARATION_STDDEV_RATIO,
    NoiseModel,
)
from diffdrive_odom.settings.geometry import GEOMETRY_PARAMS, build_encoders, build_geometry
from diffdrive_odom.settings.params import (
    AT_LEAST_ONE,
    NON_NEGATIVE,
    POSITIVE_OR_INF,
    ParameterError,
    ParamSpec,
    ParamValue,
    coerce_all,
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
              "Max odometry publish rate [Hz]; 0 = publish every reading.",
              range=NON_NEGATIVE),
    ParamSpec("covariance_model", "string", "propagated",
              "propagated: covariance from wheel noise through each step (grows with "
              "distance); static: the two diagonals below, as diff_drive_controller."),
    ParamSpec("wheel_noise_k_left", "double", DEFAULT_K,
              "Left wheel-travel noise [m]: a step's arc d has variance k * abs(d) (propagated).",
              range=NON_NEGATIVE),
    ParamSpec("wheel_noise_k_right", "double", DEFAULT_K,
              "Right wheel-travel noise [m]: a step's arc d has variance k * abs(d) (propagated).",
              range=NON_NEGATIVE),
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
    ParamSpec("velocity_rolling_window_size", "integer", 1,
              "Readings in the rolling mean of the twist (never applied to the pose).",
              range=AT_LEAST_ONE),
    ParamSpec("max_wheel_speed", "double", 200.0,
              "Fastest plausible joint speed [rad/s]; faster steps are skipped "
              "(.inf = no speed check; a wheel rolling over 1 km in one step still is).",
              range=POSITIVE_OR_INF),
    ParamSpec("time_jump_threshold", "double", 1.0,
              "A stamp this far [s] behind the last restarts odometry (bag loop).",
              range=NON_NEGATIVE),
    ParamSpec("max_reading_gap", "double", 1.0,
              "A reading this long [s] after the last usable one is held; if the next "
              "continues from it, it is the new reference, no motion integrated (driver "
              "restart), else it is dropped (future_stamp); .inf = off.",
              range=POSITIVE_OR_INF),
)


# Everything the node declares: the shared geometry rows, then its own.
ODOMETRY_PARAMS: tuple[ParamSpec, ...] = GEOMETRY_PARAMS + ODOMETRY_OWN_PARAMS


def _estimator_config(v: Mapping[str, Any]) -> EstimatorConfig:
    """Estimator config from coerced values; errors name the ROS parameter."""
    with as_parameter_error():
        return EstimatorConfig(
            max_wheel_speed=v["max_wheel_speed"],
            velocity_rolling_window_size=v["velocity_rolling_window_size"],
            time_jump_threshold=v["time_jump_threshold"],
            max_reading_gap=v["max_reading_gap"],
        )


COVARIANCE_MODELS = ("propagated", "static")


def _stamp_source(value: str) -> StampSource:
    """The ``stamp_source`` value, or ParameterError naming the choices."""
    try:
        return StampSource(value)
    except ValueError:
        choices = ", ".join(StampSource)
        raise ParameterError("stamp_source", f"must be one of {choices}, got {value!r}") from None


def _noise_model(v: Mapping[str, Any]) -> NoiseModel | None:
    """The wheel noise model, or None for ``covariance_model: static``."""
    model = v["covariance_model"]
    if model not in COVARIANCE_MODELS:
        raise ParameterError(
            "covariance_model", f"must be one of {', '.join(COVARIANCE_MODELS)}, got {model!r}")
    with as_parameter_error():
        noise = NoiseModel(v["wheel_noise_k_left"], v["wheel_noise_k_right"],
                           v["wheel_radius_stddev_ratio"], v["wheel_separation_stddev_ratio"])
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
    if not (math.isfinite(rate) and rate >= 0.0):
        raise ParameterError("publish_rate", f"must be finite and >= 0, got {rate!r}")
    prefix = frame_prefix(v["tf_frame_prefix_enable"], v["tf_frame_prefix"], namespace)
    for name in ("odom_frame_id", "base_frame_id"):
        if not v[name].strip("/"):
            raise ParameterError(name, "must not be empty")
    odom_frame = prefix + v["odom_frame_id"].lstrip("/")
    base_frame = prefix + v["base_frame_id"].lstrip("/")
    if odom_frame == base_frame:
        raise ParameterError("base_frame_id", "must differ from odom_frame_id")
    return OdometrySettings(
        geometry=build_geometry(v),
        encoders=build_encoders(v),
        estimator=_estimator_config(v),
        odom_frame_id=odom_frame,
        base_frame_id=base_frame,
        enable_odom_tf=v["enable_odom_tf"],
        publish_rate=rate,
        pose_covariance_diagonal=_covariance(
            "pose_covariance_diagonal", v["pose_covariance_diagonal"]),
        twist_covariance_diagonal=_covariance(
            "twist_covariance_diagonal", v["twist_covariance_diagonal"]),
        noise=_noise_model(v),
        stamp_source=_stamp_source(v["stamp_source"]),
    )
