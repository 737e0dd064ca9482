"""The rows several nodes share (geometry, joints, cmd_vel type) and what they build.

One YAML under ``/**`` configures every node, so the robot is described once: these
rows are the odometry node's, the cmd_vel node and the follower take the ones they
use, and no two nodes can disagree on the robot. ``sim_node`` has rows of its own
(the simulated robot has defaults, a real one has none).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from diffdrive_odom.core.estimation.wheels.encoders import EncoderConfig
from diffdrive_odom.core.geometry.kinematics import Geometry
from diffdrive_odom.settings.errors import ParameterError, as_parameter_error
from diffdrive_odom.settings.params import (
    COUNTER_BITS,
    INF,
    NON_NEGATIVE,
    POSITIVE,
    SIGN,
    ParamSpec,
    Range,
    from_fields,
)

# A wheel or a track under 1 mm is no robot's but a value in the wrong unit (1e-9): every
# step would be integrated into nonsense. The ROS range cannot say it (the default 0.0 is
# "unset"), so the validation does, at start and at runtime alike (ParameterGuard).
MIN_LENGTH = 1e-3  # [m]
LENGTH = Range(0.0, INF, "at least 0.001 (1 mm), finite")  # as ros2 param describe says it

GEOMETRY_PARAMS: tuple[ParamSpec, ...] = (
    ParamSpec("wheel_radius", "double", 0.0,
              "Nominal wheel radius [m]; must be set (at least 0.001) for your robot.",
              range=LENGTH),
    ParamSpec("wheel_separation", "double", 0.0,
              "Distance between the wheels' contact points [m]; must be set (at least "
              "0.001).", range=LENGTH),
    *(ParamSpec(f"{side}_wheel_radius_multiplier", "double", 1.0,
                f"Correction factor on the {side} wheel radius (calibration).", range=POSITIVE)
      for side in ("left", "right")),
    ParamSpec("wheel_separation_multiplier", "double", 1.0,
              "Correction factor on the wheel separation (calibration).", range=POSITIVE),
    *(ParamSpec(f"{side}_wheel_sign", "integer", 1,
                f"1 if the {side} joint angle grows when the robot drives forward, else -1.",
                range=SIGN)
      for side in ("left", "right")),
    ParamSpec("left_wheel_names", "string_array", ["left_wheel_joint"],
              "Joint names of the left wheels (several are averaged).", read_only=True),
    ParamSpec("right_wheel_names", "string_array", ["right_wheel_joint"],
              "Joint names of the right wheels (same count as left).", read_only=True),
    ParamSpec("ticks_per_revolution", "double", 0.0,
              "0: positions in radians; > 0: raw encoder counts per wheel turn "
              "(non-integer allowed).", range=NON_NEGATIVE),
    ParamSpec("encoder_counter_bits", "integer", 0,
              "Width of a wrapping encoder counter (e.g. 16, 32); 0 = no wrap.",
              range=COUNTER_BITS),
)


def check_lengths(v: Mapping[str, Any], names: tuple[str, ...]) -> None:
    """Refuse a length in ``names`` that is positive but under :data:`MIN_LENGTH`."""
    for name in names:
        value = v[name]
        if math.isfinite(value) and 0.0 < value < MIN_LENGTH:
            raise ParameterError(name, f"must be at least {MIN_LENGTH:g} m (1 mm), got "
                                       f"{value!r}: a length in another unit?")


def build_geometry(v: Mapping[str, Any]) -> Geometry:
    """Geometry from coerced values; errors name the ROS parameter."""
    geometry = from_fields(Geometry, v)
    check_lengths(v, ("wheel_radius", "wheel_separation"))
    return geometry


def build_encoders(v: Mapping[str, Any]) -> EncoderConfig:
    """Encoder config from coerced values; errors name the ROS parameter.

    Without ``encoder_counter_bits`` (the cmd_vel node reads no counter): no wrap.
    """
    with as_parameter_error():
        return EncoderConfig(
            left_wheel_names=v["left_wheel_names"],
            right_wheel_names=v["right_wheel_names"],
            ticks_per_revolution=v["ticks_per_revolution"],
            counter_bits=v.get("encoder_counter_bits", 0),
        )


# The cmd_vel message type: the cmd_vel node subscribes it, the follower publishes it,
# so one row (under ``/**``) keeps the two ends of the topic on the same type.
STAMPED_CMD_VEL_PARAM = ParamSpec(
    "enable_stamped_cmd_vel", "bool", False,
    "Subscribe geometry_msgs/TwistStamped (true) or Twist (false) on cmd_vel "
    "(Nav2's name and Jazzy default).", read_only=True)

# The command timeout: the cmd_vel node's watchdog and open-loop odometry (odometry_node
# with open_loop) hold a command this long, so one row gives both the same value.
CMD_VEL_TIMEOUT_PARAM = ParamSpec(
    "cmd_vel_timeout", "double", 0.5,
    "A command is followed for this long [s] unless another arrives, then velocity zero "
    "(cmd_vel_node publishes zeros; odometry_node with open_loop integrates zero); "
    "0 = never.", range=NON_NEGATIVE)

# Lockstep with sim_node: its mode and each node of its loop take part by the same name,
# so one row under ``/**`` puts the whole loop in lockstep (doc/nodes/sim_node.md).
LOCKSTEP_PARAM = ParamSpec(
    "lockstep", "bool", False,
    "Simulation only: sim_node steps its /clock and physics only once the nodes named in "
    "lockstep_nodes have answered the last step, and each of them (true too, with "
    "use_sim_time) runs its heartbeat, watchdog and limits on that clock. false: as on a "
    "robot.", read_only=True)
