"""Open-loop odometry (``open_loop: true``): the pose from the commanded velocity.

For a robot without encoders (or with broken ones), as diff_drive_controller's
``open_loop``: each velocity command ``(v, w)`` is taken as what the base does from the
moment it arrives until the next command, or until it is ``cmd_vel_timeout`` old (the
cmd_vel node's watchdog, :class:`diffdrive_odom.core.watchdog.Watchdog`: then zero).
A constant twist held for ``dt`` is exactly one arc, ``ds = v dt``, ``dtheta = w dt``,
so the pose is composed with the same exact step as wheel odometry
(:func:`diffdrive_odom.core.geometry.integration.compose`): on a commanded route the
pose is the route's, up to rounding.

A command is not a measurement: what it leaves out (motor lag, slip, a blocked wheel)
is not small and does not average out. The covariance says so: each wheel's executed
travel is taken to differ from the commanded one by ``noise`` (relative, 1 sigma), and
the turn by as much through the separation, one draw for the whole run, as the geometry
term of :mod:`diffdrive_odom.core.uncertainty.propagation` (it grows with distance
squared, where wheel noise grows with distance); the twist by ``noise`` of each wheel's
commanded speed. With ``covariance_model: static`` the configured diagonals are
published instead, as diff_drive_controller publishes them in open loop.

Time is one clock: the node's (ROS time, simulated or not) or a bag's log time, the
command's arrival. The node and ``replay`` make the same calls: :meth:`OpenLoopOdometry.command`
for each command, :meth:`OpenLoopOdometry.advance` at each publication instant
(:func:`publication_times` gives replay the node's timer). Pure Python.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from types import MappingProxyType

from diffdrive_odom.core.errors import ConfigError, require_finite_min
from diffdrive_odom.core.estimation.setpose import (
    PoseRefusal,
    PoseRequest,
    SetPoseRule,
    check_request,
)
from diffdrive_odom.core.geometry.integration import Pose2D, compose
from diffdrive_odom.core.geometry.kinematics import Geometry
from diffdrive_odom.core.geometry.mat3 import Matrix, wheel_noise2
from diffdrive_odom.core.uncertainty.noise import NoiseModel
from diffdrive_odom.core.uncertainty.propagation import (
    ZERO3,
    PoseUncertainty,
    covariance_matrix,
    pose_message_covariance,
    twist_message_covariance,
)
from diffdrive_odom.core.watchdog import Watchdog

# Where the commands come from (``open_loop_source``): the velocity commands as the
# cmd_vel node takes them, or the cmd_vel node's limited output (publish_limited_velocity).
CMD_VEL = "cmd_vel"
CMD_VEL_OUT = "cmd_vel_out"
OPEN_LOOP_SOURCES: tuple[str, ...] = (CMD_VEL, CMD_VEL_OUT)
# Relative 1-sigma of the executed wheel travel against the commanded one: a guess that
# grows fast (20 times the encoders' default radius uncertainty); measure yours.
DEFAULT_OPEN_LOOP_NOISE = 0.05
# [Hz] publication rate when publish_rate is 0: there are no readings to publish on
# (diff_drive_controller's publish_rate default).
DEFAULT_OPEN_LOOP_RATE = 50.0

NON_FINITE = "non_finite"
STALE_STAMP = "stale_stamp"
TIME_RESET = "time_reset"
# The clock reads zero: simulated time before the first /clock. A command placed there
# would be integrated from 1970 to the first real time (as far as the timeout lets it).
NO_CLOCK = "no_clock"


class OpenLoopConfigError(ConfigError):
    """An open-loop setting that cannot work (names the parameter)."""


@dataclass(frozen=True)
class OpenLoopConfig:
    """The open-loop parameters, validated.

    ``open_loop_source``, ``cmd_vel_timeout`` [s] (0 = never), ``open_loop_noise`` and
    ``enable_stamped_cmd_vel`` (the type of ``cmd_vel``; ``cmd_vel_out`` is always stamped).
    """

    source: str = CMD_VEL
    timeout: float = 0.5
    noise: float = DEFAULT_OPEN_LOOP_NOISE
    stamped_cmd_vel: bool = False
    # covariance_model static: the pose and twist diagonals published as they are (as
    # diff_drive_controller does in open loop too); None: the open-loop model.
    static: tuple[tuple[float, ...], tuple[float, ...]] | None = None

    def __post_init__(self) -> None:
        if self.source not in OPEN_LOOP_SOURCES:
            raise OpenLoopConfigError(
                "open_loop_source",
                f"must be one of {', '.join(OPEN_LOOP_SOURCES)}, got {self.source!r}")
        if not (math.isfinite(self.timeout) and self.timeout >= 0.0):
            raise OpenLoopConfigError(
                "cmd_vel_timeout", f"must be finite and >= 0 (0 = never), got {self.timeout!r}")
        require_finite_min(OpenLoopConfigError, "open_loop_noise", self.noise)

    @property
    def topic(self) -> str:
        """The topic the commands are read from (relative, as the node subscribes it)."""
        return self.source

    @property
    def stamped(self) -> bool:
        """True when the commands are TwistStamped (the cmd_vel node's output always is)."""
        return self.source == CMD_VEL_OUT or self.stamped_cmd_vel


def publication_rate(publish_rate: float) -> float:
    """Poses per second in open loop: ``publish_rate``, or :data:`DEFAULT_OPEN_LOOP_RATE` at 0."""
    return publish_rate if publish_rate > 0.0 else DEFAULT_OPEN_LOOP_RATE


def publication_times(start_ns: int, end_ns: int, rate: float) -> Iterator[int]:
    """The node's timer offline: ``start``, ``start + 1/rate``, ... up to ``end`` (ns)."""
    period = 1e9 / rate
    k = 0
    while (t := start_ns + round(k * period)) <= end_ns:
        yield t
        k += 1


@dataclass(frozen=True)
class OpenLoopStats:
    """Counters for diagnostics and replay's summary (a snapshot).

    ``commands``: offered; ``dropped``: refused by code (``no_clock``, ``non_finite``,
    ``stale_stamp``);
    ``time_resets``: restarts at the origin after the clock went back;
    ``last_command_ns``: arrival of the last accepted command (None: never);
    ``commanding``: a command is in force (False: none yet, or it timed out).
    """

    commands: int = 0
    dropped: Mapping[str, int] = field(default_factory=lambda: MappingProxyType({}))
    time_resets: int = 0
    last_command_ns: int | None = None
    commanding: bool = False


class OpenLoopOdometry:
    """The pose integrated from held velocity commands, with its covariance."""

    def __init__(self, config: OpenLoopConfig, geometry: Geometry,
                 time_jump_threshold: float = 1.0) -> None:
        self.geometry = geometry
        self.jump_ns = round(time_jump_threshold * 1e9)
        self.pose = Pose2D()
        self.stamp_ns: int | None = None  # integrated up to here
        self.linear = 0.0  # the twist in force at stamp_ns
        self.angular = 0.0
        self._watchdog: Watchdog[tuple[float, float]] = Watchdog(config.timeout)
        self._commands = 0
        self._dropped: dict[str, int] = {}
        self._time_resets = 0
        self._last_ns: int | None = None
        self.config = config
        self.uncertainty = PoseUncertainty(_noise_model(config))
        # A set_pose stamped ahead, held until the clock reaches it.
        self._setpose = SetPoseRule("the time integrated to", "the clock")

    def configure(self, config: OpenLoopConfig, geometry: Geometry) -> None:
        """Install new settings; the pose, its covariance and the held command carry on."""
        self.config, self.geometry = config, geometry
        self._watchdog.timeout_ns = round(config.timeout * 1e9)
        before = self.uncertainty
        self.uncertainty = PoseUncertainty(_noise_model(config))
        self.uncertainty.carry_on_from(before)

    @property
    def stats(self) -> OpenLoopStats:
        """A snapshot of the counters."""
        return OpenLoopStats(self._commands, MappingProxyType(dict(self._dropped)),
                             self._time_resets, self._last_ns,
                             self._watchdog.held is not None)

    def command(self, now_ns: int, linear: float, angular: float,
                stamp_ns: int | None = None) -> str:
        """Take the twist ``(linear.x, angular.z)`` arriving at ``now_ns``.

        ``stamp_ns``: a TwistStamped's own stamp (None: a Twist, or a zero stamp), which
        can only make the command expire sooner, as in the cmd_vel node. A refused command
        is as if it never arrived: the one before it stays in force until its timeout.
        Returns '' (taken), ``time_reset`` (taken after a restart at the origin, see
        :meth:`advance`) or the drop code (``no_clock``, ``non_finite``, ``stale_stamp``).
        """
        self._commands += 1
        code = ""
        if now_ns <= 0:
            code = NO_CLOCK
        elif not (math.isfinite(linear) and math.isfinite(angular)):
            code = NON_FINITE
        elif stamp_ns is not None and self._watchdog.is_stale(stamp_ns, now_ns):
            code = STALE_STAMP
        if code:
            self._dropped[code] = self._dropped.get(code, 0) + 1
            return code
        code = self.advance(now_ns)
        if self.stamp_ns is not None and now_ns < self.stamp_ns:
            now_ns = self.stamp_ns  # a little back in time: from where the pose is
        self._watchdog.accept((linear, angular), now_ns, stamp_ns)
        self.linear, self.angular = linear, angular
        self._last_ns = now_ns
        return code

    def set_pose(self, request: PoseRequest, odom_frame: str) -> str | PoseRefusal:
        """``~/set_pose``, by the encoders' rule (:mod:`~.setpose`, the same code).

        Checked, then the pose now if stamped at or before the time integrated to (or
        zero), else held until the clock reaches its stamp. Returns the line naming it,
        or why it is refused.
        """
        accepted = check_request(request, odom_frame)
        if isinstance(accepted, PoseRefusal):
            return accepted
        return self._setpose.offer(accepted, self, self.config.static is not None)

    @property
    def on_trial(self) -> bool:
        """Never: open loop takes every command (:class:`~.setpose.PoseHolder`)."""
        return False

    def place(self, pose: Pose2D, covariance: Matrix) -> None:
        """``~/set_pose``'s overwrite: the pose where it stands, and its covariance."""
        self.pose = pose
        self.uncertainty.covariance, self.uncertainty.sensitivity = covariance, ZERO3

    def advance(self, now_ns: int) -> str:
        """Integrate the command in force up to ``now_ns`` (or its timeout); '' or ``time_reset``.

        A held ``set_pose`` whose stamp this passes is placed at its stamp on the way.
        """
        held = self._setpose.due(now_ns, self) if now_ns > 0 else None
        if held is not None:
            last = self.stamp_ns
            if (last is None or held.stamp_ns > last) and held.stamp_ns > 0:
                self._integrate(held.stamp_ns)  # forward only: no reset can happen here
            self.place(held.pose, held.covariance)
        return self._integrate(now_ns)

    def _integrate(self, now_ns: int) -> str:
        """:meth:`advance` without the held pose.

        A time more than ``time_jump_threshold`` back (a bag played in a loop, a simulation
        restarted) restarts at the origin with no command held; less is taken as now.
        """
        start = self.stamp_ns
        if now_ns <= 0:  # no clock yet (simulated time before /clock): nothing to do
            return ""
        if start is None or now_ns <= start:
            if start is not None and start - now_ns > self.jump_ns:
                self.reset()
                self._watchdog.clear()
                self.linear = self.angular = 0.0
                self._time_resets += 1
                self.stamp_ns = now_ns
                return TIME_RESET
            if start is None:
                self.stamp_ns = now_ns
            return ""
        held = self._watchdog.held
        deadline = self._watchdog.deadline_ns()
        if held is not None:
            end = now_ns if deadline is None else min(now_ns, deadline)
            v, w = held.command
            if end > start and (v != 0.0 or w != 0.0):
                self._step(v, w, (end - start) * 1e-9)
            if deadline is not None and now_ns > deadline:
                self._watchdog.clear()
                self.linear = self.angular = 0.0
        self.stamp_ns = now_ns
        return ""

    def _step(self, v: float, w: float, dt: float) -> None:
        """One exact arc: the twist ``(v, w)`` held for ``dt`` seconds."""
        ds, dtheta = v * dt, w * dt
        before = self.pose
        self.pose = compose(before, ds, dtheta)
        self.uncertainty.propagate(before, self.geometry, ds=ds, dtheta=dtheta,
                                   d_left=0.0, d_right=0.0, dt=dt)

    def reset(self) -> None:
        """Pose and its covariance back to the origin; the command in force goes on.

        A held set_pose is dropped.
        """
        self._setpose.pending = None
        self.pose = Pose2D()
        self.uncertainty.reset()

    def covariances(self) -> tuple[list[float], list[float]]:
        """Pose and twist covariance (6x6 row-major), as the node publishes them."""
        if self.config.static is not None:
            pose_diag, twist_diag = self.config.static
            return covariance_matrix(pose_diag), covariance_matrix(twist_diag)
        pose_cov = self.uncertainty.pose_covariance(self.pose, self.geometry)
        return pose_message_covariance(pose_cov), twist_message_covariance(self.twist_covariance())

    def twist_covariance(self) -> Matrix:
        """(vx, wz) covariance of the command in force: ``noise`` of each wheel's speed."""
        sep = self.geometry.separation
        noise = self.config.noise
        left = noise * (self.linear - 0.5 * sep * self.angular)
        right = noise * (self.linear + 0.5 * sep * self.angular)
        return wheel_noise2(((0.5, 0.5), (-1.0 / sep, 1.0 / sep)), left * left, right * right)


def _noise_model(config: OpenLoopConfig) -> NoiseModel:
    """No random term: the command's error is one draw per wheel and separation."""
    return NoiseModel(k_left=0.0, k_right=0.0, radius_stddev_ratio=config.noise,
                      separation_stddev_ratio=config.noise, k_rotation=0.0)
