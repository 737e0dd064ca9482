"""odometry_node over DDS publishes at min(publish_rate, input rate), within 1 %.

A driver on its own clock (test/oracle.py: phase, jitter, a rate that divides nothing)
sends 10.5 s of stamp time, paced by the node's answers so nothing is lost on loopback
however long the node or this test stalls; a last reading after a pause (which the
schedule always publishes) marks the end, and the test holds until it is seen.
Expected: the closed form min(publish_rate, input rate), the input rate measured on the
stamps sent.
"""

from __future__ import annotations

import pytest

from oracle import mean_rate, sensor_clock
from rosutil import T0_NS, OdomRigs, ns_of, reading, send_first, spin_until

pytestmark = [pytest.mark.dds, pytest.mark.process]

# Readings in flight at most: well within the node's best-effort joint_states queue of
# 100; and, as the node answers at most one odometry per reading, fewer than 10 odoms
# are ever unread here: within this sink's 50 and the odom writer's keep-last 10 (a
# keep-last writer may discard an unacknowledged sample once 10 newer are written). A
# stall of the node or of this test then holds the sending instead of overflowing a
# queue, and what is published depends on the stamps alone (the gate runs on stamp
# time). A published reading is at most 4 readings after the one before (150 Hz at 50,
# 100 Hz at 30), so one of the last 8 sent is always answered.
WINDOW = 8


@pytest.mark.parametrize(("hz", "jitter", "rate"), [(150.0, 1e-3, 50.0), (100.0, 0.0, 30.0),
                                                    (49.0, 1e-3, 50.0)])
def test_the_node_publishes_at_the_rate_asked(odom_rig: OdomRigs, hz: float, jitter: float,
                                              rate: float) -> None:
    _, out, _, ex, pub, sink = odom_rig("-p", f"publish_rate:={rate}",
                                        "-p", "enable_odom_tf:=false")
    stamps = sensor_clock(hz, 10.5, jitter, phase_s=0.0013, seed=3, t0_ns=T0_NS)

    def at(ns: int) -> list[float]:
        angle = (ns - stamps[0]) * 1e-9  # 1 rad/s on both wheels
        return [angle, angle]

    def answered(ns: int) -> bool:
        """The node has published a reading stamped ``ns`` or later (odom is in order)."""
        return bool(sink.odom) and ns_of(sink.odom[-1].header.stamp) >= ns

    send_first(ex, pub, sink, reading(stamps[0], at(stamps[0])))
    for k in range(1, len(stamps)):
        if k > WINDOW:  # paced by the node's answers, not by a sleep
            behind = stamps[k - WINDOW]
            assert spin_until(ex, lambda: answered(behind), 10.0), (  # noqa: B023
                f"no odometry at or after reading {k - WINDOW} of {len(stamps)}\n"
                + out.text())
        pub.publish(reading(stamps[k], at(stamps[k])))
    end = stamps[-1] + 300_000_000  # over 3 periods late: published whatever the schedule
    pub.publish(reading(end, at(end)))
    assert spin_until(ex, lambda: any(ns_of(o.header.stamp) == end for o in sink.odom),
                      10.0), out.text()
    got = sorted({ns_of(o.header.stamp) for o in sink.odom} - {end})
    assert set(got) <= set(stamps)
    assert mean_rate(got) == pytest.approx(min(rate, mean_rate(stamps)), rel=0.01)
