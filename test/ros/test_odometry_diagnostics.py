"""odometry_node's /diagnostics over real DDS: what an aggregator sees as the input changes.

The node runs as its own process; a peer subscribes ``/diagnostics`` and drives
``joint_states``. Expected levels follow from the documented thresholds (stale after
0.5 s, error after 5 s or no reading 5 s after start) and from the readings sent.
"""

from __future__ import annotations

import time

import pytest
from sensor_msgs.msg import JointState

from diagutil import Peer, assert_finite, diagnosed
from rosutil import STEP_NS, T0_NS, spin_for, spin_until, stamp

pytestmark = [pytest.mark.dds, pytest.mark.process, pytest.mark.serial]

GEOMETRY = ["-p", "wheel_radius:=0.1", "-p", "wheel_separation:=0.4"]
NAMES = ["left_wheel_joint", "right_wheel_joint"]
NAME = "odometry_node: odometry"
OK, WARN, ERROR = 0, 1, 2


def reading(k: int, names: list[str] = NAMES) -> JointState:
    msg = JointState()
    msg.header.stamp = stamp(T0_NS + k * STEP_NS)
    msg.name = list(names)
    msg.position = [0.01 * k, 0.01 * k]
    return msg


def stream(peer: Peer, pub: object, first: int, count: int, rate: float = 50.0) -> int:
    """Publish ``count`` good readings at ``rate``; returns the next index."""
    for k in range(first, first + count):
        pub.publish(reading(k))  # type: ignore[attr-defined]
        spin_for(peer.executor, 1.0 / rate)
    return first + count


def test_no_input_is_an_error_naming_it() -> None:
    with diagnosed("odometry_node", GEOMETRY) as peer:
        first = peer.wait_for(lambda s: True, 10.0)
        assert first.name == NAME and first.hardware_id == "none"
        assert first.level == OK and first.message.startswith("starting")
        assert first.values["last reading [s ago]"] == "never"
        err = peer.wait_for(lambda s: s.level == ERROR, 15.0)
    assert "no reading received" in err.message
    assert_finite(err)


def test_rate_drops_staleness_and_recovery() -> None:
    with diagnosed("odometry_node", GEOMETRY) as peer:
        pub = peer.node.create_publisher(JointState, "joint_states", 10)
        assert spin_until(peer.executor, lambda: pub.get_subscription_count() > 0, 15.0)
        # While readings flow: OK, integrating, at the rate they are really sent (the
        # sender's own rate is measured too: a loaded machine sends slower than asked).
        t0 = time.monotonic()
        k = stream(peer, pub, 0, 150)
        sent_hz = 150 / (time.monotonic() - t0)
        settled = [s for s in peer.statuses if s.received > t0 + 1.5]
        assert settled and all(s.level == OK and s.message == "integrating" for s in settled), (
            [s.message for s in peer.statuses])
        rates = sorted(float(s.values["reading rate [Hz]"]) for s in settled)
        assert 0.5 * sent_hz < rates[len(rates) // 2] < 1.5 * sent_hz, (rates, sent_hz)
        for s in settled:
            assert_finite(s)
        peer.cursor = len(peer.statuses)
        # Two readings without the configured joints: WARN naming the reason and count.
        for _ in range(2):
            pub.publish(reading(k, ["a", "b"]))
            k += 1
        k = stream(peer, pub, k, 5)
        warned = peer.wait_for(lambda s: s.level == WARN, 5.0)
        assert "missing_joint 2" in warned.message
        assert warned.values["dropped: missing_joint"] == "2"
        # The next report has no new drops: back to OK, the total kept.
        end = time.monotonic() + 6.0
        back = None
        while back is None and time.monotonic() < end:
            k = stream(peer, pub, k, 10)
            back = next((s for s in peer.statuses[peer.cursor:] if s.level == OK), None)
        assert back is not None and back.values["dropped: missing_joint"] == "2"
        # Silence: stale (WARN) before it becomes an error.
        peer.cursor = len(peer.statuses)
        stale = peer.wait_for(lambda s: s.level != OK, 5.0)
    assert stale.level == WARN and stale.message.startswith("stale"), stale.message
