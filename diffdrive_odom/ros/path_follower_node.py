"""``path_follower_node``: follows a path with Kumar's control law, odom in, cmd_vel out.

Thin rclpy shell around :class:`diffdrive_odom.core.motion.path_following.PathFollower`: every
``odom`` message is one step of the law (its stamps give the time step of the speed
integral), and the twist goes to ``cmd_vel``, so the cmd_vel node's limits and
watchdog stay between the law and the wheels. The path comes from parameters or,
at runtime, from a ``nav_msgs/Path`` on ``path`` (an empty one stops following).
With ``lockstep`` it answers each step of the simulation it steers
(:mod:`diffdrive_odom.ros.lockstep`) and its odometry's age is simulated time.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any, cast

from geometry_msgs.msg import Twist, TwistStamped
from nav_msgs.msg import Odometry
from nav_msgs.msg import Path as PathMsg
from rclpy.node import Node
from std_msgs.msg import Bool, Float64

from diffdrive_odom.core.errors import ConfigError
from diffdrive_odom.core.geometry.integration import Pose2D
from diffdrive_odom.core.health.base_diagnostics import (
    FollowerHealth,
    FollowerState,
    follower_report,
)
from diffdrive_odom.core.health.diagnostics import Report, Reporter
from diffdrive_odom.core.motion.path_following import Command, PathFollower
from diffdrive_odom.core.motion.paths import Path, polyline
from diffdrive_odom.ros.diagnostics import DiagnosticsPublisher
from diffdrive_odom.ros.lockstep import join
from diffdrive_odom.ros.parameters import ParameterGuard, declare
from diffdrive_odom.ros.qos import DONE_QOS, RELIABLE_OUT_QOS, qos
from diffdrive_odom.ros.runtime import run
from diffdrive_odom.ros.throttle import WARN_THROTTLE_S
from diffdrive_odom.settings.follower import FOLLOWER_PARAMS, FollowerSettings, follower_settings
from diffdrive_odom.wire.conversions import quaternion_to_yaw, stamp_to_ns

NODE_NAME = "path_follower_node"
DIAGNOSTIC_TASK = "path_follower"
DROP_REASONS = ("non_finite_odom", "bad_path", "path_frame")
MAX_STEP_S = 0.5  # a longer gap between odometry stamps is not integrated
THROTTLE_S = WARN_THROTTLE_S

ODOM_IN_QOS = qos(10, reliable=False)  # matches reliable and best-effort odometry
PATH_IN_QOS = qos(1, reliable=True)


class PathFollowerNode(Node):
    """Odometry in, velocity commands out, along the current path."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(NODE_NAME, **kwargs)
        self._log: Any = cast(Any, self).get_logger()
        values = declare(self, FOLLOWER_PARAMS)
        s = follower_settings(values)
        self._settings = s
        self._follower: PathFollower | None = (
            PathFollower(s.path, s.gains, s.geometry) if s.path is not None else None)
        self._guard = ParameterGuard(self, values, follower_settings, self._apply)
        loop = join(self, bool(values["lockstep"]))
        self._loop_clock = loop.clock  # steady, or simulated in lockstep
        self._last_stamp_ns: int | None = None
        self._odom_ns: int | None = None  # the loop clock's time of the last odometry
        self._odom_frame = ""
        self._last: Command | None = None
        self._dropped = dict.fromkeys(DROP_REASONS, 0)
        self._near_singular = 0
        self._limited = 0

        cmd_type = TwistStamped if s.enable_stamped_cmd_vel else Twist
        self._publish_cmd = loop.publish(self.create_publisher(
            cmd_type, "cmd_vel", RELIABLE_OUT_QOS))
        self._publish_error = loop.publish(self.create_publisher(
            Float64, "~/cross_track_error", RELIABLE_OUT_QOS))
        self._publish_progress = loop.publish(self.create_publisher(
            Float64, "~/progress", RELIABLE_OUT_QOS))
        self._publish_done_msg = loop.publish(self.create_publisher(Bool, "~/done", DONE_QOS))
        loop.subscription(Odometry, "odom", self._on_odom, ODOM_IN_QOS)
        loop.subscription(PathMsg, "path", self._on_path, PATH_IN_QOS)
        self._reporter = Reporter(follower_report)
        self._diagnostics = DiagnosticsPublisher(self, DIAGNOSTIC_TASK, self._diagnose)
        self._publish_done(False)
        g = s.gains
        self._log.info(
            f"following {self._describe()}: k_p={g.k_p:g}/s, k_i={g.k_i:g}/s, "
            f"l={g.look_ahead:g} m, v_des={g.desired_speed:g} m/s -> cmd_vel "
            f"({'TwistStamped' if s.enable_stamped_cmd_vel else 'Twist'})")

    def _describe(self) -> str:
        f = self._follower
        if f is None:
            return "no path yet (waiting on the path topic)"
        length = "endless" if f.path.closed else f"{f.path.length:.3f} m"
        return f"a {self._settings.path_type} path ({length})"

    # --- parameters -------------------------------------------------------------

    def _apply(self, s: FollowerSettings) -> None:
        """Install accepted runtime changes; a changed path is followed from its start."""
        old, self._settings = self._settings, s
        if self._follower is not None:
            self._follower.gains = s.gains
            self._follower.geometry = s.geometry
        if s.path != old.path:
            self._set_path(s.path)
        self._log.info("parameters updated")

    def _set_path(self, path: Path | None) -> None:
        if path is None:
            self._follower = None
            self._publish_twist(0.0, 0.0)
        elif self._follower is None:
            s = self._settings
            self._follower = PathFollower(path, s.gains, s.geometry)
        else:
            self._follower.set_path(path)
        self._last = None
        self._publish_done(False)
        self._log.info(f"new path: {self._describe()}")

    # --- input ------------------------------------------------------------------

    def _drop(self, reason: str, text: str) -> None:
        self._dropped[reason] += 1
        self._log.warning(text, throttle_duration_sec=THROTTLE_S)

    def _on_path(self, msg: PathMsg) -> None:
        frame = msg.header.frame_id.lstrip("/")
        if frame and self._odom_frame and frame != self._odom_frame:
            self._drop("path_frame", f"path in frame '{frame}' ignored: odometry is in "
                                     f"'{self._odom_frame}' (no tf here)")
            return
        if not msg.poses:
            self._set_path(None)
            return
        points = [(float(p.pose.position.x), float(p.pose.position.y)) for p in msg.poses]
        try:
            path = polyline(points, self._settings.corner_radius)
        except ConfigError as err:
            self._drop("bad_path", f"path ignored: {err}")
            return
        self._settings = replace(self._settings, path_type="topic")
        self._set_path(path)

    def _on_odom(self, msg: Odometry) -> None:
        p, q, v = msg.pose.pose.position, msg.pose.pose.orientation, msg.twist.twist.linear
        numbers = (p.x, p.y, q.x, q.y, q.z, q.w, v.x)
        if not all(math.isfinite(n) for n in numbers):
            self._drop("non_finite_odom", "odometry with NaN/inf ignored")
            return
        self._odom_ns = self._loop_clock.now().nanoseconds
        self._odom_frame = msg.header.frame_id.lstrip("/")
        stamp = stamp_to_ns(msg.header.stamp)
        last, self._last_stamp_ns = self._last_stamp_ns, stamp
        dt = 0.0 if last is None else (stamp - last) * 1e-9
        if not 0.0 < dt <= MAX_STEP_S:
            dt = 0.0
        f = self._follower
        if f is None:
            return
        was_done = f.done
        c = f.step(Pose2D(p.x, p.y, quaternion_to_yaw(q)), v.x, dt)
        self._last = c
        self._near_singular += c.near_singular
        self._limited += c.limited
        self._publish_twist(c.linear, c.angular)
        self._publish_error(Float64(data=c.cross_track_error))
        self._publish_progress(Float64(data=c.progress))
        if c.done and not was_done:
            self._publish_done(True)
            self._log.info(f"path done after {c.progress:.3f} m")

    # --- output -----------------------------------------------------------------

    def _publish_twist(self, linear: float, angular: float) -> None:
        if not (math.isfinite(linear) and math.isfinite(angular)):  # never NaN on cmd_vel
            linear = angular = 0.0
        twist = Twist()
        twist.linear.x, twist.angular.z = linear, angular
        if self._settings.enable_stamped_cmd_vel:
            ts = TwistStamped()
            ts.header.stamp = self.get_clock().now().to_msg()
            ts.twist = twist
            self._publish_cmd(ts)
        else:
            self._publish_cmd(twist)

    def _publish_done(self, done: bool) -> None:
        self._publish_done_msg(Bool(data=done))

    # --- diagnostics --------------------------------------------------------------

    def _diagnose(self) -> Report:
        f, c = self._follower, self._last
        if f is None:
            state = FollowerState.NO_PATH
        elif f.done:
            state = FollowerState.DONE
        elif c is None:
            state = FollowerState.WAITING
        else:
            state = FollowerState.FOLLOWING
        now = self._loop_clock.now().nanoseconds
        return self._reporter(FollowerHealth(
            state=state,
            odom_age_s=None if self._odom_ns is None else (now - self._odom_ns) * 1e-9,
            cross_track_error_m=c.cross_track_error if c else 0.0,
            progress_m=c.progress if c else 0.0,
            path_length_m=f.path.length if f else 0.0,
            speed_error_mps=c.speed_error if c else 0.0,
            dropped=dict(self._dropped),
            near_singular=self._near_singular,
            limited=self._limited,
        ))


def main(args: list[str] | None = None) -> int:
    """Console script / ``ros2 run diffdrive_odom path_follower_node``."""
    return run(PathFollowerNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
