"""Issue 39 item 4: a 16-bit counter read with ``encoder_counter_bits`` unset names its fix.

A driver reports a 16-bit counter (4096 counts a wheel turn) and the user left
``encoder_counter_bits`` unset: each wrap moves a wheel by 65536 counts (100.5 rad) in one
step, which ``max_wheel_speed`` skips as ``too_fast``. Before, replay said only
``12 x too_fast: wheel moved 100.4 rad in 0.02 s, over max_wheel_speed 200 rad/s; step
skipped``. The user's command (``diffdrive-odom replay``) and ``/diagnostics`` must name the
likely cause and the parameter that fixes it; with that parameter set, every step is
integrated (the closed form of the drive: one circle).
"""

from __future__ import annotations

import math
from pathlib import Path

import pytest
from gyrostreams import NAMES, T0

from diffdrive_odom.core.estimation.pipeline import ReadingPipeline
from diffdrive_odom.core.health.diagnostics import ReadingHealth, odometry_report
from diffdrive_odom.tools.cli import main as cli
from diffdrive_odom.tools.cmdline.args import load_settings

import oracle
from bagutil import write_params, write_sensor_bag

TICKS = 4096.0
SPAN = 65536  # a 16-bit counter
RATES = (40.0, 44.0)  # rad/s: 26075 and 28683 counts/s, a wrap every 2.5 and 2.3 s
PERIOD_NS = 20_000_000  # 50 Hz
READINGS = 1251  # 25 s
R, B = 0.05, 0.3
PARAMS = {"wheel_radius": R, "wheel_separation": B, "ticks_per_revolution": TICKS}


def counts(k: int) -> tuple[float, float]:
    """The counters at reading ``k``, as the driver reports them (unsigned 16-bit)."""
    t = k * PERIOD_NS * 1e-9
    return tuple(float(round(w * t * TICKS / (2 * math.pi)) % SPAN)  # type: ignore[return-value]
                 for w in RATES)


def wraps() -> int:
    """Readings at which either counter went back (wrapped): the steps to be skipped."""
    return sum(any(b < a for a, b in zip(counts(k - 1), counts(k), strict=True))
               for k in range(1, READINGS))


@pytest.fixture
def bag(tmp_path: Path) -> Path:
    path = tmp_path / "wrapping"
    write_sensor_bag(path, [("j", T0 + k * PERIOD_NS, T0 + k * PERIOD_NS, *counts(k))
                            for k in range(READINGS)], imu_hz=100.0, imu=False)
    return path


def test_replay_names_the_counter_wrap_and_its_parameter(
        tmp_path: Path, bag: Path, capsys: pytest.CaptureFixture[str]) -> None:
    params = write_params(tmp_path / "p.yaml", PARAMS)
    assert cli(["replay", str(bag), "--params-file", str(params),
                "--csv", str(tmp_path / "out.csv")]) == 0
    err = capsys.readouterr().err
    skipped = wraps()
    assert skipped >= 18, skipped  # the stream really wraps, both wheels
    line = next(x for x in err.splitlines() if "x too_fast:" in x)
    assert line.startswith(f"  {skipped} x too_fast: wheel moved "), err
    assert "likely a 16-bit counter wrapping (65536 counts = 100.5 rad)" in line, err
    assert "set encoder_counter_bits: 16" in line, err
    assert f"  {skipped} of the too_fast steps: likely a 16-bit counter wrapping" in err, err


def test_with_the_named_parameter_every_step_is_integrated(
        tmp_path: Path, bag: Path, capsys: pytest.CaptureFixture[str]) -> None:
    params = write_params(tmp_path / "p.yaml", {**PARAMS, "encoder_counter_bits": 16})
    out = tmp_path / "out.csv"
    assert cli(["replay", str(bag), "--params-file", str(params), "--csv", str(out)]) == 0
    assert "too_fast" not in capsys.readouterr().err
    last = out.read_text().strip().splitlines()[-1].split(",")
    # Each step one arc of the counts' differences, unwrapped here (closed forms).
    q = 2 * math.pi / TICKS
    steps = []
    for k in range(1, READINGS):
        dl, dr = ((b - a + SPAN / 2) % SPAN - SPAN / 2
                  for a, b in zip(counts(k - 1), counts(k), strict=True))
        steps.append((R * q * (dl + dr) / 2, R * q * (dr - dl) / B))
    x, y, _ = oracle.integrate(steps)
    assert float(last[2]) == pytest.approx(x, abs=1e-9)
    assert float(last[3]) == pytest.approx(y, abs=1e-9)


def test_diagnostics_name_the_counter_wrap_and_its_parameter(tmp_path: Path) -> None:
    """/diagnostics' report from the node's own counters (the same pipeline)."""
    pipe = ReadingPipeline(load_settings(write_params(tmp_path / "p.yaml", PARAMS)))
    for k in range(READINGS):
        pipe.feed(T0 + k * PERIOD_NS, NAMES, list(counts(k)))
    s = pipe.stats
    report = odometry_report(ReadingHealth(
        uptime_s=30.0, reading_rate_hz=50.0, since_last_reading_s=0.01,
        dropped=dict(s.dropped), reanchors=s.reanchors, causes=dict(s.causes),
        gap_reanchors=s.gap_reanchors, gaps_integrated=s.gaps_integrated,
        time_resets=s.time_resets))
    assert report.message == (
        f"{wraps()} re-anchors (implausible step; likely a 16-bit counter wrapping "
        "(65536 counts = 100.5 rad): set encoder_counter_bits: 16)")
    values = dict(report.values)
    assert values["re-anchors: likely a 16-bit counter wrapping (65536 counts = 100.5 rad): "
                  "set encoder_counter_bits: 16"] == str(wraps())


@pytest.mark.dds
@pytest.mark.process
def test_the_nodes_diagnostics_name_the_counter_wrap() -> None:
    """What ``ros2 topic echo /diagnostics`` shows: odometry_node fed the wrapping counters."""
    from sensor_msgs.msg import JointState

    from diagutil import diagnosed
    from rosutil import spin_for, spin_until, stamp

    args = ["-p", f"wheel_radius:={R}", "-p", f"wheel_separation:={B}",
            "-p", f"ticks_per_revolution:={TICKS}"]
    with diagnosed("odometry_node", args) as peer:
        pub = peer.node.create_publisher(JointState, "joint_states", 10)
        assert spin_until(peer.executor, lambda: pub.get_subscription_count() > 0, 15.0)
        for k in range(150):  # 3 s at 50 Hz: both counters wrap at least once
            msg = JointState()
            msg.header.stamp = stamp(T0 + k * PERIOD_NS)
            msg.name = list(NAMES)
            msg.position = list(counts(k))
            pub.publish(msg)
            spin_for(peer.executor, 0.02)
        warned = peer.wait_for(lambda s: "re-anchors" in s.message, 10.0)
    assert "likely a 16-bit counter wrapping" in warned.message, warned.message
    assert "set encoder_counter_bits: 16" in warned.message, warned.message
