"""Each gate of the wheels' rules counted on real runs, and what the ground truth says of it.

    .venv/bin/python bench/bench_gates.py [--quick]

Every real run (:mod:`realruns`: 47 OptiOdom, 7 PHIL; ``--quick``: 3) fed reading by
reading through the node's ``ReadingPipeline``, in five scenarios:

- ``real``: the run as recorded, defaults (nominal geometry);
- ``real, top speed``: the same with ``max_wheel_speed`` at 1.5 times the robot's top
  wheel speed (OptiOdom 10 rad/s; the Kobuki 30 rad/s, 0.7 m/s at 35 mm), as a user
  who sets it to the robot's would: a driver that repeats its counters then moves them
  by two periods' worth (the Kobuki does) meets it;
- ``relogged``: the copy a logger writes (``test/relogged.py``: holds released 1 ms
  after the previous row, gaps inside turns, jittered stamps), defaults;
- ``faults``: that copy with two real faults (``relogged.with_faults``: a counter spike
  that returns, a driver restart counting again from near zero), defaults; what the
  gates did with each (in brackets, and totalled: skipped or taken as a restart, or
  let through as motion); ``faults, top speed``: the same with ``max_wheel_speed`` at
  the robot's (it bounds a gap's mean speed too).

Per run and scenario, each gate that fired: what it did (``too_fast``: the step skipped;
``gap``: a driver restart, the gap's motion not integrated; ``gap_integrated``: the gap's
motion integrated; other codes: the reading dropped) and what the ground truth says of
the step the counts claimed: ``motion`` where its heading change (and, where the truth
is the robot's centre, its chord) agrees with the counts' within 3 deg or 10 % (2 cm or
20 %), over the interval the counts' motion accrued (since they last changed), else
``glitch``. A gate is right when it drops glitches and integrates motion. Runs without
ground truth (PHIL 4, 5, 7, 9) are counted, not judged (``?``).
"""

from __future__ import annotations

import argparse
import math
from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np
from realruns import RealRun, real_runs
from relogged import Recording, Robot, relog, seed_of, with_faults

from diffdrive_odom.core.estimation.pipeline import ReadingPipeline
from diffdrive_odom.core.evaluation.metrics import Trajectory
from diffdrive_odom.settings.odometry import odometry_settings

TOP_SPEED = {"optiodom": 10.0, "phil": 30.0}  # rad/s: 1.5 x the robot's top wheel speed
HEADING_DEG, HEADING_SHARE = 3.0, 0.10
CHORD_M, CHORD_SHARE = 0.02, 0.20
PASS = ("updated", "first", "held")  # a held reading is decided by the next one


@dataclass(frozen=True)
class Event:
    """One gate's decision on one step: its code, the step's stamps, the counts' claim."""

    code: str
    t0: int
    t1: int
    dtheta: float  # rad the counts say the robot turned
    chord: float  # m the counts say it moved (chord of the arc)


def events(rec: Recording, robot: Robot, params: dict[str, object]) -> Iterator[Event]:
    """What the gates did with ``rec``: every reading fed as the node does."""
    pipe = ReadingPipeline(odometry_settings(params))
    phi = robot.angles(rec.position)  # every count, unwrapped (as the counts claim)
    t = rec.stamp_ns
    moved = np.concatenate(([True], (np.diff(rec.position, axis=0) != 0).any(axis=1)))
    first = np.maximum.accumulate(np.where(moved, np.arange(len(t)), 0))  # run starts
    for k in range(len(t)):
        code = str(pipe.feed(int(t[k]), list(rec.names), rec.position[k].tolist(),
                             receive_ns=int(rec.log_ns[k])).verdict.code)
        if code in PASS or k == 0:
            continue
        a, b = (k - 2, k - 1) if code.startswith("gap") and k >= 2 else (k - 1, k)
        d = phi[b] - phi[a]
        dth = robot.radius * (d[1] - d[0]) / robot.separation
        ds = robot.radius * (d[0] + d[1]) / 2
        chord = abs(ds) * (abs(math.sin(dth / 2) / (dth / 2)) if dth else 1.0)
        yield Event(code, int(t[first[a]]), int(t[b]), dth, chord)


def verdict(e: Event, run: RealRun) -> str:
    """What the ground truth says of the step the counts claimed: motion, glitch, ?."""
    truth: Trajectory | None = run.truth
    if truth is None:
        return "?"
    ts = truth.stamp_ns.astype(float)

    def at(s: int) -> tuple[float, float, float]:
        s += run.truth_lag_ns
        return (float(np.interp(s, ts, truth.x)), float(np.interp(s, ts, truth.y)),
                float(np.interp(s, ts, truth.yaw)))

    (x0, y0, h0), (x1, y1, h1) = at(e.t0), at(e.t1)
    turned = h1 - h0
    heading = abs(e.dtheta - turned) <= max(math.radians(HEADING_DEG),
                                            HEADING_SHARE * abs(turned))
    chord = math.hypot(x1 - x0, y1 - y0)
    path = not run.centre or abs(e.chord - chord) <= max(CHORD_M, CHORD_SHARE * chord)
    return "motion" if heading and path else "glitch"


Fault = tuple[str, int, int]


def scenarios(run: RealRun
              ) -> Iterator[tuple[str, Recording, dict[str, object], list[Fault]]]:
    """Each scenario's rows, parameters and the faults injected into them."""
    kind = "phil" if run.robot.counter_bits else "optiodom"
    copy = relog(run.recording, run.robot, seed_of(run.name)).recording
    yield "real", run.recording, run.params, []
    yield ("real, top speed", run.recording,
           {**run.params, "max_wheel_speed": TOP_SPEED[kind]}, [])
    yield "relogged", copy, run.params, []
    faulty, faults = with_faults(copy, run.robot, seed_of(run.name))
    yield "faults", faulty, run.params, faults
    yield "faults, top speed", faulty, {**run.params, "max_wheel_speed": TOP_SPEED[kind]}, faults


def caught(faults: list[Fault], seen: list[Event]) -> Counter[str]:
    """What the gates did with each injected fault: the spike's step (and the one back)
    skipped, the restart taken as one; else let through (integrated as motion)."""
    out: Counter[str] = Counter()
    for kind, a, b in faults:
        hit = {e.code for e in seen if a < e.t1 <= b}
        if kind == "spike":
            out["spike skipped" if "too_fast" in hit else "spike let through"] += 1
        else:
            out["restart taken" if "gap" in hit else "restart let through"] += 1
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="3 runs")
    args = parser.parse_args()
    totals: dict[str, Counter[tuple[str, str]]] = {}
    injected: dict[str, Counter[str]] = {}
    print("per run and scenario: gate events (ground truth: motion / glitch / ? no truth)")
    for run in real_runs(args.quick):
        cells = []
        for name, rec, params, faults in scenarios(run):
            found = list(events(rec, run.robot, params))
            seen: Counter[tuple[str, str]] = Counter((e.code, verdict(e, run)) for e in found)
            totals.setdefault(name, Counter()).update(seen)
            outcome = caught(faults, found)
            if faults:
                injected.setdefault(name, Counter()).update(outcome)
            cells.append(f"{name}: " + (_text(seen) or "none") + (
                " [" + ", ".join(sorted(outcome)) + "]" if faults else ""))
        print(f"{run.name:30s} " + " | ".join(cells))
    print("\ntotals over the runs, per scenario and gate (events: motion / glitch / ?)")
    for name, seen in totals.items():
        print(f"  {name:16s} " + (_text(seen) or "none"))
    for name, outcomes in injected.items():
        print(f"faults injected ({name}): "
              + ", ".join(f"{k} {v}" for k, v in sorted(outcomes.items())))
    return 0


def _text(seen: Counter[tuple[str, str]]) -> str:
    """``code n (m motion, g glitch, u ?)`` for each code seen."""
    out = []
    for code in sorted({c for c, _ in seen}):
        m, g, u = (seen[(code, v)] for v in ("motion", "glitch", "?"))
        parts = [f"{m} motion"] * bool(m) + [f"{g} glitch"] * bool(g) + [f"{u} ?"] * bool(u)
        out.append(f"{code} {m + g + u} ({', '.join(parts)})")
    return ", ".join(out)


if __name__ == "__main__":
    raise SystemExit(main())
