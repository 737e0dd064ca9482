"""Parameter specs shared by the nodes and the offline tools (no rclpy import).

One table of names, defaults, types and one-line meanings serves four readers: the
nodes (declare + validate), ``replay`` (reads the same params YAML as the node),
``config/diffdrive_odom.yaml`` and the README's parameter tables. Values are
coerced here rather than by rclpy's static typing so that ``-p wheel_radius:=1``
(an integer on the command line) works and a wrong type gets one clear line.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from diffdrive_odom.encoders import EncoderConfig
from diffdrive_odom.errors import ParameterError as ParameterError  # re-exported
from diffdrive_odom.errors import as_parameter_error
from diffdrive_odom.kinematics import Geometry
from diffdrive_odom.odometry import EstimatorConfig

ParamValue = Any


def _as_float(name: str, value: ParamValue) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ParameterError(name, f"must be a number, got {value!r}")
    return float(value)


def _as_int(name: str, value: ParamValue) -> int:
    if isinstance(value, bool):
        raise ParameterError(name, f"must be an integer, got {value!r}")
    if isinstance(value, float) and value.is_integer():
        return int(value)
    if not isinstance(value, int):
        raise ParameterError(name, f"must be an integer, got {value!r}")
    return value


def _as_bool(name: str, value: ParamValue) -> bool:
    if not isinstance(value, bool):
        raise ParameterError(name, f"must be true or false, got {value!r}")
    return value


def _as_str(name: str, value: ParamValue) -> str:
    if not isinstance(value, str):
        raise ParameterError(name, f"must be a string, got {value!r}")
    return value


def _as_str_list(name: str, value: ParamValue) -> tuple[str, ...]:
    if isinstance(value, str) or not isinstance(value, Iterable):
        raise ParameterError(name, f"must be a list of strings, got {value!r}")
    items = tuple(value)
    if not all(isinstance(v, str) for v in items):
        raise ParameterError(name, f"must be a list of strings, got {value!r}")
    return items


def _as_float_list(name: str, value: ParamValue) -> tuple[float, ...]:
    if isinstance(value, str) or not isinstance(value, Iterable):
        raise ParameterError(name, f"must be a list of numbers, got {value!r}")
    return tuple(_as_float(name, v) for v in value)


COERCE: dict[str, Callable[[str, ParamValue], ParamValue]] = {
    "double": _as_float,
    "integer": _as_int,
    "bool": _as_bool,
    "string": _as_str,
    "string_array": _as_str_list,
    "double_array": _as_float_list,
}


@dataclass(frozen=True)
class ParamSpec:
    """One parameter: name, kind (a key of ``COERCE``), default and one-line meaning."""

    name: str
    kind: str
    default: ParamValue
    description: str
    read_only: bool = False

    def coerce(self, value: ParamValue) -> ParamValue:
        """The value in this parameter's Python type, or ParameterError."""
        return COERCE[self.kind](self.name, value)


GEOMETRY_PARAMS: tuple[ParamSpec, ...] = (
    ParamSpec("wheel_radius", "double", 0.0,
              "Nominal wheel radius [m]; must be set (> 0) for your robot."),
    ParamSpec("wheel_separation", "double", 0.0,
              "Distance between the wheels' contact points [m]; must be set (> 0)."),
    ParamSpec("left_wheel_radius_multiplier", "double", 1.0,
              "Correction factor on the left wheel radius (calibration)."),
    ParamSpec("right_wheel_radius_multiplier", "double", 1.0,
              "Correction factor on the right wheel radius (calibration)."),
    ParamSpec("wheel_separation_multiplier", "double", 1.0,
              "Correction factor on the wheel separation (calibration)."),
    ParamSpec("left_wheel_sign", "integer", 1,
              "1 if the left joint angle grows when the robot drives forward, else -1."),
    ParamSpec("right_wheel_sign", "integer", 1,
              "1 if the right joint angle grows when the robot drives forward, else -1."),
    ParamSpec("left_wheel_names", "string_array", ["left_wheel_joint"],
              "Joint names of the left wheels (several are averaged).", read_only=True),
    ParamSpec("right_wheel_names", "string_array", ["right_wheel_joint"],
              "Joint names of the right wheels (same count as left).", read_only=True),
    ParamSpec("ticks_per_revolution", "double", 0.0,
              "0: positions in radians; > 0: raw encoder counts per wheel turn "
              "(non-integer allowed)."),
    ParamSpec("encoder_counter_bits", "integer", 0,
              "Width of a wrapping encoder counter (e.g. 16, 32); 0 = no wrap."),
)

ODOMETRY_PARAMS: tuple[ParamSpec, ...] = (
    ParamSpec("odom_frame_id", "string", "odom", "Frame of the published pose."),
    ParamSpec("base_frame_id", "string", "base_link", "Child frame (the robot)."),
    ParamSpec("tf_frame_prefix_enable", "bool", True,
              "Prefix both frame ids with tf_frame_prefix (multi-robot)."),
    ParamSpec("tf_frame_prefix", "string", "",
              "Frame prefix; empty = the node's namespace (as diff_drive_controller)."),
    ParamSpec("enable_odom_tf", "bool", True, "Publish odom -> base_link on /tf."),
    ParamSpec("publish_rate", "double", 0.0,
              "Max odometry publish rate [Hz]; 0 = publish every reading."),
    ParamSpec("pose_covariance_diagonal", "double_array",
              [0.001, 0.001, 1.0e6, 1.0e6, 1.0e6, 0.01],
              "Diagonal of the pose covariance (x, y, z, roll, pitch, yaw)."),
    ParamSpec("twist_covariance_diagonal", "double_array",
              [0.001, 1.0e-6, 1.0e6, 1.0e6, 1.0e6, 0.01],
              "Diagonal of the twist covariance (vx, vy, vz, wx, wy, wz)."),
    ParamSpec("velocity_rolling_window_size", "integer", 1,
              "Readings in the rolling mean of the twist (never applied to the pose)."),
    ParamSpec("max_wheel_speed", "double", 200.0,
              "Fastest plausible joint speed [rad/s]; faster steps are skipped."),
    ParamSpec("time_jump_threshold", "double", 1.0,
              "A stamp this far [s] behind the last restarts odometry (bag loop)."),
    ParamSpec("max_reading_gap", "double", 1.0,
              "A reading this long [s] after the last usable one is a new reference, "
              "no motion integrated (driver restart); .inf = off."),
)


def defaults(specs: Iterable[ParamSpec]) -> dict[str, ParamValue]:
    """``{name: default}`` for a set of specs."""
    return {s.name: s.default for s in specs}


def coerce_all(specs: Iterable[ParamSpec], values: Mapping[str, ParamValue]) -> dict[str, Any]:
    """Every spec's value from ``values`` (default where absent), typed; ParameterError if not."""
    return {s.name: s.coerce(values.get(s.name, s.default)) for s in specs}


def build_geometry(v: Mapping[str, Any]) -> Geometry:
    """Geometry from coerced values; errors name the ROS parameter."""
    with as_parameter_error():
        return Geometry(
            wheel_radius=v["wheel_radius"],
            wheel_separation=v["wheel_separation"],
            left_wheel_radius_multiplier=v["left_wheel_radius_multiplier"],
            right_wheel_radius_multiplier=v["right_wheel_radius_multiplier"],
            wheel_separation_multiplier=v["wheel_separation_multiplier"],
            left_wheel_sign=v["left_wheel_sign"],
            right_wheel_sign=v["right_wheel_sign"],
        )


def build_encoders(v: Mapping[str, Any]) -> EncoderConfig:
    """Encoder config from coerced values; errors name the ROS parameter."""
    with as_parameter_error():
        return EncoderConfig(
            left_wheel_names=v["left_wheel_names"],
            right_wheel_names=v["right_wheel_names"],
            ticks_per_revolution=v["ticks_per_revolution"],
            counter_bits=v["encoder_counter_bits"],
        )


def build_estimator_config(v: Mapping[str, Any]) -> EstimatorConfig:
    """Estimator config from coerced values; errors name the ROS parameter."""
    with as_parameter_error():
        return EstimatorConfig(
            max_wheel_speed=v["max_wheel_speed"],
            velocity_rolling_window_size=v["velocity_rolling_window_size"],
            time_jump_threshold=v["time_jump_threshold"],
            max_reading_gap=v["max_reading_gap"],
        )


@dataclass(frozen=True)
class OdometrySettings:
    """All validated settings of the odometry node / replay tool."""

    geometry: Geometry
    encoders: EncoderConfig
    estimator: EstimatorConfig
    odom_frame_id: str
    base_frame_id: str
    enable_odom_tf: bool
    publish_rate: float
    pose_covariance_diagonal: tuple[float, ...]
    twist_covariance_diagonal: tuple[float, ...]


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
    v = coerce_all(GEOMETRY_PARAMS + ODOMETRY_PARAMS, values)
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
        estimator=build_estimator_config(v),
        odom_frame_id=odom_frame,
        base_frame_id=base_frame,
        enable_odom_tf=v["enable_odom_tf"],
        publish_rate=rate,
        pose_covariance_diagonal=_covariance(
            "pose_covariance_diagonal", v["pose_covariance_diagonal"]),
        twist_covariance_diagonal=_covariance(
            "twist_covariance_diagonal", v["twist_covariance_diagonal"]),
    )


def load_params_file(
    path: str | Path, node_name: str, namespace: str = "/"
) -> dict[str, ParamValue]:
    """Parameters for ``node_name`` from a ROS 2 params YAML (as ``--params-file`` reads it).

    Sections apply in rcl's order of precedence: wildcards (``/**``), then
    ``/**/node``, then the plain or fully qualified node name, so the tools take the
    very file the node takes. Nested maps become dotted names.
    """
    import yaml

    with open(path, encoding="utf-8") as f:
        doc = yaml.safe_load(f) or {}
    if not isinstance(doc, dict):
        raise ParameterError("--params-file", f"{path} is not a mapping")
    ns = namespace.strip("/")
    full = f"/{ns}/{node_name}" if ns else f"/{node_name}"
    keys = ("/**", "**", f"/**/{node_name}", node_name, f"/{node_name}", full, full[1:])
    merged: dict[str, ParamValue] = {}
    for key in dict.fromkeys(keys):  # ordered, without repeats
        section = doc.get(key)
        if isinstance(section, dict):
            merged.update(_flatten(section.get("ros__parameters", {}) or {}))
    return merged


def _flatten(tree: Mapping[str, Any], prefix: str = "") -> dict[str, ParamValue]:
    """Nested YAML maps -> dotted names (``linear: {x: {max_velocity: 1}}``)."""
    flat: dict[str, ParamValue] = {}
    for key, value in tree.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            flat.update(_flatten(value, name + "."))
        else:
            flat[name] = value
    return flat


def yaml_text(value: object) -> str:
    """YAML 1.1 text that both rcl's parser and PyYAML read back as the same type."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        if value != value:
            return ".nan"
        if value in (float("inf"), float("-inf")):
            return ".inf" if value > 0 else "-.inf"
        mantissa, _, exponent = repr(value).partition("e")
        if "." not in mantissa:
            mantissa += ".0"
        return mantissa + (f"e{exponent}" if exponent else "")
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(yaml_text(v) for v in value) + "]"
    return json.dumps(value)
