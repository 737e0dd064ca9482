"""The open-loop /diagnostics status from plain numbers: always says "open loop"."""

from __future__ import annotations

from types import MappingProxyType

from diffdrive_odom.core.estimation.open_loop import OpenLoopStats
from diffdrive_odom.core.health.diagnostics import Level
from diffdrive_odom.core.health.open_loop_health import OpenLoopHealth, open_loop_report


def health(stats: OpenLoopStats, since: float | None = 0.1) -> OpenLoopHealth:
    return OpenLoopHealth("/cmd_vel", 20.0, since, 0.5, stats)


def test_states_are_named_and_at_rest_is_no_fault() -> None:
    waiting = open_loop_report(health(OpenLoopStats(), None))
    following = open_loop_report(health(OpenLoopStats(commands=5, last_command_ns=1,
                                                      commanding=True)))
    at_rest = open_loop_report(health(OpenLoopStats(commands=5, last_command_ns=1), 30.0))
    for r in (waiting, following, at_rest):
        assert r.level is Level.OK
        assert r.message.startswith("open loop: odometry from the commanded velocity on "
                                    "/cmd_vel, not measured")
        assert dict(r.values)["mode"] == "open loop"
    assert waiting.message.endswith("waiting for the first command")
    assert following.message.endswith("following the command")
    assert at_rest.message.endswith("no command for cmd_vel_timeout (0.5 s)")
    assert dict(at_rest.values)["last command [s ago]"] == "30.000"


def test_refused_commands_and_time_resets_warn_for_one_report() -> None:
    before = health(OpenLoopStats(commands=5, last_command_ns=1))
    now = health(OpenLoopStats(commands=9, dropped=MappingProxyType({"non_finite": 2}),
                               time_resets=1, last_command_ns=2))
    r = open_loop_report(now, before)
    assert r.level is Level.WARN
    assert "dropped 2 commands (non_finite 2)" in r.message and "1 time resets" in r.message
    assert r.message.startswith("open loop")
    assert open_loop_report(now, now).level is Level.OK
