"""The pure /diagnostics verdicts and the rate meter, with expectations worked by hand."""

from __future__ import annotations

import math

import pytest

from diffdrive_odom.core.commands.limits import (
    AxisLimits,
    CommandLimits,
    TwistLimiter,
)
from diffdrive_odom.core.geometry.kinematics import Geometry
from diffdrive_odom.core.health.base_diagnostics import CommandHealth, CommandState, cmd_vel_report
from diffdrive_odom.core.health.diagnostics import (
    Level,
    RateMeter,
    ReadingHealth,
    ReadingThresholds,
    Reporter,
    odometry_report,
)

# --- Level ---------------------------------------------------------------------------


def test_levels_are_diagnostic_msgs_bytes() -> None:
    # diagnostic_msgs/DiagnosticStatus: OK=0 WARN=1 ERROR=2 STALE=3.
    assert [int(x) for x in (Level.OK, Level.WARN, Level.ERROR, Level.STALE)] == [0, 1, 2, 3]


# --- RateMeter -----------------------------------------------------------------------


def test_rate_counts_the_last_window() -> None:
    m = RateMeter(start=0.0, window_s=1.0)
    for i in range(1, 31):  # 30 readings, every 0.1 s: t = 0.1 ... 3.0
        m.add(i * 0.1)
    # In (2.0, 3.0]: t = 2.1 ... 3.0, ten readings in one second.
    assert m.rate(3.0) == pytest.approx(10.0)
    # In (2.5, 3.5]: t = 2.6 ... 3.0, five readings.
    assert m.rate(3.5) == pytest.approx(5.0)
    # Nothing for more than a window: 0.
    assert m.rate(4.5) == 0.0


def test_rate_before_a_full_window_uses_the_elapsed_time() -> None:
    m = RateMeter(start=10.0, window_s=2.0)
    for t in (10.1, 10.2, 10.3, 10.4, 10.5):
        m.add(t)
    # 5 readings in the 0.5 s since the start: 10 Hz, not 5 / 2 s = 2.5 Hz.
    assert m.rate(10.5) == pytest.approx(10.0)
    assert m.rate(10.0) == 0.0  # no time elapsed yet


def test_rate_memory_is_one_window() -> None:
    m = RateMeter(start=0.0, window_s=0.01)
    for i in range(100_000):  # 1 kHz for 100 s
        m.add(i * 1e-3)
    assert len(m._times) <= 11  # 10 per 10 ms window (+ float slack)
    assert m.rate(99.999) == pytest.approx(1000.0, rel=0.11)


def test_rate_meter_refuses_a_bad_window() -> None:
    for bad in (0.0, -1.0, math.nan, math.inf):
        with pytest.raises(ValueError):
            RateMeter(start=0.0, window_s=bad)


# --- odometry_report -----------------------------------------------------------------

TH = ReadingThresholds(stale_after_s=0.5, error_after_s=5.0, startup_grace_s=3.0)


def health(**kw: object) -> ReadingHealth:
    base: dict[str, object] = {"uptime_s": 10.0, "reading_rate_hz": 100.0,
                               "since_last_reading_s": 0.01}
    base.update(kw)
    return ReadingHealth(**base)  # type: ignore[arg-type]


def test_odometry_ok_while_readings_flow() -> None:
    r = odometry_report(health(), None, TH)
    assert r.level is Level.OK
    assert r.message == "integrating"
    v = dict(r.values)
    assert v["reading rate [Hz]"] == "100.0"
    assert v["last reading [s ago]"] == "0.010"
    assert v["velocity fallback"] == "false"
    assert v["stale after [s]"] == "0.5"
    assert v["error after [s]"] == "5"


def test_odometry_warns_when_the_robot_stood_and_no_zero_velocity_update_ran() -> None:
    from diffdrive_odom.core.estimation.results import GyroStats

    ran = GyroStats(samples=400, silent=False, zero_velocity_updates=100, standing_s=2.0)
    r = odometry_report(health(gyro=ran), None, TH)
    assert r.level is Level.OK
    v = dict(r.values)
    assert v["zero-velocity updates"] == "100" and v["standing still [s]"] == "2.0"
    none = GyroStats(samples=400, silent=False, zero_velocity_updates=0, standing_s=2.0)
    r = odometry_report(health(gyro=none), None, TH)
    assert r.level is Level.WARN and "stood still 2.0 s, no zero-velocity update" in r.message
    short = GyroStats(samples=40, silent=False, zero_velocity_updates=0, standing_s=0.5)
    assert odometry_report(health(gyro=short), None, TH).level is Level.OK


def test_odometry_reports_the_online_estimate_and_warns_when_outside() -> None:
    from types import MappingProxyType

    from diffdrive_odom.core.estimation.online.online_estimate import OnlineEstimate
    from diffdrive_odom.core.estimation.results import GyroStats

    def estimate(outside: bool, determined: bool = True) -> OnlineEstimate:
        return OnlineEstimate(
            determined=determined, ratios=(0.165, 0.164), covariance=(1e-9, 0.0, 0.0, 1e-9),
            bias=0.0, bias_stddev=1e-4, multipliers=(0.9975, 1.0025, 1.0075),
            stddevs=(5e-5, 5e-5, 1.1e-4), mahalanobis2=40.0 if outside else 1.0,
            outside=outside, turned=(15.2, 9.6), distance=52.9, steps=7000, windows=290,
            excluded=MappingProxyType({"slip": 38, "standstill": 279}))

    gyro = GyroStats(samples=400, silent=False, zero_velocity_updates=100, standing_s=2.0)
    r = odometry_report(health(gyro=gyro, online=estimate(False)), None, TH)
    assert r.level is Level.OK
    v = dict(r.values)
    assert v["online calibration"] == "determined"
    assert v["right_wheel_radius_multiplier (online estimate)"] == "1.00250 +- 0.00005"
    assert v["wheel_separation_multiplier (online estimate)"] == "1.00750 +- 0.00011"
    assert v["online steps excluded: slip"] == "38"
    assert v["online turned left / right [rad]"] == "15.20 / 9.60"
    r = odometry_report(health(gyro=gyro, online=estimate(True)), None, TH)
    assert r.level is Level.WARN and "recalibrate" in r.message
    assert dict(r.values)["online Mahalanobis d^2 of configured geometry"].startswith("40.00")
    # The scale: the configured one, said so; or the reference's with its sigma.
    assert dict(r.values)["online scale"].startswith("configured (no reference topic)")
    from dataclasses import replace

    from diffdrive_odom.core.estimation.online.online_scale import ScaleEstimate
    scale = ScaleEstimate(determined=True, mean_radius=(1.0025, 0.0015),
                          gyro_scale=(1.01, 0.0013), multipliers=(1.0, 1.005, 1.01),
                          stddevs=(0.0015, 0.0015, 0.0021), poses=3000, windows=116,
                          distance=48.0, turned=24.0, excluded=MappingProxyType({"slip": 34}))
    v = dict(odometry_report(health(gyro=gyro, online=replace(estimate(False), scale=scale)),
                             None, TH).values)
    assert v["online scale"] == "from the reference: determined"
    assert v["wheel_separation_multiplier (with the reference)"] == "1.01000 +- 0.00210"
    assert v["gyro scale factor (reference)"] == "1.01000 +- 0.00130"
    assert v["mean radius multiplier (reference)"] == "1.00250 +- 0.00150"
    assert v["reference excluded: slip"] == "34"


def test_odometry_says_when_it_integrates_velocities() -> None:
    r = odometry_report(health(velocity_fallback=True), None, TH)
    assert (r.level, r.message) == (Level.OK, "integrating wheel velocities")
    assert dict(r.values)["velocity fallback"] == "true"


def test_odometry_no_reading_yet_is_ok_within_the_grace_then_error() -> None:
    r = odometry_report(health(uptime_s=2.9, since_last_reading_s=None), None, TH)
    assert (r.level, r.message) == (Level.OK, "starting: waiting for the first reading")
    assert dict(r.values)["last reading [s ago]"] == "never"
    r = odometry_report(health(uptime_s=3.0, since_last_reading_s=None), None, TH)
    assert (r.level, r.message) == (Level.ERROR, "no reading received in 3.0 s")


def test_odometry_stale_warns_and_long_silence_is_an_error() -> None:
    assert odometry_report(health(since_last_reading_s=0.49), None, TH).level is Level.OK
    r = odometry_report(health(since_last_reading_s=0.5), None, TH)
    assert (r.level, r.message) == (Level.WARN, "stale: no reading for 0.50 s")
    r = odometry_report(health(since_last_reading_s=5.0), None, TH)
    assert (r.level, r.message) == (Level.ERROR, "no reading for 5.0 s")


def test_odometry_drops_warn_only_when_recent() -> None:
    before = health(dropped={"zero_stamp": 2, "missing_joint": 0, "non_finite": 1})
    now = health(dropped={"zero_stamp": 5, "missing_joint": 0, "non_finite": 1})
    r = odometry_report(now, before, TH)
    assert (r.level, r.message) == (Level.WARN, "dropped 3 readings (zero_stamp 3)")
    v = dict(r.values)
    assert v["dropped (total)"] == "6"
    assert v["dropped since last report"] == "3"
    assert v["dropped: zero_stamp"] == "5"
    assert v["dropped: missing_joint"] == "0"
    assert v["dropped: non_finite"] == "1"
    # The next report with no new drop: OK again, totals kept.
    r = odometry_report(now, now, TH)
    assert r.level is Level.OK
    assert dict(r.values)["dropped (total)"] == "6"
    assert dict(r.values)["dropped since last report"] == "0"


def test_odometry_first_report_counts_everything_as_recent() -> None:
    r = odometry_report(health(dropped={"too_fast": 4}), None, TH)
    assert (r.level, r.message) == (Level.WARN, "dropped 4 readings (too_fast 4)")


def test_odometry_reanchors_and_time_resets_warn_when_recent() -> None:
    before = health(reanchors=1, gap_reanchors=2, time_resets=0)
    now = health(reanchors=3, gap_reanchors=3, time_resets=1)
    r = odometry_report(now, before, TH)
    assert r.level is Level.WARN
    assert r.message == ("2 re-anchors (implausible step); 1 re-anchors after a gap; "
                         "1 time resets (stamp jumped back)")
    v = dict(r.values)
    assert (v["re-anchors (implausible step)"], v["re-anchors after a gap"],
            v["time resets"]) == ("3", "3", "1")
    assert odometry_report(now, now, TH).level is Level.OK


def test_odometry_worst_problem_comes_first() -> None:
    r = odometry_report(health(since_last_reading_s=6.0, time_resets=1), None, TH)
    assert r.level is Level.ERROR
    assert r.message == "no reading for 6.0 s; 1 time resets (stamp jumped back)"


def test_odometry_values_are_finite_strings() -> None:
    r = odometry_report(health(reading_rate_hz=math.nan), None, TH)
    assert dict(r.values)["reading rate [Hz]"] == "0.0"


def test_reporter_remembers_the_previous_snapshot() -> None:
    rep: Reporter[ReadingHealth] = Reporter(lambda now, before: odometry_report(now, before, TH))
    first = health(dropped={"zero_stamp": 1})
    assert rep(first).level is Level.WARN  # 1 since the start
    assert rep(first).level is Level.OK  # nothing new since
    assert rep(health(dropped={"zero_stamp": 2})).message == "dropped 1 readings (zero_stamp 1)"


# --- cmd_vel_report ------------------------------------------------------------------

ZERO_LIMITED = {"velocity": 0, "acceleration": 0, "jerk": 0, "wheel_saturation": 0}
ZERO_DROPPED = {"non_finite": 0, "stale_stamp": 0}


def command(**kw: object) -> CommandHealth:
    base: dict[str, object] = {
        "state": CommandState.COMMANDING, "command_age_s": 0.02, "last_command_moving": True,
        "limited": ZERO_LIMITED, "dropped": ZERO_DROPPED, "command_rate_hz": 20.0,
        "output_rate_hz": 50.0, "expected_output_hz": 50.0, "timeout_s": 0.5}
    base.update(kw)
    return CommandHealth(**base)  # type: ignore[arg-type]


def test_cmd_vel_never_commanded() -> None:
    r = cmd_vel_report(command(state=CommandState.NEVER, command_age_s=None,
                               last_command_moving=False, command_rate_hz=0.0))
    assert (r.level, r.message) == (Level.OK, "never commanded: publishing zeros")
    v = dict(r.values)
    assert v["state"] == "never commanded"
    assert v["command age [s]"] == "never"
    assert v["cmd_vel_timeout [s]"] == "0.5"


def test_cmd_vel_commanding_and_limited() -> None:
    r = cmd_vel_report(command())
    assert (r.level, r.message) == (Level.OK, "commanding")
    before = command(limited={**ZERO_LIMITED, "velocity": 2})
    now = command(limited={**ZERO_LIMITED, "velocity": 5, "wheel_saturation": 1})
    r = cmd_vel_report(now, before)
    assert (r.level, r.message) == (Level.OK,
                                    "commanding (limited: velocity 3, wheel_saturation 1)")
    v = dict(r.values)
    assert v["limited (total)"] == "6"
    assert v["limited since last report"] == "4"
    assert v["limited: velocity"] == "5"
    assert v["limited: acceleration"] == "0"
    assert v["command rate [Hz]"] == "20.0"
    assert v["output rate [Hz]"] == "50.0"


def test_cmd_vel_timeout_warns_only_if_it_stopped_a_motion() -> None:
    r = cmd_vel_report(command(state=CommandState.TIMED_OUT, command_age_s=1.25,
                               last_command_moving=True))
    assert (r.level, r.message) == (
        Level.WARN, "stopped by the watchdog: no command for 1.2 s while moving")
    r = cmd_vel_report(command(state=CommandState.TIMED_OUT, command_age_s=1.25,
                               last_command_moving=False))
    assert (r.level, r.message) == (Level.OK, "idle: timed out, publishing zeros")
    assert dict(r.values)["state"] == "timed out"


def test_cmd_vel_dropped_commands_warn_when_recent() -> None:
    now = command(dropped={"non_finite": 2, "stale_stamp": 1})
    r = cmd_vel_report(now, command())
    assert (r.level, r.message) == (Level.WARN,
                                    "dropped 3 commands (non_finite 2, stale_stamp 1)")
    assert cmd_vel_report(now, now).level is Level.OK


def test_cmd_vel_late_heartbeat_warns() -> None:
    assert cmd_vel_report(command(output_rate_hz=25.0)).level is Level.OK  # exactly half
    r = cmd_vel_report(command(output_rate_hz=24.9))
    assert (r.level, r.message) == (Level.WARN, "wheel commands at 24.9 Hz, expected 50 Hz")


# --- limits say which bound acted ----------------------------------------------------

GEOM = Geometry(wheel_radius=0.1, wheel_separation=0.4)


def test_limiter_names_the_bound_that_changed_the_command() -> None:
    lim = TwistLimiter(CommandLimits(linear=AxisLimits(max_velocity=0.5)), GEOM)
    assert lim.step(0.4, 0.0, 0.02).limited == ()
    assert lim.step(1.0, 0.0, 0.02).limited == ("velocity",)
    lim = TwistLimiter(CommandLimits(linear=AxisLimits(max_acceleration=1.0)), GEOM)
    assert lim.step(1.0, 0.0, 0.02).limited == ("acceleration",)  # 1 m/s in 20 ms > 1 m/s^2
    lim = TwistLimiter(CommandLimits(linear=AxisLimits(max_jerk=1.0)), GEOM)
    assert lim.step(1.0, 0.0, 0.02).limited == ("jerk",)
    # 1 m/s straight on 0.1 m wheels is 10 rad/s > 5 rad/s.
    lim = TwistLimiter(CommandLimits(max_wheel_velocity=5.0), GEOM)
    out = lim.step(1.0, 0.0, 0.02)
    assert out.limited == ("wheel_saturation",)
    assert out.linear == pytest.approx(0.5)
