"""The publish_rate gate: the rate users get is min(publish_rate, input rate), within 1 %.

Streams are drivers on their own clocks (test/oracle.py: a rate that divides nothing, a
phase, a uniform jitter); the expected rate is the closed form min(publish_rate, input
rate), the input rate measured on the stream itself. The array form (the fast lane's)
is checked against the scalar form pose by pose.
"""

from __future__ import annotations

import random
from pathlib import Path

import numpy as np
import pytest

from diffdrive_odom.core.estimation import gate as gate_module
from diffdrive_odom.core.estimation.gate import GateState, PublishGate
from diffdrive_odom.core.estimation.pipeline import ReadingPipeline
from diffdrive_odom.tools.cmdline.args import load_settings

from bagutil import write_params
from oracle import mean_rate, sensor_clock

# (input rate [Hz], jitter [s], publish_rate [Hz]): the cases and a few more.
CASES = [(150.0, 1e-3, 50.0), (100.0, 0.0, 30.0), (49.0, 1e-3, 50.0), (1000.0, 0.0, 50.0),
         (60.0, 1e-3, 25.0), (97.3, 2e-3, 20.0), (333.0, 0.5e-3, 100.0), (20.0, 0.0, 5.0)]


def _published(rate: float, stamps: list[int]) -> list[int]:
    gate = PublishGate(rate)
    return [s for s in stamps if gate.due(s)]


@pytest.mark.parametrize(("hz", "jitter", "rate"), CASES)
def test_the_rate_users_get_is_the_lesser_of_the_two(hz: float, jitter: float,
                                                     rate: float) -> None:
    stamps = sensor_clock(hz, 12.0, jitter, phase_s=0.0037, seed=int(hz))
    out = _published(rate, stamps)
    want = min(rate, mean_rate(stamps))
    assert mean_rate(out) == pytest.approx(want, rel=0.01)
    assert set(out) <= set(stamps)  # only real readings go out


def test_a_pause_is_no_burst_and_time_going_back_restarts() -> None:
    """After 2 s without readings the schedule starts again at the next reading."""
    a = sensor_clock(200.0, 3.0, 1e-3, seed=1)
    b = [s + 5 * 10**9 for s in sensor_clock(200.0, 3.0, 1e-3, seed=2)]
    out = _published(50.0, a + b)
    after = [s for s in out if s >= b[0]]
    assert after[0] == b[0]  # the first reading after the pause goes out ...
    gaps = np.diff(after)
    assert gaps.min() > 20e6 - 2 * 6e6  # ... and none crowds it: less than a reading early
    assert mean_rate(after) == pytest.approx(50.0, rel=0.01)
    # A stamp before the last published one (a bag looping) is published at once.
    gate = PublishGate(10.0)
    assert [gate.due(s) for s in (100 * 10**6, 150 * 10**6, 50 * 10**6, 60 * 10**6)] == [
        True, False, True, False]


def test_rate_zero_publishes_every_pose() -> None:
    stamps = sensor_clock(97.0, 1.0, 1e-3)
    assert _published(0.0, stamps) == stamps
    assert PublishGate(0.0).passed(stamps).tolist() == list(range(len(stamps)))


def _stream(rng: random.Random) -> list[int]:
    """Stamps with every oddity: pauses, repeats, time going back, a 1 us early stamp."""
    t, out = 10**9, []
    for _ in range(rng.randrange(1, 400)):
        r = rng.random()
        if r < 0.02:
            t += rng.randrange(1, 3 * 10**9)  # a pause
        elif r < 0.04:
            t -= rng.randrange(0, 10**9)  # time goes back (or repeats)
        elif r < 0.06:
            t += 20_000_000 - 1000  # one period of 50 Hz, less the slack
        else:
            t += rng.randrange(1, 30_000_000)
        out.append(t)
    return out


@pytest.mark.parametrize("array_from", [0.0, gate_module.ARRAY_FROM])
@pytest.mark.parametrize("seed", range(60))
def test_the_array_form_is_the_scalar_form(monkeypatch: pytest.MonkeyPatch, seed: int,
                                           array_from: float) -> None:
    """passed() over random chunks, handing the state on, publishes what due() does.

    ``array_from`` 0: every chunk in array form, however sparse its readings.
    """
    monkeypatch.setattr(gate_module, "ARRAY_FROM", array_from)
    rng = random.Random(seed)
    stamps = _stream(rng)
    rate = rng.choice([0.0, 7.3, 30.0, 50.0, 100.0, 1e6])
    scalar = PublishGate(rate)
    want = [k for k, s in enumerate(stamps) if scalar.due(s)]
    got: list[int] = []
    state = GateState()
    k = 0
    while k < len(stamps):
        n = rng.randrange(1, 80)
        gate = PublishGate(rate, state)
        got += (gate.passed(stamps[k:k + n]) + k).tolist()
        state = gate.state
        k += n
    assert got == want
    assert state == scalar.state


def test_the_pipeline_publishes_on_the_schedule(tmp_path: Path) -> None:
    """Through the one reading path: 100 Hz readings at publish_rate 30 give 30 Hz, not 25."""
    settings = load_settings(write_params(tmp_path / "p.yaml", {
        "wheel_radius": 0.1, "wheel_separation": 0.4, "publish_rate": 30.0}))
    pipe = ReadingPipeline(settings)
    stamps = sensor_clock(100.0, 10.0, phase_s=0.001)
    names = ["left_wheel_joint", "right_wheel_joint"]
    out = [s for k, s in enumerate(stamps)
           if pipe.feed(s, names, [0.01 * k, 0.01 * k]).publish]
    assert mean_rate(out) == pytest.approx(30.0, rel=0.01)
    assert pipe.stats.published == len(out)
