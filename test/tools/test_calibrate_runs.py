"""What calibrate's runs leave out is said (issue 39 item 4, calibrate's part).

Wrong joint names gave only ``fewer than 2 usable readings`` where replay names the
missing joints; a 16-bit counter's wraps, read with ``encoder_counter_bits`` 0, were
skipped as ``too_fast`` and left out of the fit in silence. The bag: ``gyrostreams``'
route (no IMU) with each wheel's angle as a 4096-count encoder on a signed 16-bit
counter that starts near its end, so it wraps; the wraps expected are counted here
from those counts.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from gyrostreams import TIMINGS, B, R, Route, stream, truth

from diffdrive_odom.tools.cli import main as cli

from bagutil import write_params, write_sensor_bag

TPR = 4096.0
BITS = 16
START = 30_000  # the counters' first count: near the end of the signed 16-bit range
ROUTE = Route(((12.0, 0.4, 0.0), (6.0, 0.3, 0.4), (8.0, 0.4, 0.0)))


def _wrapped(angle: float) -> float:
    count = round(angle * TPR / (2 * math.pi)) + START
    return float((count + 2**(BITS - 1)) % 2**BITS - 2**(BITS - 1))


@pytest.fixture(scope="module")
def tick_bag(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, int]:
    """The bag and how many of its steps wrap a counter (either wheel's)."""
    root = tmp_path_factory.mktemp("ticks")
    tr = truth(ROUTE)
    messages = [(k, rx, st, _wrapped(a), _wrapped(b)) if k == "j" else (k, rx, st, a, b)
                for k, rx, st, a, b in stream(ROUTE, TIMINGS[0], seed=3, tru=tr)]
    write_sensor_bag(root / "bag", messages, TIMINGS[0].imu_hz, truth=tr, imu=False)
    counts = np.array([m[3:5] for m in messages if m[0] == "j"])
    wraps = int(np.count_nonzero((np.abs(np.diff(counts, axis=0)) > 2**(BITS - 1)).any(axis=1)))
    return root / "bag", wraps


def _calibrate(bag: Path, capfd: pytest.CaptureFixture[str], **values: object,
               ) -> tuple[int, str, str]:
    params = write_params(bag.parent / "p.yaml", {
        "wheel_radius": R, "wheel_separation": B, "ticks_per_revolution": TPR, **values})
    code = cli(["calibrate", str(bag), "--params-file", str(params), "--reference-error", "0,0",
                "--force"])
    said = capfd.readouterr()
    return code, said.out, said.err


def test_a_wrapping_counter_read_without_its_width_is_said_with_its_cause(
        tick_bag: tuple[Path, int], capfd: pytest.CaptureFixture[str]) -> None:
    bag, wraps = tick_bag
    assert wraps >= 2  # the route wraps each wheel's counter at least once
    code, _, err = _calibrate(bag, capfd, encoder_counter_bits=0)
    assert code == 0, err
    said = [ln for ln in err.splitlines() if "too_fast" in ln]
    assert len(said) == 1, err
    assert said[0].startswith(f"[calibrate] bag: {wraps} x too_fast ("), said
    assert "the fit misses their motion" in said[0], said
    assert "encoder_counter_bits" in said[0] and "wrap" in said[0], said
    # The counter's width given: every step integrated, nothing said.
    code, _, err = _calibrate(bag, capfd, encoder_counter_bits=BITS)
    assert code == 0, err
    assert "too_fast" not in err, err


def test_wrong_joint_names_are_named_as_replay_names_them(
        tick_bag: tuple[Path, int], capfd: pytest.CaptureFixture[str]) -> None:
    bag, _ = tick_bag
    code, _, err = _calibrate(bag, capfd, encoder_counter_bits=BITS,
                              left_wheel_names=["wheel_left_joint"])
    assert code == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1, lines
    assert lines[0].startswith("[calibrate] bag: fewer than 2 usable readings on "
                               "/joint_states; "), lines
    assert "x missing_joint: joint_states lacks wheel joint(s) ['wheel_left_joint']" \
        in lines[0], lines
    assert "got names ['left_wheel_joint', 'right_wheel_joint']" in lines[0], lines
