"""The slip event rule (one place for the node, replay and the demo): its cases by hand."""

from __future__ import annotations

import math

import pytest

from diffdrive_odom.core.estimation.gyro.slips import MAX_RUN_S, MERGE_S, SlipEvents

MS = 1_000_000
LEAST = math.radians(0.5)


def feed(events: SlipEvents, steps: list[tuple[int, float]]) -> None:
    """Flagged steps (stamp in ms, the wheels' heading error [rad])."""
    for t, e in steps:
        events.step(True, t * MS, e)


def test_steps_close_together_are_one_event_of_their_summed_error() -> None:
    ev = SlipEvents(LEAST)
    feed(ev, [(1000, 0.004), (1020, 0.004), (1300, 0.004)])  # within MERGE_S: 0.012 rad
    ev.step(False, 1320 * MS, 0.0)  # an unflagged step ends nothing by itself
    feed(ev, [(1000 + round(MERGE_S * 1000) + 400, 0.02)])  # over MERGE_S later: another
    (t1, s1), (t2, s2) = ev.events
    assert (t1, t2, s2) == (1000 * MS, 1900 * MS, 0.02) and s1 == pytest.approx(0.012)
    s = ev.stats
    assert s.events == 2 and s.steps == 4 and s.total_size == pytest.approx(0.032)
    assert s.last_stamp_ns == 1900 * MS and s.last_size == 0.02


def test_a_single_tick_is_no_event_and_noise_both_ways_adds_to_none() -> None:
    ev = SlipEvents(LEAST)
    feed(ev, [(0, 0.0003)])  # one encoder tick at a standstill
    # A gyro noisier than declared: flagged steps every 20 ms, errors both ways.
    feed(ev, [(100 + 20 * k, 0.003 * (-1) ** k) for k in range(500)])
    assert ev.stats.events == 0 and ev.stats.steps == 501


def test_a_run_not_yet_an_event_starts_afresh_after_max_run_s() -> None:
    ev = SlipEvents(LEAST)
    per = LEAST / 150  # an error drifting one way, slower than any slip
    n = round(MAX_RUN_S * 1000 / 20)  # steps over MAX_RUN_S at 50 Hz
    feed(ev, [(20 * k, per) for k in range(3 * n)])
    assert ev.stats.events == 0  # each 2 s run sums to n * per = 100/150 of the threshold
    big = SlipEvents(LEAST)
    feed(big, [(20 * k, LEAST / 10) for k in range(30)])  # a real slip: 10 steps suffice
    (start, size), = big.events
    assert start == 0 and size == pytest.approx(3 * LEAST)
