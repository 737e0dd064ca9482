"""Health reports of the nodes that move the base: cmd_vel_node, the follower, the sim.

Pure Python, beside :mod:`diffdrive_odom.core.health.diagnostics` (levels, rate meters, the
odometry node's report) whose helpers they share, so every node's verdict reads alike.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from enum import Enum
from typing import Protocol

from diffdrive_odom.core.health.diagnostics import (
    Level,
    Report,
    by_reason_text,
    count_values,
    dropped_since,
    finite,
    increase_since,
    seconds_text,
    worst_verdict,
)

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


class _Commanded(Protocol):
    """What the cmd_vel node and the simulated base both say of the commands they follow."""

    @property
    def state(self) -> CommandState: ...
    @property
    def command_age_s(self) -> float | None: ...
    @property
    def last_command_moving(self) -> bool: ...
    @property
    def timeout_s(self) -> float: ...


def _command_state(now: _Commanded, what: str, timeout_name: str,
                   problems: list[tuple[Level, str]]) -> list[tuple[str, str]]:
    """The command-state values both report, and the WARN when the watchdog stopped motion."""
    if now.state is CommandState.TIMED_OUT and now.last_command_moving:
        problems.append((Level.WARN, f"stopped by the watchdog: no {what} for "
                                     f"{finite(now.command_age_s or 0.0):.1f} s while moving"))
    return [
        ("state", now.state.value),
        ("command age [s]", seconds_text(None if now.command_age_s is None
                                     else finite(now.command_age_s))),
        (f"{timeout_name} [s]", f"{now.timeout_s:g}"),
        ("last command moving", "true" if now.last_command_moving else "false"),
    ]


def cmd_vel_report(now: CommandHealth, before: CommandHealth | None = None) -> Report:
    """The cmd_vel node's health; ``before`` is the previous report's snapshot."""
    problems: list[tuple[Level, str]] = []
    state = _command_state(now, "command", "cmd_vel_timeout", problems)
    dropped = dropped_since(now.dropped, before.dropped if before else None, "commands",
                            problems)
    out_rate = finite(now.output_rate_hz)
    if out_rate < MIN_OUTPUT_FRACTION * now.expected_output_hz:
        problems.append((Level.WARN, f"wheel commands at {out_rate:.1f} Hz, "
                                     f"expected {now.expected_output_hz:g} Hz"))
    limited = increase_since(now.limited, before.limited if before else None)
    if now.state is CommandState.COMMANDING:
        ok = "commanding" + (f" (limited: {by_reason_text(limited)})" if any(limited.values())
                             else "")
    elif now.state is CommandState.TIMED_OUT:
        ok = "idle: timed out, publishing zeros"
    else:
        ok = "never commanded: publishing zeros"
    level, message = worst_verdict(problems, ok)
    values = [
        *state,
        ("command rate [Hz]", f"{finite(now.command_rate_hz):.1f}"),
        ("output rate [Hz]", f"{out_rate:.1f}"),
        ("expected output rate [Hz]", f"{now.expected_output_hz:g}"),
        *count_values("limited", now.limited, limited),
        *count_values("dropped", now.dropped, dropped),
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
        problems.append((Level.WARN, f"no odometry for {finite(age):.2f} s while following"))
    dropped = dropped_since(now.dropped, before.dropped if before else None, "messages",
                            problems)
    singular = now.near_singular - (before.near_singular if before else 0)
    if singular:
        problems.append((Level.WARN, f"{singular} steps heading across the path "
                                     "(law bounded)"))
    ok = now.state.value
    if now.state is FollowerState.FOLLOWING:
        ok += f": cross-track {finite(now.cross_track_error_m):+.3f} m"
    level, message = worst_verdict(problems, ok)
    length = now.path_length_m
    values = [
        ("state", now.state.value),
        ("odometry age [s]", seconds_text(None if age is None else finite(age))),
        ("cross-track error [m]", f"{finite(now.cross_track_error_m):.4f}"),
        ("progress [m]", f"{finite(now.progress_m):.3f}"),
        ("path length [m]", "endless" if math.isinf(length) else f"{finite(length):.3f}"),
        ("speed error [m/s]", f"{finite(now.speed_error_mps):.4f}"),
        ("steps near singular (total)", str(now.near_singular)),
        ("steps omega limited (total)", str(now.limited)),
        *count_values("dropped", now.dropped, dropped),
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
    state = _command_state(now, "wheel command", "command_timeout", problems)
    dropped = dropped_since(now.dropped, before.dropped if before else None, "wheel commands",
                            problems)
    step_rate = finite(now.step_rate_hz)
    if step_rate < MIN_OUTPUT_FRACTION * now.expected_step_hz:
        problems.append((Level.WARN, f"simulating at {step_rate:.1f} steps/s, expected "
                                     f"{now.expected_step_hz:g} (too slow for the asked rate)"))
    ok = {CommandState.NEVER: "idle: never commanded",
          CommandState.COMMANDING: "following wheel commands",
          CommandState.TIMED_OUT: "idle: wheel commands timed out, wheels stopped"}[now.state]
    level, message = worst_verdict(problems, ok)
    values = [
        *state,
        ("command rate [Hz]", f"{finite(now.command_rate_hz):.1f}"),
        ("step rate [Hz]", f"{step_rate:.1f}"),
        ("expected step rate [Hz]", f"{now.expected_step_hz:g}"),
        ("simulated time [s]", f"{finite(now.sim_time_s):.3f}"),
        ("distance [m]", f"{finite(now.distance_m):.3f}"),
        *count_values("dropped", now.dropped, dropped),
    ]
    return Report(level, message, tuple(values))
