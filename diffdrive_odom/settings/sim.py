"""``sim_node``'s parameters and their validation (no rclpy import).

The simulated robot has rows of its own: nominal geometry with defaults (the demo's
robot) and the TRUE geometry the base moves with, which may differ from the nominal
one, as a real robot's does. ``wheel_command_format`` takes the cmd_vel node's
output formats, checked once in ``settings.cmd_vel.wheel_command_format``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

from diffdrive_odom.core.commands.cmd_vel_pipeline import FLOAT64_ARRAY
from diffdrive_odom.core.errors import require_finite_min
from diffdrive_odom.core.geometry.kinematics import Geometry
from diffdrive_odom.core.sim.model import SimConfig, SlipEvent
from diffdrive_odom.settings.cmd_vel import wheel_command_format
from diffdrive_odom.settings.errors import ParameterError, as_parameter_error, one_of
from diffdrive_odom.settings.geometry import (
    LENGTH,
    LOCKSTEP_PARAM,
    build_encoders,
    check_lengths,
)
from diffdrive_odom.settings.params import (
    AT_LEAST_ONE,
    COUNTER_BITS,
    INF,
    INT64_MAX,
    NON_NEGATIVE,
    POSITIVE,
    SIGN,
    ParamSpec,
    ParamValue,
    Range,
    coerce_all,
)

RADIANS = "radians"
TICKS = "ticks"
AUTO = "auto"
JOINT_STATE_UNITS = (AUTO, RADIANS, TICKS)

SIM_PARAMS: tuple[ParamSpec, ...] = (
    ParamSpec("wheel_radius", "double", 0.033,
              "Nominal wheel radius [m] (the robot's drawing; shared with the other nodes).",
              range=LENGTH),
    ParamSpec("wheel_separation", "double", 0.160,
              "Nominal wheel separation [m] (shared with the other nodes).", range=LENGTH),
    ParamSpec("true_left_wheel_radius", "double", 0.0,
              "TRUE left wheel radius [m] the base moves with; 0 = wheel_radius.",
              range=NON_NEGATIVE),
    ParamSpec("true_right_wheel_radius", "double", 0.0,
              "TRUE right wheel radius [m]; 0 = wheel_radius.", range=NON_NEGATIVE),
    ParamSpec("true_wheel_separation", "double", 0.0,
              "TRUE wheel separation [m]; 0 = wheel_separation.", range=NON_NEGATIVE),
    ParamSpec("left_wheel_sign", "integer", 1,
              "Hardware joint sign: -1 = the left joint counts (and turns) backwards "
              "when the robot drives forward.", range=SIGN),
    ParamSpec("right_wheel_sign", "integer", 1,
              "Hardware joint sign of the right joint (-1 = flipped).", range=SIGN),
    ParamSpec("left_wheel_names", "string_array", ["left_wheel_joint"],
              "Joint names of the left wheels, in wheel command order.", read_only=True),
    ParamSpec("right_wheel_names", "string_array", ["right_wheel_joint"],
              "Joint names of the right wheels (same count as left).", read_only=True),
    ParamSpec("ticks_per_revolution", "double", 0.0,
              "Encoder counts per wheel turn; 0 = ideal encoder (no quantization).",
              range=NON_NEGATIVE),
    ParamSpec("encoder_counter_bits", "integer", 0,
              "Width of the wrapping encoder counter (e.g. 16); 0 = no wrap.",
              range=COUNTER_BITS),
    ParamSpec("encoder_initial_count", "double", 0.0,
              "Counter value at start (e.g. 65530 to cross a 16-bit wrap at once)."),
    ParamSpec("joint_state_units", "string", AUTO,
              "Position units on joint_states: ticks, radians, or auto (ticks when "
              "ticks_per_revolution > 0).", read_only=True),
    ParamSpec("motor_time_constant", "double", 0.0,
              "First-order motor response [s]; 0 = wheels follow commands at once.",
              range=NON_NEGATIVE),
    ParamSpec("slip_stddev", "double", 0.0,
              "Wheel slip [m]: std of one side's ground-arc error after 1 m rolled "
              "(variance grows with distance; Carroll and Jha, sec. 2.3).",
              range=NON_NEGATIVE),
    ParamSpec("random_seed", "integer", 0,
              "Seed of the slip noise (same seed, same run).", read_only=True,
              range=Range(0, INT64_MAX)),
    ParamSpec("command_timeout", "double", 0.5,
              "No wheel command for this long [s, simulated] -> wheels stop; 0 = never.",
              range=NON_NEGATIVE),
    ParamSpec("wheel_command_format", "string", FLOAT64_ARRAY,
              "Input on wheel_commands: float64_array (rad/s), joint_state (velocity by "
              "name, rad/s) or ticks_per_second (Float64MultiArray, counts/s).",
              read_only=True),
    ParamSpec("joint_state_rate", "double", 50.0,
              "joint_states and ground truth rate [Hz of simulated time], > 0; not "
              "publish_rate, which is the odometry node's.", read_only=True,
              range=Range(0.0, 2000.0, "> 0")),
    ParamSpec("physics_substeps", "integer", 10,
              "Motion steps per published step (exactness with a motor lag).",
              range=AT_LEAST_ONE),
    ParamSpec("publish_clock", "bool", False,
              "Own the time: publish /clock and run at real_time_factor (run the other "
              "nodes with use_sim_time:=true).", read_only=True),
    ParamSpec("real_time_factor", "double", 1.0,
              "Simulated seconds per wall second when publish_clock is true (not in "
              "lockstep, which runs as fast as the loop answers).", read_only=True,
              range=Range(0.0, 100.0, "> 0")),
    LOCKSTEP_PARAM,
    ParamSpec("lockstep_nodes", "string_array",
              ["odometry_node", "path_follower_node", "cmd_vel_node"],
              "lockstep: the nodes whose answer each step waits for (relative names are "
              "in this node's namespace); each runs with lockstep: true.", read_only=True),
    ParamSpec("imu_rate", "double", 0.0,
              "Simulated gyro on imu (sensor_msgs/Imu) [Hz]: samples per joint_states "
              "reading = round(imu_rate / joint_state_rate), at least 1; 0 = no imu.",
              read_only=True, range=NON_NEGATIVE),
    ParamSpec("imu_frame_id", "string", "base_link",
              "Frame of the simulated Imu (mounted as the base: z up)."),
    ParamSpec("sim_gyro_bias", "double", 0.0,
              "Bias [rad/s] the simulated gyro adds to the true yaw rate.",
              range=Range(-INF, INF, "finite")),
    ParamSpec("sim_gyro_noise_density", "double", 0.0,
              "White noise of the simulated gyro [rad/s/sqrt(Hz)].", range=NON_NEGATIVE),
    ParamSpec("sim_gyro_scale", "double", 1.0,
              "Scale factor of the simulated gyro: it reads this times the true yaw rate "
              "(1 = exact; 1.01 = reads 1 % too much).", range=POSITIVE),
    ParamSpec("slip_events", "string", "",
              "Scripted wheel slip: 'SIDE START DURATION RATE' entries separated by ';', "
              "e.g. 'right 5 1 15; left 9 0.5 10': from 5 s for 1 s the right encoders "
              "count 15 rad/s more than the wheel rolls (the ground does not move for it); "
              "empty = none."),
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
    joint_state_rate: float
    publish_clock: bool
    real_time_factor: float
    world_frame_id: str
    base_frame_id: str
    imu_rate: float = 0.0
    imu_frame_id: str = "base_link"
    lockstep: bool = False
    lockstep_nodes: tuple[str, ...] = ()

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
    check_lengths(v, ("wheel_radius", "wheel_separation", "true_left_wheel_radius",
                      "true_right_wheel_radius", "true_wheel_separation"))
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
    encoders = build_encoders(v)
    units = one_of("joint_state_units", v["joint_state_units"], JOINT_STATE_UNITS)
    tpr = encoders.ticks_per_revolution
    if units == AUTO:
        units = TICKS if tpr > 0.0 else RADIANS
    if units == TICKS and tpr <= 0.0:
        raise ParameterError("ticks_per_revolution", "must be > 0 to publish ticks")
    if units == RADIANS and encoders.counter_bits > 0:
        raise ParameterError("encoder_counter_bits",
                             "a wrapping counter needs joint_state_units ticks")
    fmt = wheel_command_format(v["wheel_command_format"], tpr)
    rate = v["joint_state_rate"]
    if not (math.isfinite(rate) and 0.0 < rate <= 2000.0):
        raise ParameterError("joint_state_rate", f"must be > 0 and <= 2000 [Hz], got {rate!r}")
    rtf = v["real_time_factor"]
    if not (math.isfinite(rtf) and 0.0 < rtf <= 100.0):
        raise ParameterError("real_time_factor", f"must be > 0 and <= 100, got {rtf!r}")
    if v["random_seed"] < 0:  # numpy's generator takes no negative seed
        raise ParameterError("random_seed", f"must be >= 0, got {v['random_seed']!r}")
    require_finite_min(ParameterError, "imu_rate", v["imu_rate"])
    for name in ("world_frame_id", "base_frame_id", "imu_frame_id"):
        if not v[name].strip("/"):
            raise ParameterError(name, "must not be empty")
    with as_parameter_error(rename={"substeps": "physics_substeps"}):
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
            slip_events=_slip_events(v["slip_events"]),
            gyro_bias=v["sim_gyro_bias"],
            gyro_noise_density=v["sim_gyro_noise_density"],
            gyro_scale=v["sim_gyro_scale"],
        )
    return SimSettings(
        config=config,
        left_wheel_names=encoders.left_wheel_names,
        right_wheel_names=encoders.right_wheel_names,
        joint_state_units=units,
        wheel_command_format=fmt,
        joint_state_rate=rate,
        publish_clock=v["publish_clock"],
        real_time_factor=rtf,
        world_frame_id=v["world_frame_id"],
        base_frame_id=v["base_frame_id"],
        imu_rate=v["imu_rate"],
        imu_frame_id=v["imu_frame_id"],
        lockstep=v["lockstep"],
        lockstep_nodes=_lockstep_nodes(v["lockstep_nodes"]) if v["lockstep"] else (),
    )


def _lockstep_nodes(names: tuple[str, ...]) -> tuple[str, ...]:
    """``lockstep_nodes``: node names, at least one (ParameterError naming it)."""
    if not names or not all(n.strip("/") and " " not in n for n in names):
        raise ParameterError("lockstep_nodes", f"must name the loop's nodes (e.g. "
                                               f"odometry_node), got {list(names)!r}")
    return names


def _slip_events(value: str) -> tuple[SlipEvent, ...]:
    """``slip_events`` entries 'SIDE START DURATION RATE', or ParameterError naming it."""
    events = []
    for text in filter(None, (t.strip() for t in value.split(";"))):
        parts = text.split()
        try:
            side, start, duration, rate = parts[0], *(float(p) for p in parts[1:])
        except (ValueError, IndexError, TypeError):
            raise ParameterError("slip_events", f"{text!r}: expected 'SIDE START DURATION "
                                                "RATE', e.g. 'right 5 1 15'") from None
        events.append(SlipEvent(side, start, duration, rate))
    return tuple(events)
