"""cmd_vel_node's /diagnostics over real DDS: name, cadence, states and counters.

The node runs as its own process; a peer node subscribes ``/diagnostics`` as
diagnostic_aggregator does and drives ``cmd_vel``. Expectations come from the
parameters given to the node (timeout, max velocity) and from diagnostic_updater's
conventions (status "<node>: <task>", absolute /diagnostics topic, 1 Hz).
"""

from __future__ import annotations

import itertools
import math
import statistics
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

import pytest
from geometry_msgs.msg import Twist

import diagutil
from diagutil import Peer, Status, assert_finite
from rosutil import spin_for, spin_until

pytestmark = [pytest.mark.dds, pytest.mark.process, pytest.mark.serial]

GEOMETRY = ["-p", "wheel_radius:=0.1", "-p", "wheel_separation:=0.4"]
NAME = "cmd_vel_node: cmd_vel"


@contextmanager
def diagnosed(args: list[str]) -> Iterator[Peer]:
    with diagutil.diagnosed("cmd_vel_node", [*GEOMETRY, *args]) as peer:
        yield peer


def publish_for(peer: Peer, pub: Any, msg: Twist, seconds: float, rate: float = 20.0) -> None:
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        pub.publish(msg)
        spin_for(peer.executor, 1.0 / rate)


def publish_until(peer: Peer, pub: Any, msg: Twist, check: Callable[[Status], bool],
                  timeout: float = 10.0) -> Status:
    """Publish ``msg`` at about 20 Hz until a status passing ``check`` arrives."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        pub.publish(msg)
        try:
            return peer.wait_for(check, 0.05)
        except AssertionError:
            continue
    raise AssertionError("no such status arrived while publishing")


def twist(x: float) -> Twist:
    t = Twist()
    t.linear.x = x
    return t


def test_status_name_hardware_id_cadence_and_never_commanded() -> None:
    with diagnosed([]) as peer:
        assert spin_until(peer.executor, lambda: len(peer.statuses) >= 5, 20.0)
        spin_for(peer.executor, 0.1)
        statuses = list(peer.statuses)
    assert set(peer.arrays) == {1}  # one task, one status per array
    for s in statuses:
        assert s.name == NAME
        assert s.hardware_id == "none"
        assert s.level == 0
        assert s.values["state"] == "never commanded"
        assert s.values["command age [s]"] == "never"
        assert s.message == "never commanded: publishing zeros"
        assert_finite(s)
    # 1 Hz: stamps (taken by the node) 1 s apart; each within 0.5 s of that (load).
    stamp_gaps = [b.stamp_s - a.stamp_s for a, b in itertools.pairwise(statuses)]
    assert statistics.median(stamp_gaps) == pytest.approx(1.0, abs=0.05)
    assert all(0.5 < g < 1.5 for g in stamp_gaps), stamp_gaps
    assert abs(statuses[-1].stamp_s - time.time()) < 5.0  # stamped with the node's clock
    # The heartbeat is 50 Hz (the default wheel_command_rate) and is measured as such.
    assert abs(float(statuses[-1].values["output rate [Hz]"]) - 50.0) < 10.0


def test_commanding_limited_then_timed_out() -> None:
    args = ["-p", "linear.x.max_velocity:=0.5", "-p", "cmd_vel_timeout:=0.5"]
    with diagnosed(args) as peer:
        pub = peer.node.create_publisher(Twist, "cmd_vel", 10)
        assert spin_until(peer.executor, lambda: pub.get_subscription_count() > 0, 15.0)
        # Within the limit: commanding, nothing limited.
        # Held until a 1 Hz report sees it (CI once: 0.5 s of commands then the timeout,
        # all between two reports, and the state never read "commanding").
        publish_until(peer, pub, twist(0.2), lambda s: s.values["state"] == "commanding")
        publish_for(peer, pub, twist(0.2), 1.5)
        s = peer.wait_for(lambda s: s.values["state"] == "commanding", 5.0)
        assert s.values["limited: velocity"] == "0", s.values
        assert s.level == 0 and s.message == "commanding"
        assert float(s.values["command rate [Hz]"]) > 0.0
        # Beyond linear.x.max_velocity: the count of limited commands rises.
        publish_for(peer, pub, twist(1.0), 1.5)
        first = peer.wait_for(lambda s: int(s.values["limited: velocity"]) > 0, 5.0)
        publish_for(peer, pub, twist(1.0), 1.5)
        later = peer.wait_for(lambda s: int(s.values["limited: velocity"])
                              > int(first.values["limited: velocity"]), 5.0)
        assert later.values["state"] == "commanding"
        assert "limited: velocity" in later.message
        for other in ("acceleration", "jerk", "wheel_saturation"):
            assert later.values[f"limited: {other}"] == "0"
        # Silence: after cmd_vel_timeout the watchdog stops the moving robot, and says so.
        stopped_at = time.monotonic()
        timed_out = peer.wait_for(lambda s: s.values["state"] == "timed out", 5.0)
        assert timed_out.received - stopped_at > 0.5 - 0.05
        assert float(timed_out.values["command age [s]"]) > 0.5
        assert timed_out.level == 1
        assert timed_out.message.startswith("stopped by the watchdog")
        for s in (first, later, timed_out):
            assert s.name == NAME
            assert_finite(s)


def test_nan_and_implausible_twists_are_counted_as_dropped() -> None:
    with diagnosed([]) as peer:
        pub = peer.node.create_publisher(Twist, "cmd_vel", 10)
        assert spin_until(peer.executor, lambda: pub.get_subscription_count() > 0, 15.0)
        publish_for(peer, pub, twist(math.nan), 0.5)
        s = peer.wait_for(lambda s: int(s.values["dropped: non_finite"]) > 0, 10.0)
        assert s.level == 1
        assert s.message.startswith("dropped ") and "non_finite" in s.message
        assert s.values["state"] == "never commanded"  # a NaN is not a command
        assert s.values["dropped: stale_stamp"] == "0"
        assert s.values["dropped: implausible"] == "0"
        assert_finite(s)
        # No new drop: back to OK, the total kept (not reset). It may have grown since: the
        # 0.5 s burst can straddle two 1 Hz reports (a loaded run: 1, then 7 in all).
        total = int(s.values["dropped (total)"])
        calm = peer.wait_for(lambda s: s.values["dropped since last report"] == "0", 5.0)
        assert calm.level == 0 and int(calm.values["dropped (total)"]) >= total
        # 1e300 m/s = 1e301 rad/s at r = 0.1 m: finite, but beyond any wheel.
        publish_for(peer, pub, twist(1e300), 0.5)
        s = peer.wait_for(lambda s: int(s.values["dropped: implausible"]) > 0, 10.0)
        assert s.level == 1 and "implausible" in s.message
        assert s.values["state"] == "never commanded"
        assert_finite(s)


def test_namespace_is_in_the_name_and_the_topic_stays_absolute() -> None:
    with diagnosed(["-r", "__ns:=/robot1"]) as peer:
        s = peer.wait_for(lambda s: True, 15.0)
        assert s.name == "/robot1/cmd_vel_node: cmd_vel"
        assert s.hardware_id == "none"
        names = dict(peer.node.get_topic_names_and_types())
        assert "/diagnostics" in names
        assert "/robot1/diagnostics" not in names
        # and the node's own topics did move into the namespace
        assert spin_until(peer.executor, lambda: "/robot1/wheel_commands" in dict(
            peer.node.get_topic_names_and_types()), 10.0)
