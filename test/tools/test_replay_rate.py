"""replay publishes at min(publish_rate, input rate), within 1 %, from a real bag.

The bags are written with rosbags (a JointState driver on its own clock: phase, jitter,
a rate that divides nothing), replayed through the CLI (the fast lane on) and read back
with mcap-ros2-support; the expected rate is the closed form min(publish_rate, input
rate), the input rate measured on the stamps written.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from diffdrive_odom.tools.bags import bagio, bagwriter
from diffdrive_odom.tools.cli import main as cli

from bagutil import mcap_messages, write_params
from oracle import mean_rate, sensor_clock


def _write(path: Path, stamps: list[int]) -> None:
    """A straight drive (1 rad/s on both wheels), logged 0.2 ms after each stamp."""
    with bagwriter.BagWriter(path) as w:
        w.add_topic("/joint_states", bagio.JOINT_STATE)
        t = w.typestore.types
        for ns in stamps:
            angle = (ns - stamps[0]) * 1e-9
            sec, nsec = divmod(ns, 10**9)
            w.write("/joint_states", ns + 200_000, t[bagio.JOINT_STATE](
                header=t["std_msgs/msg/Header"](
                    stamp=t["builtin_interfaces/msg/Time"](sec=sec, nanosec=nsec),
                    frame_id=""),
                name=["left_wheel_joint", "right_wheel_joint"],
                position=np.array([angle, angle]), velocity=np.zeros(0), effort=np.zeros(0)))


@pytest.mark.parametrize(("hz", "jitter", "rate"), [(150.0, 1e-3, 50.0), (100.0, 0.0, 30.0),
                                                    (49.0, 1e-3, 50.0), (60.0, 1e-3, 25.0)])
def test_replay_gets_the_rate_it_is_asked(tmp_path: Path, hz: float, jitter: float,
                                          rate: float) -> None:
    stamps = sensor_clock(hz, 11.0, jitter, phase_s=0.0021, seed=7)
    bag = tmp_path / "in"
    _write(bag, stamps)
    params = write_params(tmp_path / "p.yaml", {"wheel_radius": 0.1, "wheel_separation": 0.4,
                                                "publish_rate": rate, "enable_odom_tf": False})
    out = tmp_path / "out"
    assert cli(["replay", str(bag), "--params-file", str(params), "-o", str(out)]) == 0
    got = [int(m.header.stamp.sec) * 10**9 + int(m.header.stamp.nanosec)
           for _, _, m in mcap_messages(out, ["/odom"])]
    assert set(got) <= set(stamps)  # real readings only
    assert mean_rate(got) == pytest.approx(min(rate, mean_rate(stamps)), rel=0.01)
