"""sim_node's /diagnostics, like every other node's: the pure report, then over real DDS.

Expectations come from the parameters given to the sim (joint_state_rate,
command_timeout) and diagnostic_updater's conventions ("<node>: <task>", 1 Hz).
"""

from __future__ import annotations

import time

import pytest
from std_msgs.msg import Float64MultiArray

from diffdrive_odom.core.health.base_diagnostics import CommandState, SimHealth, sim_report
from diffdrive_odom.core.health.diagnostics import Level

import diagutil
from diagutil import assert_finite
from rosutil import handshake, spin_for, spin_until

NAME = "sim_node: simulation"


def health(**changes: object) -> SimHealth:
    base = dict(state=CommandState.COMMANDING, command_age_s=0.02, last_command_moving=True,
                command_rate_hz=50.0, step_rate_hz=50.0, expected_step_hz=50.0,
                timeout_s=0.5, sim_time_s=12.0, distance_m=3.0, dropped={})
    base.update(changes)
    return SimHealth(**base)  # type: ignore[arg-type]


def test_the_report_says_what_the_sim_does() -> None:
    r = sim_report(health())
    assert (r.level, r.message) == (Level.OK, "following wheel commands")
    values = dict(r.values)
    assert values["state"] == "commanding" and values["command age [s]"] == "0.020"
    assert values["step rate [Hz]"] == "50.0" and values["expected step rate [Hz]"] == "50"
    assert values["simulated time [s]"] == "12.000" and values["distance [m]"] == "3.000"
    never = sim_report(health(state=CommandState.NEVER, command_age_s=None,
                              last_command_moving=False))
    assert never.level is Level.OK and dict(never.values)["command age [s]"] == "never"


def test_the_watchdog_drops_and_a_slow_machine_warn() -> None:
    stopped = sim_report(health(state=CommandState.TIMED_OUT, command_age_s=1.25))
    assert (stopped.level, stopped.message) == (
        Level.WARN, "stopped by the watchdog: no wheel command for 1.2 s while moving")
    resting = sim_report(health(state=CommandState.TIMED_OUT, last_command_moving=False))
    assert resting.level is Level.OK and "timed out" in resting.message
    before = health(dropped={"bad_array": 2})
    now = health(dropped={"bad_array": 5, "non_finite": 1})
    dropped = sim_report(now, before)
    assert dropped.message == "dropped 4 wheel commands (bad_array 3, non_finite 1)"
    assert dict(dropped.values)["dropped (total)"] == "6"
    assert sim_report(now, now).level is Level.OK  # nothing new since the last report
    slow = sim_report(health(step_rate_hz=30.0, expected_step_hz=200.0))
    assert slow.level is Level.WARN and "30.0 steps/s, expected 200" in slow.message


@pytest.mark.dds
@pytest.mark.process
@pytest.mark.serial
def test_sim_node_publishes_its_health_on_diagnostics() -> None:
    """Never commanded, then a malformed command (dropped), then driving and silence:
    the watchdog stops the wheels and the status says so. On main sim_node had no
    /diagnostics at all."""
    args = ["-p", "joint_state_rate:=50.0", "-p", "command_timeout:=0.5"]
    with diagutil.diagnosed("sim_node", args) as peer:
        first = peer.wait_for(lambda s: s.name == NAME)
        assert first.level == 0 and first.hardware_id == "none", first
        assert first.values["state"] == "never commanded"
        assert first.values["command age [s]"] == "never"
        assert_finite(first)
        steady = peer.wait_for(lambda s: s.name == NAME)
        assert abs(float(steady.values["step rate [Hz]"]) - 50.0) < 10.0, steady.values
        pub = peer.node.create_publisher(Float64MultiArray, "wheel_commands", 10)
        assert spin_until(peer.executor, lambda: pub.get_subscription_count() > 0, 15.0)
        # The sim must have matched our writer too before the one malformed command.
        handshake(peer.node, peer.executor, "/sim_node")
        pub.publish(Float64MultiArray(data=[1.0, 1.0, 1.0]))  # three values for two wheels
        warned = peer.wait_for(lambda s: s.name == NAME and s.level == 1)
        assert warned.message == "dropped 1 wheel commands (bad_array 1)", warned
        end = time.monotonic() + 1.5
        while time.monotonic() < end:  # driving: 10 rad/s on both wheels at 20 Hz
            pub.publish(Float64MultiArray(data=[10.0, 10.0]))
            spin_for(peer.executor, 0.05)
        moving = peer.statuses[-1]
        assert moving.values["state"] == "commanding", moving
        assert float(moving.values["distance [m]"]) > 0.0
        stopped = peer.wait_for(lambda s: s.name == NAME and "watchdog" in s.message)
    assert stopped.level == 1 and stopped.values["state"] == "timed out"
    assert float(stopped.values["command age [s]"]) >= 0.5
    assert stopped.values["dropped: bad_array"] == "1"
    assert_finite(stopped)
