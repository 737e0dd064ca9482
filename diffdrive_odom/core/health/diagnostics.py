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
from enum import IntEnum
from typing import Generic, TypeVar

from diffdrive_odom.core.estimation.gyro.standstill import STAND_WARN_S
from diffdrive_odom.core.estimation.online.online_estimate import CHI2_2DOF_3SIGMA, OnlineEstimate
from diffdrive_odom.core.estimation.results import GyroStats

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


def seconds_text(value: float | None) -> str:
    """A time for a report: seconds with ms, or "never"."""
    return "never" if value is None else f"{value:.3f}"


def finite(value: float) -> float:
    """Reports never carry NaN/inf (a bad input must not poison the monitor)."""
    return value if math.isfinite(value) else 0.0


def increase_since(now: Mapping[str, int], before: Mapping[str, int] | None) -> dict[str, int]:
    """Per-key increase since the previous report (all of it at the first report)."""
    return {k: v - (before.get(k, 0) if before is not None else 0) for k, v in now.items()}


def count_values(label: str, totals: Mapping[str, int], recent: Mapping[str, int]
            ) -> list[tuple[str, str]]:
    """A counter's report rows: its total, its increase, and each reason's total."""
    values = [(f"{label} (total)", str(sum(totals.values()))),
              (f"{label} since last report", str(sum(recent.values())))]
    values += [(f"{label}: {k}", str(v)) for k, v in totals.items()]
    return values


def by_reason_text(counts: Mapping[str, int]) -> str:
    """The non-zero counts of a report message, by reason."""
    return ", ".join(f"{k} {v}" for k, v in counts.items() if v)


def dropped_since(now: Mapping[str, int], before: Mapping[str, int] | None, what: str,
                  problems: list[tuple[Level, str]]) -> dict[str, int]:
    """The drops by reason since the last report, and a WARN naming them if there are any."""
    dropped = increase_since(now, before)
    if any(dropped.values()):
        problems.append((Level.WARN, f"dropped {sum(dropped.values())} {what} "
                                     f"({by_reason_text(dropped)})"))
    return dropped


def worst_verdict(problems: list[tuple[Level, str]], ok_message: str) -> tuple[Level, str]:
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
    # the re-anchors with a likely cause, by its text (which names the fixing parameter)
    causes: Mapping[str, int] = field(default_factory=dict)
    gap_reanchors: int = 0
    gaps_integrated: int = 0  # gaps in the readings whose motion was integrated
    time_resets: int = 0
    velocity_fallback: bool = False
    gyro: GyroStats | None = None  # use_imu true: the gyro's counters and slip events
    online: OnlineEstimate | None = None  # online_calibration monitor|apply (use_imu)


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
    dropped = dropped_since(now.dropped, before.dropped if before else None, "readings",
                            problems)
    def recent(count: Callable[[ReadingHealth], int]) -> int:
        return count(now) - (count(before) if before is not None else 0)

    reanchors = recent(lambda h: h.reanchors)
    gap_reanchors = recent(lambda h: h.gap_reanchors)
    gaps = recent(lambda h: h.gaps_integrated)
    time_resets = recent(lambda h: h.time_resets)
    causes = increase_since(now.causes, before.causes if before else None)
    if reanchors:
        cause = max(causes, key=lambda k: causes[k]) if any(causes.values()) else ""
        problems.append((Level.WARN, f"{reanchors} re-anchors (implausible step"
                                     + (f"; {cause})" if cause else ")")))
    if gap_reanchors:
        problems.append((Level.WARN, f"{gap_reanchors} re-anchors after a gap"))
    if gaps:
        problems.append((Level.WARN, f"{gaps} gaps in the readings, their motion integrated "
                                     "from the counts"))
    if time_resets:
        problems.append((Level.WARN, f"{time_resets} time resets (stamp jumped back)"))
    gyro_values = _gyro(now.gyro, before.gyro if before else None, problems)
    gyro_values += _online(now.online, problems)
    if since is None and not problems:
        ok = "starting: waiting for the first reading"
    else:
        ok = "integrating wheel velocities" if now.velocity_fallback else "integrating"
        ok += ", gyro-aided" if now.gyro is not None else ""
    level, message = worst_verdict(problems, ok)
    values = [
        ("reading rate [Hz]", f"{finite(now.reading_rate_hz):.1f}"),
        ("last reading [s ago]", seconds_text(since)),
        *count_values("dropped", now.dropped, dropped),
        ("re-anchors (implausible step)", str(now.reanchors)),
        *((f"re-anchors: {cause}", str(count)) for cause, count in now.causes.items()),
        ("re-anchors after a gap", str(now.gap_reanchors)),
        ("gaps integrated", str(now.gaps_integrated)),
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
    if now.standing_s >= STAND_WARN_S and now.zero_velocity_updates == 0:
        problems.append((Level.WARN, f"stood still {now.standing_s:.1f} s, no zero-velocity "
                                     "update: gyro bias not estimated (IMU stamps?)"))
    dropped = dropped_since(now.dropped, before.dropped if before else None, "IMU samples",
                            problems)
    s = now.slips
    last = "never" if s.last_stamp_ns is None else f"{s.last_stamp_ns * 1e-9:.3f}"
    return [
        ("imu", "silent (wheels only)" if now.silent else "gyro-aided"),
        ("imu samples", str(now.samples)),
        *count_values("imu dropped", now.dropped, dropped),
        ("slip events", str(s.events)),
        ("slip steps", str(s.steps)),
        ("last slip [stamp s]", last),
        ("last slip size [rad]", f"{finite(s.last_size):.6f}"),
        ("slip heading total [rad]", f"{finite(s.total_size):.6f}"),
        ("gyro bias [rad/s]", f"{finite(now.bias):.6g}"),
        ("gyro bias stddev [rad/s]", f"{finite(now.bias_stddev):.6g}"),
        ("zero-velocity updates", str(now.zero_velocity_updates)),
        ("standing still [s]", f"{finite(now.standing_s):.1f}"),
        ("wheel stamp jitter [ms]", f"{finite(now.jitter * 1e3):.1f}"),
        ("imu lag [ms]", "not measured" if now.lag is None
         else f"{finite(now.lag.lag * 1e3):+.0f} +- {finite(now.lag.sigma * 1e3):.0f}"),
        ("imu lag", "" if now.lag is None else now.lag.line(now.jitter)),
    ]


def _online(est: OnlineEstimate | None, problems: list[tuple[Level, str]]
            ) -> list[tuple[str, str]]:
    """The online geometry estimate; WARN while the configured one is outside its 3 sigma."""
    if est is None:
        return []
    if est.outside:
        problems.append((Level.WARN, "configured geometry outside the online estimate's "
                                     "3-sigma region: the robot changed, recalibrate"))
    names = ("left_wheel_radius_multiplier", "right_wheel_radius_multiplier",
             "wheel_separation_multiplier")
    return [
        ("online calibration", "determined" if est.determined else "not yet determined"),
        ("online estimate applied", "true" if est.applied else "false"),
        *((f"{n} (online estimate)", f"{m:.5f} +- {sd:.5f}")
          for n, m, sd in zip(names, est.multipliers, est.stddevs, strict=True)),
        ("online Mahalanobis d^2 of configured geometry",
         f"{finite(est.mahalanobis2):.2f} (warn above {CHI2_2DOF_3SIGMA:.2f})"),
        ("online turned left / right [rad]", f"{est.turned[0]:.2f} / {est.turned[1]:.2f}"),
        ("online distance [m]", f"{est.distance:.1f}"),
        ("online steps used", str(est.steps)),
        *((f"online steps excluded: {k}", str(v)) for k, v in est.excluded.items()),
        *_scale(est),
    ]


def _scale(est: OnlineEstimate) -> list[tuple[str, str]]:
    """The scale: the configured one (no reference topic, said so) or the reference's."""
    sc = est.scale
    if sc is None:
        return [("online scale", "configured (no reference topic): mean radius held, gyro "
                                 "scale factor taken as 1")]
    names = ("left_wheel_radius_multiplier", "right_wheel_radius_multiplier",
             "wheel_separation_multiplier")
    return [
        ("online scale", "from the reference: " + (
            "determined" if sc.determined else "not yet determined")),
        *((f"{n} (with the reference)", f"{m:.5f} +- {sd:.5f}")
          for n, m, sd in zip(names, sc.multipliers, sc.stddevs, strict=True)),
        ("mean radius multiplier (reference)", "{:.5f} +- {:.5f}".format(*sc.mean_radius)),
        ("gyro scale factor (reference)", "{:.5f} +- {:.5f}".format(*sc.gyro_scale)),
        ("reference poses / windows", f"{sc.poses} / {sc.windows}"),
        ("reference distance [m] / turned [rad]", f"{sc.distance:.1f} / {sc.turned:.1f}"),
        *((f"reference excluded: {k}", str(v)) for k, v in sc.excluded.items()),
    ]
