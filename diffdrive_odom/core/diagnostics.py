"""Health reports for ``/diagnostics``: levels, rate meters and each node's verdict.

Pure Python (no rclpy, no messages) so the verdicts are unit-tested from plain
numbers; :class:`diffdrive_odom.ros.diagnostics.DiagnosticsPublisher` turns a
:class:`Report` into the ``diagnostic_msgs/DiagnosticStatus`` that
diagnostic_aggregator and rqt_robot_monitor read.

Each report compares the node's cumulative counters with those of the previous
report: a problem that happened "since the last report" warns for one report
period (about a second), a persistent one (no readings, a robot stopped by the
watchdog) warns for as long as it lasts.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from enum import Enum, IntEnum
from typing import Generic, TypeVar

from diffdrive_odom.core.pipeline import GyroStats

H = TypeVar("H")


class Level(IntEnum):
    """diagnostic_msgs/DiagnosticStatus levels, with the message's byte values."""

    OK = 0
    WARN = 1
    ERROR = 2
    STALE = 3


@dataclass(frozen=True)
class Report:
    """One status: level, a few words saying why, and every number as key/value strings."""

    level: Level
    message: str
    values: tuple[tuple[str, str], ...] = ()


class RateMeter:
    """Events per second over a sliding window of monotonic times [s].

    ``add`` is an append plus amortised O(1) pruning (it sits in a 1 kHz reading
    path); memory is bounded by the events of one window. Before one full window has
    passed since ``start`` the rate is taken over the time elapsed, so it is right
    from the first report rather than ramping up.
    """

    def __init__(self, start: float, window_s: float = 1.0) -> None:
        if not (window_s > 0.0 and math.isfinite(window_s)):
            raise ValueError(f"window_s must be > 0, got {window_s!r}")
        self.start = start
        self.window_s = window_s
        self._times: deque[float] = deque()

    def add(self, t: float) -> None:
        """Record one event at monotonic time ``t``."""
        times = self._times
        times.append(t)
        horizon = t - self.window_s
        while times[0] <= horizon:
            times.popleft()

    def rate(self, now: float) -> float:
        """Events in (now - window, now] per second of that window (or of the time since start)."""
        times = self._times
        horizon = now - self.window_s
        while times and times[0] <= horizon:
            times.popleft()
        span = min(self.window_s, now - self.start)
        if span <= 0.0:
            return 0.0
        return len(times) / span  # monotonic times: none is later than now


def _seconds(value: float | None) -> str:
    return "never" if value is None else f"{value:.3f}"


def _finite(value: float) -> float:
    """Reports never carry NaN/inf (a bad input must not poison the monitor)."""
    return value if math.isfinite(value) else 0.0


def _since(now: Mapping[str, int], before: Mapping[str, int] | None) -> dict[str, int]:
    """Per-key increase since the previous report (all of it at the first report)."""
    return {k: v - (before.get(k, 0) if before is not None else 0) for k, v in now.items()}


def _counts(label: str, totals: Mapping[str, int], recent: Mapping[str, int]
            ) -> list[tuple[str, str]]:
    values = [(f"{label} (total)", str(sum(totals.values()))),
              (f"{label} since last report", str(sum(recent.values())))]
    values += [(f"{label}: {k}", str(v)) for k, v in totals.items()]
    return values


def _by_reason(counts: Mapping[str, int]) -> str:
    return ", ".join(f"{k} {v}" for k, v in counts.items() if v)


def _verdict(problems: list[tuple[Level, str]], ok_message: str) -> tuple[Level, str]:
    """The worst level; the message lists the problems, worst first."""
    if not problems:
        return Level.OK, ok_message
    problems = sorted(problems, key=lambda p: -p[0])
    return problems[0][0], "; ".join(text for _, text in problems)


class Reporter(Generic[H]):
    """Calls a report function with this and the previous snapshot of a node's health.

    The one piece of state the pure report functions need (what "since the last
    report" means), kept out of the nodes.
    """

    def __init__(self, report: Callable[[H, H | None], Report]) -> None:
        self._report = report
        self._before: H | None = None

    def __call__(self, health: H) -> Report:
        """Report ``health``; remember it as the baseline of the next report."""
        report = self._report(health, self._before)
        self._before = health
        return report


# --- odometry_node -------------------------------------------------------------------


@dataclass(frozen=True)
class ReadingThresholds:
    """When the odometry input counts as late.

    WARN after ``stale_after_s`` without a reading, ERROR after ``error_after_s``, or
    when none arrived ``startup_grace_s`` after the start.
    """

    stale_after_s: float = 0.5
    error_after_s: float = 5.0
    startup_grace_s: float = 5.0


DEFAULT_READING_THRESHOLDS = ReadingThresholds()


@dataclass(frozen=True)
class ReadingHealth:
    """A snapshot of the odometry input; counters are cumulative since the start.

    ``dropped`` maps a stable short reason ("zero_stamp", "missing_joint",
    "non_finite", "too_fast", ...) to the readings dropped for it.
    """

    uptime_s: float
    reading_rate_hz: float
    since_last_reading_s: float | None
    dropped: Mapping[str, int] = field(default_factory=dict)
    reanchors: int = 0
    gap_reanchors: int = 0
    time_resets: int = 0
    velocity_fallback: bool = False
    gyro: GyroStats | None = None  # use_imu true: the gyro's counters and slip events


def odometry_report(
    now: ReadingHealth,
    before: ReadingHealth | None = None,
    thresholds: ReadingThresholds = DEFAULT_READING_THRESHOLDS,
) -> Report:
    """The odometry input's health; ``before`` is the previous report's snapshot."""
    t = thresholds
    problems: list[tuple[Level, str]] = []
    since = now.since_last_reading_s
    if since is None:
        if now.uptime_s >= t.startup_grace_s:
            problems.append((Level.ERROR, f"no reading received in {now.uptime_s:.1f} s"))
    elif since >= t.error_after_s:
        problems.append((Level.ERROR, f"no reading for {since:.1f} s"))
    elif since >= t.stale_after_s:
        problems.append((Level.WARN, f"stale: no reading for {since:.2f} s"))
    dropped = _since(now.dropped, before.dropped if before else None)
    if any(dropped.values()):
        problems.append((Level.WARN, f"dropped {sum(dropped.values())} readings "
                                     f"({_by_reason(dropped)})"))
    def recent(count: Callable[[ReadingHealth], int]) -> int:
        return count(now) - (count(before) if before is not None else 0)

    reanchors = recent(lambda h: h.reanchors)
    gap_reanchors = recent(lambda h: h.gap_reanchors)
    time_resets = recent(lambda h: h.time_resets)
    if reanchors:
        problems.append((Level.WARN, f"{reanchors} re-anchors (implausible step)"))
    if gap_reanchors:
        problems.append((Level.WARN, f"{gap_reanchors} re-anchors after a gap"))
    if time_resets:
        problems.append((Level.WARN, f"{time_resets} time resets (stamp jumped back)"))
    gyro_values = _gyro(now.gyro, before.gyro if before else None, problems)
    if since is None and not problems:
        ok = "starting: waiting for the first reading"
    else:
        ok = "integrating wheel velocities" if now.velocity_fallback else "integrating"
        ok += ", gyro-aided" if now.gyro is not None else ""
    level, message = _verdict(problems, ok)
    values = [
        ("reading rate [Hz]", f"{_finite(now.reading_rate_hz):.1f}"),
        ("last reading [s ago]", _seconds(since)),
        *_counts("dropped", now.dropped, dropped),
        ("re-anchors (implausible step)", str(now.reanchors)),
        ("re-anchors after a gap", str(now.gap_reanchors)),
        ("time resets", str(now.time_resets)),
        ("velocity fallback", "true" if now.velocity_fallback else "false"),
        ("stale after [s]", f"{t.stale_after_s:g}"),
        ("error after [s]", f"{t.error_after_s:g}"),
        *gyro_values,
    ]
    return Report(level, message, tuple(values))


def _gyro(now: GyroStats | None, before: GyroStats | None,
          problems: list[tuple[Level, str]]) -> list[tuple[str, str]]:
    """The gyro's values (``use_imu``); WARN while it is silent or after refused samples.

    A slip is what the gyro is for, not a fault: counted and named, not warned of.
    """
    if now is None:
        return []
    if now.silent:
        problems.append((Level.WARN, "IMU silent: wheels only"))
    dropped = _since(now.dropped, before.dropped if before else None)
    if any(dropped.values()):
        problems.append((Level.WARN, f"dropped {sum(dropped.values())} IMU samples "
                                     f"({_by_reason(dropped)})"))
    s = now.slips
    last = "never" if s.last_stamp_ns is None else f"{s.last_stamp_ns * 1e-9:.3f}"
    return [
        ("imu", "silent (wheels only)" if now.silent else "gyro-aided"),
        ("imu samples", str(now.samples)),
        *_counts("imu dropped", now.dropped, dropped),
        ("slip events", str(s.events)),
        ("slip steps", str(s.steps)),
        ("last slip [stamp s]", last),
        ("last slip size [rad]", f"{_finite(s.last_size):.6f}"),
        ("slip heading total [rad]", f"{_finite(s.total_size):.6f}"),
        ("gyro bias [rad/s]", f"{_finite(now.bias):.6g}"),
        ("gyro bias stddev [rad/s]", f"{_finite(now.bias_stddev):.6g}"),
        ("zero-velocity updates", str(now.zero_velocity_updates)),
    ]


# --- cmd_vel_node --------------------------------------------------------------------


class CommandState(Enum):
    """What the watchdog lets through: the values are what the report shows."""

    NEVER = "never commanded"
    COMMANDING = "commanding"
    TIMED_OUT = "timed out"


@dataclass(frozen=True)
class CommandHealth:
    """A snapshot of the cmd_vel node; counters are cumulative since the start.

    ``limited`` counts the commands whose following was changed by each limit (a
    command counts once per limit); ``dropped`` the commands refused, by reason
    ("non_finite", "stale_stamp", "implausible"). ``last_command_moving`` says whether the last
    accepted command asked for motion: a watchdog stop then means the sender went
    silent mid-motion.
    """

    state: CommandState
    command_age_s: float | None
    last_command_moving: bool
    limited: Mapping[str, int]
    dropped: Mapping[str, int]
    command_rate_hz: float
    output_rate_hz: float
    expected_output_hz: float
    timeout_s: float


# Below this fraction of wheel_command_rate the heartbeat drivers watch is late.
MIN_OUTPUT_FRACTION = 0.5


def cmd_vel_report(now: CommandHealth, before: CommandHealth | None = None) -> Report:
    """The cmd_vel node's health; ``before`` is the previous report's snapshot."""
    problems: list[tuple[Level, str]] = []
    if now.state is CommandState.TIMED_OUT and now.last_command_moving:
        problems.append((Level.WARN, f"stopped by the watchdog: no command for "
                                     f"{_finite(now.command_age_s or 0.0):.1f} s while moving"))
    dropped = _since(now.dropped, before.dropped if before else None)
    if any(dropped.values()):
        problems.append((Level.WARN, f"dropped {sum(dropped.values())} commands "
                                     f"({_by_reason(dropped)})"))
    out_rate = _finite(now.output_rate_hz)
    if out_rate < MIN_OUTPUT_FRACTION * now.expected_output_hz:
        problems.append((Level.WARN, f"wheel commands at {out_rate:.1f} Hz, "
                                     f"expected {now.expected_output_hz:g} Hz"))
    limited = _since(now.limited, before.limited if before else None)
    if now.state is CommandState.COMMANDING:
        ok = "commanding" + (f" (limited: {_by_reason(limited)})" if any(limited.values())
                             else "")
    elif now.state is CommandState.TIMED_OUT:
        ok = "idle: timed out, publishing zeros"
    else:
        ok = "never commanded: publishing zeros"
    level, message = _verdict(problems, ok)
    values = [
        ("state", now.state.value),
        ("command age [s]", _seconds(None if now.command_age_s is None
                                     else _finite(now.command_age_s))),
        ("cmd_vel_timeout [s]", f"{now.timeout_s:g}"),
        ("last command moving", "true" if now.last_command_moving else "false"),
        ("command rate [Hz]", f"{_finite(now.command_rate_hz):.1f}"),
        ("output rate [Hz]", f"{out_rate:.1f}"),
        ("expected output rate [Hz]", f"{now.expected_output_hz:g}"),
        *_counts("limited", now.limited, limited),
        *_counts("dropped", now.dropped, dropped),
    ]
    return Report(level, message, tuple(values))


# --- path_follower_node --------------------------------------------------------------


class FollowerState(Enum):
    """What the path follower is doing: the values are what the report shows."""

    NO_PATH = "no path"
    WAITING = "waiting for odometry"
    FOLLOWING = "following"
    DONE = "done"


@dataclass(frozen=True)
class FollowerHealth:
    """A snapshot of the path follower; counters are cumulative since the start.

    ``dropped`` counts refused input by reason ("non_finite_odom", "bad_path",
    "path_frame"); ``near_singular`` and ``limited`` the control steps where the law
    had to be bounded (heading across the path, omega clipped).
    """

    state: FollowerState
    odom_age_s: float | None
    cross_track_error_m: float
    progress_m: float
    path_length_m: float
    speed_error_mps: float
    dropped: Mapping[str, int]
    near_singular: int
    limited: int
    stale_after_s: float = 0.5


def follower_report(now: FollowerHealth, before: FollowerHealth | None = None) -> Report:
    """The path follower's health; ``before`` is the previous report's snapshot."""
    problems: list[tuple[Level, str]] = []
    age = now.odom_age_s
    if now.state is FollowerState.FOLLOWING and age is not None and age >= now.stale_after_s:
        problems.append((Level.WARN, f"no odometry for {_finite(age):.2f} s while following"))
    dropped = _since(now.dropped, before.dropped if before else None)
    if any(dropped.values()):
        problems.append((Level.WARN, f"dropped {sum(dropped.values())} messages "
                                     f"({_by_reason(dropped)})"))
    singular = now.near_singular - (before.near_singular if before else 0)
    if singular:
        problems.append((Level.WARN, f"{singular} steps heading across the path "
                                     "(law bounded)"))
    ok = now.state.value
    if now.state is FollowerState.FOLLOWING:
        ok += f": cross-track {_finite(now.cross_track_error_m):+.3f} m"
    level, message = _verdict(problems, ok)
    length = now.path_length_m
    values = [
        ("state", now.state.value),
        ("odometry age [s]", _seconds(None if age is None else _finite(age))),
        ("cross-track error [m]", f"{_finite(now.cross_track_error_m):.4f}"),
        ("progress [m]", f"{_finite(now.progress_m):.3f}"),
        ("path length [m]", "endless" if math.isinf(length) else f"{_finite(length):.3f}"),
        ("speed error [m/s]", f"{_finite(now.speed_error_mps):.4f}"),
        ("steps near singular (total)", str(now.near_singular)),
        ("steps omega limited (total)", str(now.limited)),
        *_counts("dropped", now.dropped, dropped),
    ]
    return Report(level, message, tuple(values))


# --- sim_node ------------------------------------------------------------------------


@dataclass(frozen=True)
class SimHealth:
    """A snapshot of the simulated base; counters are cumulative since the start.

    ``command_age_s`` is in simulated seconds (the sim's watchdog runs on its own time);
    ``step_rate_hz`` counts the joint_states published per wall second against
    ``expected_step_hz`` (``joint_state_rate``, times ``real_time_factor`` when the sim
    owns the clock): a machine too slow for the asked real-time factor shows there.
    ``dropped`` counts the wheel commands refused, by reason.
    """

    state: CommandState
    command_age_s: float | None
    last_command_moving: bool
    command_rate_hz: float
    step_rate_hz: float
    expected_step_hz: float
    timeout_s: float
    sim_time_s: float
    distance_m: float
    dropped: Mapping[str, int]


def sim_report(now: SimHealth, before: SimHealth | None = None) -> Report:
    """The simulated base's health; ``before`` is the previous report's snapshot."""
    problems: list[tuple[Level, str]] = []
    if now.state is CommandState.TIMED_OUT and now.last_command_moving:
        problems.append((Level.WARN, "stopped by the watchdog: no wheel command for "
                                     f"{_finite(now.command_age_s or 0.0):.1f} s while moving"))
    dropped = _since(now.dropped, before.dropped if before else None)
    if any(dropped.values()):
        problems.append((Level.WARN, f"dropped {sum(dropped.values())} wheel commands "
                                     f"({_by_reason(dropped)})"))
    step_rate = _finite(now.step_rate_hz)
    if step_rate < MIN_OUTPUT_FRACTION * now.expected_step_hz:
        problems.append((Level.WARN, f"simulating at {step_rate:.1f} steps/s, expected "
                                     f"{now.expected_step_hz:g} (too slow for the asked rate)"))
    ok = {CommandState.NEVER: "idle: never commanded",
          CommandState.COMMANDING: "following wheel commands",
          CommandState.TIMED_OUT: "idle: wheel commands timed out, wheels stopped"}[now.state]
    level, message = _verdict(problems, ok)
    values = [
        ("state", now.state.value),
        ("command age [s]", _seconds(None if now.command_age_s is None
                                     else _finite(now.command_age_s))),
        ("command_timeout [s]", f"{now.timeout_s:g}"),
        ("last command moving", "true" if now.last_command_moving else "false"),
        ("command rate [Hz]", f"{_finite(now.command_rate_hz):.1f}"),
        ("step rate [Hz]", f"{step_rate:.1f}"),
        ("expected step rate [Hz]", f"{now.expected_step_hz:g}"),
        ("simulated time [s]", f"{_finite(now.sim_time_s):.3f}"),
        ("distance [m]", f"{_finite(now.distance_m):.3f}"),
        *_counts("dropped", now.dropped, dropped),
    ]
    return Report(level, message, tuple(values))
