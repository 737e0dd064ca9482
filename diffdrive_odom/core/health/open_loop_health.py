"""The ``/diagnostics`` status of ``odometry_node`` in open loop (``open_loop: true``).

Its message always begins "open loop": whoever reads the status must know the odometry
is the commanded velocity, not a measurement. Commands stopping is no fault (a robot at
rest gets none; the timeout stops the integration), so there is no "stale" verdict as
for encoder readings; refused commands and time resets warn for one report, as the
encoder status does. Pure Python.
"""

from __future__ import annotations

from dataclasses import dataclass

from diffdrive_odom.core.estimation.open_loop import OpenLoopStats
from diffdrive_odom.core.health.diagnostics import (
    Level,
    Report,
    count_values,
    dropped_since,
    finite,
    seconds_text,
)

OPEN_LOOP = "open loop"


@dataclass(frozen=True)
class OpenLoopHealth:
    """A snapshot of the open-loop input: the topic as resolved, rates, the core's counters."""

    topic: str
    command_rate_hz: float
    since_last_command_s: float | None
    timeout_s: float
    stats: OpenLoopStats


def open_loop_report(now: OpenLoopHealth, before: OpenLoopHealth | None = None) -> Report:
    """The status; ``before`` is the previous report's snapshot."""
    s = now.stats
    problems: list[tuple[Level, str]] = []
    dropped = dropped_since(s.dropped, before.stats.dropped if before else None, "commands",
                            problems)
    resets = s.time_resets - (before.stats.time_resets if before else 0)
    if resets:
        problems.append((Level.WARN, f"{resets} time resets (clock jumped back)"))
    if s.last_command_ns is None:
        state = "waiting for the first command"
    elif s.commanding:
        state = "following the command"
    else:
        state = (f"at rest: no command for cmd_vel_timeout ({now.timeout_s:g} s)"
                 if now.timeout_s > 0 else "at rest")
    message = f"{OPEN_LOOP}: odometry from the commanded velocity on {now.topic}, not measured"
    message += "; " + "; ".join(text for _, text in problems) if problems else f"; {state}"
    values = [
        ("mode", OPEN_LOOP),
        ("command topic", now.topic),
        ("command rate [Hz]", f"{finite(now.command_rate_hz):.1f}"),
        ("last command [s ago]", seconds_text(now.since_last_command_s)),
        ("commanding", "true" if s.commanding else "false"),
        ("commands", str(s.commands)),
        *count_values("dropped", s.dropped, dropped),
        ("time resets", str(s.time_resets)),
        ("cmd_vel_timeout [s]", f"{now.timeout_s:g}"),
    ]
    return Report(Level.WARN if problems else Level.OK, message, tuple(values))
