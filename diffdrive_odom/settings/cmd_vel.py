"""The cmd_vel node's parameters and their validation (no rclpy import).

The geometry rows are every node's (``geometry_settings.GEOMETRY_PARAMS``), so one
YAML under ``/**`` configures both nodes and they can never disagree on the robot.
The limits keep diff_drive_controller's dotted names and signs (see ``limits``).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from diffdrive_odom.core.commands.cmd_vel_pipeline import (
    FLOAT64_ARRAY,
    TICKS_PER_SECOND,
    WHEEL_COMMAND_FORMATS,
    CmdVelSettings,
)
from diffdrive_odom.core.commands.limits import AxisLimits, CommandLimits, ddc_axis_limits
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
    POSITIVE,
    ParamSpec,
    ParamValue,
    Range,
    coerce_all,
)

# [rad/s] ~95 000 rpm: no wheel turns this fast, so a command beyond it is nonsense.
DEFAULT_PLAUSIBLE_WHEEL_VELOCITY = 1e4

# Odometry-only geometry rows the cmd_vel node has no use for.
_NOT_USED = ("encoder_counter_bits",)

# axis, velocity unit, positive / negative direction
_AXES: tuple[tuple[str, str, str, str], ...] = (
    ("linear.x", "m/s", "forwards", "backwards"),
    ("angular.z", "rad/s", "counter-clockwise", "clockwise"),
)


def _limit_specs(axis: str, unit: str, pos: str, neg: str) -> tuple[ParamSpec, ...]:
    nan = math.nan
    acc, jerk = f"{unit}^2", f"{unit}^3"
    return (
        ParamSpec(f"{axis}.max_velocity", "double", nan,
                  f"Highest velocity [{unit}], >= 0; .nan = no limit."),
        ParamSpec(f"{axis}.min_velocity", "double", nan,
                  f"Lowest velocity [{unit}], <= 0; .nan = -max_velocity."),
        ParamSpec(f"{axis}.max_acceleration", "double", nan,
                  f"Speeding up {pos} or from rest [{acc}], > 0; .nan = no limit."),
        ParamSpec(f"{axis}.max_deceleration", "double", nan,
                  f"Slowing down while moving {pos} [{acc}], < 0; "
                  ".nan = max_acceleration_reverse."),
        ParamSpec(f"{axis}.max_acceleration_reverse", "double", nan,
                  f"Speeding up {neg} or from rest [{acc}], < 0; .nan = -max_acceleration."),
        ParamSpec(f"{axis}.max_deceleration_reverse", "double", nan,
                  f"Slowing down while moving {neg} [{acc}], > 0; .nan = -max_deceleration."),
        ParamSpec(f"{axis}.max_jerk", "double", nan,
                  f"Upper bound of the change of acceleration [{jerk}], > 0; .nan = no limit."),
        ParamSpec(f"{axis}.min_jerk", "double", nan,
                  f"Lower bound of the change of acceleration [{jerk}], < 0; .nan = -max_jerk."),
        ParamSpec(f"{axis}.has_velocity_limits", "bool", True,
                  "Deprecated diff_drive_controller switch: false = no velocity limits, "
                  "whatever the values say."),
        ParamSpec(f"{axis}.has_acceleration_limits", "bool", True,
                  "Deprecated diff_drive_controller switch: false = no acceleration or "
                  "deceleration limits."),
        ParamSpec(f"{axis}.has_jerk_limits", "bool", True,
                  "Deprecated diff_drive_controller switch: false = no jerk limits "
                  "(a 0.0 jerk then means nothing)."),
        ParamSpec(f"{axis}.min_acceleration", "double", nan,
                  f"Deprecated diff_drive_controller name [{acc}], < 0: used as "
                  "max_acceleration_reverse when that is .nan."),
    )


CMD_VEL_OWN_PARAMS: tuple[ParamSpec, ...] = (
    STAMPED_CMD_VEL_PARAM,
    ParamSpec("wheel_command_format", "string", FLOAT64_ARRAY,
              "Output on wheel_commands: float64_array (std_msgs/Float64MultiArray, rad/s), "
              "joint_state (sensor_msgs/JointState velocity, rad/s) or ticks_per_second "
              "(Float64MultiArray, encoder counts/s).", read_only=True),
    CMD_VEL_TIMEOUT_PARAM,
    ParamSpec("wheel_command_rate", "double", 50.0,
              "Rate of wheel_commands [Hz], steady whether or not commands arrive (> 0); "
              "not publish_rate, which is the odometry node's.",
              range=Range(0.0, 10_000.0, "> 0")),
    ParamSpec("publish_limited_velocity", "bool", False,
              "Publish the twist actually commanded (after limits) on cmd_vel_out."),
    ParamSpec("control_point_offset", "double", 0.0,
              "l [m]: linear.x/linear.y command the velocity of the point l ahead of the "
              "axle (Kumar, Kinematics of Wheeled Robots); 0 = off (linear.x/angular.z as usual)."),
    ParamSpec("max_wheel_velocity", "double", math.nan,
              "Fastest joint rate [rad/s]; faster commands scale both wheels alike "
              "(keeps curvature); .nan or 0 = no limit."),
    ParamSpec("max_plausible_wheel_velocity", "double", DEFAULT_PLAUSIBLE_WHEEL_VELOCITY,
              "Sanity bound [rad/s], > 0: a command whose wheel targets (after control point, "
              "inverse kinematics and limits) are beyond it or not finite is refused with a "
              "warning and counted as dropped 'implausible', never forwarded; the default is "
              "beyond any robot. Not a limit: see max_wheel_velocity.", range=POSITIVE),
    *(spec for axis in _AXES for spec in _limit_specs(*axis)),
)

CMD_VEL_PARAMS: tuple[ParamSpec, ...] = (
    tuple(s for s in GEOMETRY_PARAMS if s.name not in _NOT_USED) + CMD_VEL_OWN_PARAMS
    + (LOCKSTEP_PARAM,)
)




def _axis_limits(axis: str, v: Mapping[str, Any]) -> AxisLimits:
    prefix = axis + "."
    with as_parameter_error(prefix):
        return ddc_axis_limits({
            name[len(prefix):]: value for name, value in v.items() if name.startswith(prefix)
        })


def wheel_command_format(value: str, ticks_per_revolution: float) -> str:
    """``wheel_command_format`` (the cmd_vel node's output, the sim's input), checked."""
    fmt = one_of("wheel_command_format", value, WHEEL_COMMAND_FORMATS)
    if fmt == TICKS_PER_SECOND and ticks_per_revolution <= 0.0:
        raise ParameterError("ticks_per_revolution",
                             f"must be > 0 when wheel_command_format is {TICKS_PER_SECOND}")
    return fmt


def cmd_vel_settings(values: Mapping[str, ParamValue]) -> CmdVelSettings:
    """Validate every cmd_vel parameter; the first bad one raises ParameterError."""
    v = coerce_all(CMD_VEL_PARAMS, values)
    geometry, wheels = build_geometry(v), build_encoders(v)
    fmt = wheel_command_format(v["wheel_command_format"], wheels.ticks_per_revolution)
    timeout = v["cmd_vel_timeout"]
    if not (math.isfinite(timeout) and timeout >= 0.0):
        raise ParameterError("cmd_vel_timeout",
                             f"must be finite and >= 0 (0 = no timeout), got {timeout!r}")
    rate = v["wheel_command_rate"]
    if not (math.isfinite(rate) and 0.0 < rate <= 10_000.0):
        raise ParameterError("wheel_command_rate",
                             f"must be > 0 and <= 10000 [Hz] (drivers take wheel_commands "
                             f"as a heartbeat), got {rate!r}")
    offset = v["control_point_offset"]
    if not math.isfinite(offset):
        raise ParameterError("control_point_offset",
                             f"must be finite (0 = off), got {offset!r}")
    linear = _axis_limits("linear.x", v)
    angular = _axis_limits("angular.z", v)
    with as_parameter_error():
        limits = CommandLimits(linear, angular, v["max_wheel_velocity"])
    plausible = v["max_plausible_wheel_velocity"]
    if not (math.isfinite(plausible) and plausible > 0.0):
        raise ParameterError("max_plausible_wheel_velocity",
                             f"must be finite and > 0 [rad/s], got {plausible!r}")
    if limits.max_wheel_velocity > plausible:
        raise ParameterError("max_wheel_velocity",
                             f"must not exceed max_plausible_wheel_velocity ({plausible:g} "
                             f"rad/s): commands beyond that are refused, not saturated; "
                             f"got {limits.max_wheel_velocity!r}")
    return CmdVelSettings(
        geometry=geometry,
        left_wheel_names=wheels.left_wheel_names,
        right_wheel_names=wheels.right_wheel_names,
        ticks_per_revolution=wheels.ticks_per_revolution,
        enable_stamped_cmd_vel=v["enable_stamped_cmd_vel"],
        wheel_command_format=fmt,
        cmd_vel_timeout=timeout,
        wheel_command_rate=rate,
        publish_limited_velocity=v["publish_limited_velocity"],
        control_point_offset=offset,
        limits=limits,
        max_plausible_wheel_velocity=plausible,
    )
