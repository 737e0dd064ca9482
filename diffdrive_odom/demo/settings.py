"""The demo's settings: options, the run's params file, the squares' paths, the topics.

Pure (yaml and the package's params only): everything here is decided before a node
starts, so a bad option fails in a second with one line, and the tests check it
without DDS.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from diffdrive_odom.core.estimation.config import OdometrySettings
from diffdrive_odom.core.motion import routes
from diffdrive_odom.core.motion.paths import Point, route_points
from diffdrive_odom.settings.errors import ParameterError
from diffdrive_odom.settings.follower import FollowerSettings, follower_settings
from diffdrive_odom.settings.odometry import odometry_settings
from diffdrive_odom.settings.params import EXAMPLE_PARAMS_FILE, ParamValue
from diffdrive_odom.settings.rcl import load_params_file
from diffdrive_odom.settings.sim import SimSettings, sim_settings

DEFAULT_PARAMS = EXAMPLE_PARAMS_FILE
PROGRAM = "diffdrive-odom demo"
FOLLOWER = "path_follower_node"
# The one topic table: bag topic -> message type. The recorder subscribes to exactly
# these (it resolves the classes from the type names) and the other tools (eval,
# replay, play, calibrate) read them from the bag.
BAG_TOPICS: dict[str, str] = {
    "/joint_states": "sensor_msgs/msg/JointState",
    "/imu": "sensor_msgs/msg/Imu",  # the sim's gyro (imu_rate): the gyro-aided replay's
    "/odom": "nav_msgs/msg/Odometry",
    "/ground_truth/odom": "nav_msgs/msg/Odometry",
    "/tf": "tf2_msgs/msg/TFMessage",
    "/cmd_vel": "geometry_msgs/msg/Twist",
    "/path": "nav_msgs/msg/Path",
    f"/{FOLLOWER}/cross_track_error": "std_msgs/msg/Float64",
}
SETTLE_S = 1.0  # simulated time at rest between the squares and after the last
# Simulated time at rest before the first square: the odometry's gyro bias is found
# standing still, and until then its uncertainty hides part of a slip from the gyro (a
# slip 3 s into a route after 1 s of rest was found at 1.8 of its 5.7 deg).
START_REST_S = 5.0
STARTUP_TIMEOUT_S = 45.0
# The robot starts (and, on its odometry, ends) each square this far into the first
# leg, so it comes back along a straight and stops there with its heading settled:
# both squares start at the same place, as UMBmark requires.
START_OFFSET_M = 0.5
# Cornered routes only: the follower takes a route's corners (circles are not polylines).
ROUTES: dict[str, tuple[bool, ...]] = {  # name -> the squares' directions (True = CW)
    "umbmark": (True, False), "umbmark_cw": (True,), "umbmark_ccw": (False,),
    "square": (False,), "square_cw": (True,),
}


class DemoError(RuntimeError):
    """The demo cannot go on; the message says why (and which process failed)."""


@dataclass(frozen=True)
class DemoOptions:
    """What to run and where to write it."""

    route: str = "umbmark"
    side: float = 4.0
    output: Path = Path("demo_output")
    params_file: Path = DEFAULT_PARAMS
    speed: float = 0.4  # the follower's desired speed [m/s]
    max_angular: float = 2.0  # the follower's turn rate bound [rad/s]
    sim_overrides: dict[str, str] = field(default_factory=dict)
    timeout: float = 150.0  # wall seconds for the whole run
    write_bag: bool = True
    write_plot: bool = True
    domain_id: int | None = None

    @property
    def squares(self) -> tuple[bool, ...]:
        """The squares to drive, in order (True = clockwise)."""
        return ROUTES[self.route]


@dataclass(frozen=True)
class Settings:
    """The three nodes' settings as the run's params file gives them.

    ``gyro_odometry``: the odometry node's settings with ``use_imu`` true (its gyro
    parameters from the same section), for the gyro-aided replay; the live node runs
    as the file says (the demo's: wheels only, so the follower steers on what slip does
    to wheel odometry).
    """

    odometry: OdometrySettings
    sim: SimSettings
    follower: FollowerSettings
    gyro_odometry: OdometrySettings


def parse_override(text: str) -> tuple[str, str]:
    """``NAME:=VALUE`` of ``--sim-param``."""
    name, sep, value = text.partition(":=")
    if not sep or not name:
        raise DemoError(f"--sim-param takes NAME:=VALUE, got {text!r}")
    return name, value


def yaml_value(text: str) -> ParamValue:
    """A ``-p name:=value`` value as ROS reads it (YAML)."""
    return yaml.safe_load(text) if text.strip() else text


def check_options(opts: DemoOptions) -> None:
    """Refuse options that cannot run, before anything starts."""
    if opts.route not in ROUTES:
        raise DemoError(f"--route must be one of {', '.join(ROUTES)}, got {opts.route!r}")
    if not (math.isfinite(opts.side) and opts.side >= 2.0 * START_OFFSET_M):
        raise DemoError(f"--size must be >= {2 * START_OFFSET_M:g} m (the robot starts "
                        f"{START_OFFSET_M:g} m into the first leg), got {opts.side}")
    for flag, value in (("--linear", opts.speed), ("--angular", opts.max_angular)):
        if not (math.isfinite(value) and value > 0.0):
            raise DemoError(f"{flag} must be > 0, got {value}")
    check_output(opts.output)


# What a demo writes into its output directory: one holding only these is a previous
# demo's, which a new run replaces once it has finished.
OUTPUT_NAMES = frozenset({"logs", "bag", "params.yaml", "results.json", "trajectory.png"})


def check_output(output: Path) -> None:
    """Refuse an ``--output`` a finished run could not replace.

    That is anything but a directory holding a previous demo's files (or nothing): a
    user's own files are never deleted.
    """
    if not output.exists():
        return
    if not output.is_dir():
        raise DemoError(f"--output {output}: exists and is not a directory")
    foreign = sorted(p.name for p in output.iterdir() if p.name not in OUTPUT_NAMES)
    if foreign:
        raise DemoError(f"--output {output}: holds {', '.join(foreign[:3])}"
                        f"{', ...' if len(foreign) > 3 else ''}, not a demo's output: "
                        "choose another --output (a finished run replaces a previous one)")


def follower_values(opts: DemoOptions) -> dict[str, ParamValue]:
    """The follower's parameters for this run: no path at start (the demo sends each)."""
    return {"use_sim_time": True, "follower.path_type": "none",
            "follower.desired_speed": float(opts.speed),
            "follower.max_angular_velocity": float(opts.max_angular)}


def load_settings(opts: DemoOptions) -> Settings:
    """The odometry node's, the sim's and the follower's settings (file + overrides)."""
    try:
        odo_values = load_params_file(opts.params_file, "odometry_node")
        odo = odometry_settings(odo_values)
        gyro = odometry_settings({**odo_values, "use_imu": True})
        sim_values = load_params_file(opts.params_file, "sim_node")
        sim_values.update({k: yaml_value(v) for k, v in opts.sim_overrides.items()})
        sim = sim_settings(sim_values)
        fol_values = load_params_file(opts.params_file, FOLLOWER)
        fol_values.update({k: v for k, v in follower_values(opts).items()
                           if k != "use_sim_time"})
        fol = follower_settings(fol_values)
    except (ParameterError, OSError, yaml.YAMLError) as err:
        raise DemoError(f"{opts.params_file}: {err}") from err
    return Settings(odo, sim, fol, gyro)


def write_run_params(source: Path, changes: dict[str, dict[str, ParamValue]],
                     path: Path) -> Path:
    """Write the params file with this run's settings in the nodes' own sections.

    In a params file a node's own section wins over ``-p`` on the command line, so
    the run's values go into the file rather than onto the command line.
    """
    try:
        doc = yaml.safe_load(source.read_text(encoding="utf-8")) or {}
    except (OSError, yaml.YAMLError) as err:
        raise DemoError(f"{source}: {err}") from err
    if not isinstance(doc, dict):
        raise DemoError(f"{source} is not a ROS 2 params file")
    for node, values in changes.items():
        section = doc.setdefault(node, {}).setdefault("ros__parameters", {})
        section.update(values)
    path.write_text("# Written by diffdrive-odom demo for this run: " + str(source)
                    + " with the run's settings applied.\n"
                    + yaml.safe_dump(doc, default_flow_style=None, sort_keys=False),
                    encoding="utf-8")
    return path


def square_corners(side: float, clockwise: bool) -> list[Point]:
    """The square's corners in the odom frame, the robot's start ``START_OFFSET_M`` into leg 1.

    The corners are UMBmark's (:func:`diffdrive_odom.core.motion.routes.umbmark`), shifted back so
    the first leg runs through the start.
    """
    corners = route_points(routes.umbmark(side, clockwise=clockwise))
    return [(x - START_OFFSET_M, y) for x, y in corners]


def square_path(side: float, clockwise: bool, look_ahead: float) -> list[Point]:
    """The points sent to the follower for one square, from the start back to it.

    The follower steers its point P, ``look_ahead`` ahead of the axle, so the path
    starts and ends at P's place when the axle is at the start heading along x.
    """
    p = (look_ahead, 0.0)
    return [p, *square_corners(side, clockwise)[1:], p]
