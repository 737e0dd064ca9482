"""odometry_node over DDS publishes at min(publish_rate, input rate), within 1 %.

A driver on its own clock (test/oracle.py: phase, jitter, a rate that divides nothing)
sends 10.5 s of stamp time, paced so nothing is lost on loopback; a last reading after
a pause (which the schedule always publishes) marks the end, and the test holds until
it is seen. Expected: the closed form min(publish_rate, input rate), the input rate
measured on the stamps sent.
"""

from __future__ import annotations

import pytest

from oracle import mean_rate, sensor_clock
from rosutil import T0_NS, OdomRigs, ns_of, reading, send_first, spin_for, spin_until

pytestmark = [pytest.mark.dds, pytest.mark.process]


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

    send_first(ex, pub, sink, reading(stamps[0], at(stamps[0])))
    for k, ns in enumerate(stamps[1:]):
        pub.publish(reading(ns, at(ns)))
        if k % 10 == 9:  # ten at a time: well within the node's queue of 100
            spin_for(ex, 0.01)
    end = stamps[-1] + 300_000_000  # over 3 periods late: published whatever the schedule
    pub.publish(reading(end, at(end)))
    assert spin_until(ex, lambda: any(ns_of(o.header.stamp) == end for o in sink.odom),
                      10.0), out.text()
    got = sorted({ns_of(o.header.stamp) for o in sink.odom} - {end})
    assert set(got) <= set(stamps)
    assert mean_rate(got) == pytest.approx(min(rate, mean_rate(stamps)), rel=0.01)
