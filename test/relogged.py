"""Real runs re-logged the way a logger that stamps rows when it writes them makes them.

Test and bench code (issue 37), written without the package's estimator: it reads the
runs' wheel readings (the bag library), changes only their rows, and judges a replay
against two things that need no estimator, the unmodified run and an anchor that
integrates every count (:func:`anchor_heading`, a few lines here).

What such a logger does to a run (:func:`relog`), each from a seed of the run's name:

- **holds**: dozens a run, 0.1-0.3 s each, 1-4 s apart: the rows keep the counts of the
  row before the hold, then the moved counts are written 1 ms after the previous row
  (the counts of the last held row's own time, so no count is lost);
- **gaps**: up to :data:`GAPS` a run, 1-5 s without rows, each inside a turn (a stretch
  of 1 s or more where the wheels' heading turns faster than :data:`TURN_RATE`, the gap
  no longer than the stretch): the row after a gap has the counts of its own time;
- **jitter**: every row's stamp moved by up to :data:`JITTER_S` either way (rows stay in
  order; the bag's log time is the stamp, as the logger writes it).

Every count of the run is in the copy: the anchor's heading is the same on both.
:func:`judge` replays a run and its copy through replay's engine and sets them side by
side with the anchor and, where there is ground truth, the ATE after the best SE(2) fit
(also on the same rows of both: outside the copy's holds, whose poses no estimate can
place while the counts are held, and its gaps, which have no rows).
"""

from __future__ import annotations

import math
import zlib
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from diffdrive_odom.core.bulk.readings import JointReading
from diffdrive_odom.core.evaluation.metrics import Trajectory, evaluate
from diffdrive_odom.settings.odometry import odometry_settings
from diffdrive_odom.tools.bags import bagreadings
from diffdrive_odom.tools.replaying.readings import replay_readings
from diffdrive_odom.tools.replaying.sinks import Published

Ints = npt.NDArray[np.int64]
Floats = npt.NDArray[np.float64]

HOLD_S = (0.1, 0.3)  # s a hold lasts
HOLD_EVERY_S = (1.0, 4.0)  # s from one hold to the next
RELEASE_NS = 1_000_000  # the moved counts: 1 ms after the previous row
GAP_S = (1.0, 5.0)  # s a gap lasts (at most its turn's length)
GAPS = 3  # gaps a run at most
TURN_RATE = 0.1  # rad/s: turning, by the wheels' heading over 0.5 s
TURN_S = 1.0  # s a turning stretch lasts at least to hold a gap
JITTER_S = 0.002  # s each row's stamp moves at most
MARGIN_S = 0.5  # s between a hold and a gap


@dataclass(frozen=True)
class Robot:
    """What the anchor and the turn finder need: geometry and the counters' units."""

    radius: float
    separation: float
    ticks_per_revolution: float = 0.0  # 0: positions in radians
    counter_bits: int = 0  # 0: no wrap

    def angles(self, position: Floats) -> Floats:
        """Joint angles [rad] from 0, every count since the first row (wraps unwrapped)."""
        d = np.diff(position, axis=0)
        if self.counter_bits:
            span = 2.0 ** self.counter_bits
            d = (d + span / 2) % span - span / 2
        scale = 2 * math.pi / self.ticks_per_revolution if self.ticks_per_revolution else 1.0
        return np.vstack((np.zeros((1, position.shape[1])), np.cumsum(d * scale, axis=0)))

    def headings(self, position: Floats) -> Floats:
        """The wheels' heading at each row [rad, from 0]: every count integrated."""
        phi = self.angles(position)
        return self.radius * (phi[:, 1] - phi[:, 0]) / self.separation


OPTIODOM = Robot(0.042, 0.200)
KOBUKI = Robot(0.035, 0.23, 2578.33, 16)


@dataclass(frozen=True)
class Recording:
    """A run's wheel rows: stamps, log times, joint names, positions (left, right)."""

    stamp_ns: Ints
    log_ns: Ints
    names: tuple[str, str]
    position: Floats  # (n, 2) raw: radians or counts

    def readings(self) -> list[JointReading]:
        """The rows as the replay engine takes them."""
        return [JointReading(int(s), int(g), self.names, tuple(p.tolist()), ())
                for s, g, p in zip(self.stamp_ns, self.log_ns, self.position, strict=True)]


@dataclass(frozen=True)
class Relogged:
    """A re-logged copy and what was done to it: holds and gaps as (from, to) stamps."""

    recording: Recording
    holds: list[tuple[int, int]]
    gaps: list[tuple[int, int]]


def load(bag: Path, left: str, right: str) -> Recording:
    """A bag's JointState rows in stamp order, the two wheels' positions."""
    rows = list(bagreadings.read_joint_states(bag))
    idx = [list(rows[0].names).index(n) for n in (left, right)]
    return Recording(np.array([r.stamp_ns for r in rows], dtype=np.int64),
                     np.array([r.log_ns for r in rows], dtype=np.int64), (left, right),
                     np.array([[r.position[k] for k in idx] for r in rows], dtype=np.float64))


def anchor_heading(rec: Recording, robot: Robot) -> float:
    """The final heading of every count integrated [rad, wrapped]: right minus left arc."""
    return math.remainder(float(robot.headings(rec.position)[-1]), 2 * math.pi)


def turning_stretches(rec: Recording, robot: Robot) -> list[tuple[int, int]]:
    """Stretches (first, last stamp) of at least TURN_S turning faster than TURN_RATE."""
    t = rec.stamp_ns * 1e-9
    th = robot.headings(rec.position)
    grid = np.arange(t[0] + 0.25, t[-1] - 0.25, 0.05)
    rate = (np.interp(grid + 0.25, t, th) - np.interp(grid - 0.25, t, th)) / 0.5
    turning = np.abs(rate) > TURN_RATE
    out: list[tuple[int, int]] = []
    k = 0
    while k < len(grid):
        if not turning[k]:
            k += 1
            continue
        j = k
        while j + 1 < len(grid) and turning[j + 1]:
            j += 1
        if grid[j] - grid[k] >= TURN_S:
            out.append((round(grid[k] * 1e9), round(grid[j] * 1e9)))
        k = j + 1
    return out


def seed_of(name: str) -> int:
    """A run's seed: the same copy every time, another for another run."""
    return zlib.crc32(name.encode())


def relog(rec: Recording, robot: Robot, seed: int) -> Relogged:
    """The run as the logger of the module's text writes it."""
    rng = np.random.default_rng(seed)
    t0, t1 = int(rec.stamp_ns[0]), int(rec.stamp_ns[-1])
    gaps: list[tuple[int, int]] = []
    stretches = turning_stretches(rec, robot)
    for k in sorted(rng.permutation(len(stretches))[:GAPS].tolist()):
        a, b = stretches[k]
        length = rng.uniform(GAP_S[0], min(GAP_S[1], (b - a) * 1e-9))
        start = a + round(rng.uniform(0.0, (b - a) * 1e-9 - length) * 1e9)
        gaps.append((start, start + round(length * 1e9)))
    holds: list[tuple[int, int]] = []
    at = t0 + round(rng.uniform(*HOLD_EVERY_S) * 1e9)
    while at < t1 - 1e9:
        length = round(rng.uniform(*HOLD_S) * 1e9)
        margin = round(MARGIN_S * 1e9)
        if not any(a - margin < at + length and at < b + margin for a, b in gaps):
            holds.append((at, at + length))
        at += length + round(rng.uniform(*HOLD_EVERY_S) * 1e9)
    return Relogged(_rows(rec, rng, holds, gaps), holds, gaps)


def _rows(rec: Recording, rng: np.random.Generator, holds: Sequence[tuple[int, int]],
          gaps: Sequence[tuple[int, int]]) -> Recording:
    """The rows written: jittered, gaps cut, holds repeated and released late."""
    n = len(rec.stamp_ns)
    jitter = np.round(rng.uniform(-JITTER_S, JITTER_S, n) * 1e9).astype(np.int64)
    stamps = rec.stamp_ns + jitter
    stamps[0] = rec.stamp_ns[0]
    floor = np.maximum.accumulate(stamps)  # jitter never reorders
    stamps = np.maximum(stamps, floor)
    t = rec.stamp_ns
    cut = np.zeros(n, dtype=np.bool_)
    for a, b in gaps:
        cut |= (t > a) & (t <= b)
    out_t: list[int] = []
    out_p: list[Floats] = []
    hold_at = {int(np.searchsorted(t, a, side="right")) - 1: b for a, b in holds}
    k = 0
    while k < n:
        if cut[k]:
            k += 1
            continue
        out_t.append(int(stamps[k]))
        out_p.append(rec.position[k])
        end = hold_at.get(k)
        if end is None:
            k += 1
            continue
        last = k
        j = k + 1
        while j < n and t[j] <= end and not cut[j]:
            out_t.append(int(stamps[j]))
            out_p.append(rec.position[k])  # held: the counts before the hold
            last = j
            j += 1
        if last > k:  # released: the moved counts, 1 ms after the previous row
            out_t.append(out_t[-1] + RELEASE_NS)
            out_p.append(rec.position[last])
        k = j
    stamp = np.array(out_t, dtype=np.int64)
    return replace(rec, stamp_ns=stamp, log_ns=stamp.copy(), position=np.array(out_p))


# --- judging a replay of a run and of its copy (the package's replay engine) ----------


@dataclass(frozen=True)
class Replayed:
    """What replay made of some rows: the final heading, the poses, what the rules did."""

    heading: float  # rad, wrapped
    trajectory: Trajectory
    reasons: Counter[str]
    examples: dict[str, str]
    gaps_integrated: int


def replay(rec: Recording, params: dict[str, Any],
           imu: Sequence[bagreadings.ImuSample] = ()) -> Replayed:
    """``rec`` through replay's engine (the node's pipeline, the fast lane) with ``params``.

    ``imu``: gyro samples to merge in by log time, as replay reads a bag (``use_imu``).
    """
    out: list[Published] = []
    rows: list[Any] = sorted([*rec.readings(), *imu], key=lambda r: (r.log_ns, r.stamp_ns))
    stats = replay_readings(rows, odometry_settings(params), out.append)
    traj = Trajectory.from_arrays([p.stamp_ns for p in out], [p.pose.x for p in out],
                                  [p.pose.y for p in out], [p.pose.theta for p in out])
    # (read by name: the benches judge an older tree too, PYTHONPATH set to it)
    return Replayed(stats.final_pose.theta, traj, stats.reasons, stats.examples,
                    getattr(stats.pipeline, "gaps_integrated", 0))


def outside(traj: Trajectory, windows: Sequence[tuple[int, int]]) -> Trajectory:
    """The poses stamped outside every window (with the jitter's margin): held rows' poses
    are stale in any estimate (the logger hid the motion), a gap has none."""
    keep = np.ones(len(traj), dtype=np.bool_)
    margin = round(JITTER_S * 1e9) + RELEASE_NS
    for a, b in windows:
        keep &= ~((traj.stamp_ns > a - margin) & (traj.stamp_ns <= b + margin))
    return Trajectory(traj.stamp_ns[keep], traj.x[keep], traj.y[keep], traj.yaw[keep])


@dataclass(frozen=True)
class Judged:
    """One run and its copy side by side. ATE [m]: best SE(2) fit, on all poses and on
    the same rows (outside the copy's holds and gaps, in both); None without truth."""

    name: str
    copy: Relogged
    anchor: float  # rad: every count of the run integrated
    unmodified: Replayed
    relogged: Replayed
    ate: tuple[float, float, float, float] | None  # unmodified, copy; same rows: both

    def degrees(self, a: float, b: float) -> float:
        """``a - b`` in degrees, wrapped."""
        return math.degrees(math.remainder(a - b, 2 * math.pi))


def judge(name: str, rec: Recording, robot: Robot, params: dict[str, Any],
          truth: Trajectory | None) -> Judged:
    """Replay ``rec`` and its copy (seeded by ``name``) and compare them."""
    copy = relog(rec, robot, seed_of(name))
    a, b = replay(rec, params), replay(copy.recording, params)
    ate = None
    if truth is not None:
        windows = copy.holds + copy.gaps
        fits = [evaluate(t, truth).ate_rmse_best_fit_m for t in (
            a.trajectory, b.trajectory, outside(a.trajectory, windows),
            outside(b.trajectory, windows))]
        ate = (fits[0], fits[1], fits[2], fits[3])
    return Judged(name, copy, anchor_heading(rec, robot), a, b, ate)


# --- real faults, to count what the gates still catch ---------------------------------

SPIKE_RAD = 40.0  # a counter glitch that returns: one row's left wheel this far up
RESTART_S = 2.0  # a driver restart: this long without rows, then counting from near 0


def with_faults(rec: Recording, robot: Robot, seed: int
                ) -> tuple[Recording, list[tuple[str, int, int]]]:
    """The run with two faults a driver really makes, each where the wheels move.

    A counter spike that returns (one row's left count :data:`SPIKE_RAD` up, the next
    row as it was) about a third into the run; a driver restart two thirds in: no rows
    for :data:`RESTART_S`, then the counters counting again from the row before the
    first one after it (near zero, not zero; a wrapping counter wraps). Returns the rows
    and the faults as ``(kind, from, to)`` stamps.
    """
    rng = np.random.default_rng(seed)
    t, pos = rec.stamp_ns.copy(), rec.position.copy()
    speed = np.abs(np.diff(robot.angles(pos), axis=0)).max(axis=1)
    moving = np.flatnonzero(speed > 0.0) + 1
    n = len(t)

    def pick(lo: float, hi: float) -> int:
        choice = moving[(moving > lo * n) & (moving < hi * n - 1)]
        return int(rng.choice(choice)) if len(choice) else int(lo * n)

    unit = 2 * math.pi / robot.ticks_per_revolution if robot.ticks_per_revolution else 1.0
    span = 2.0 ** robot.counter_bits if robot.counter_bits else 0.0
    k = pick(0.25, 0.45)
    pos[k, 0] += round(SPIKE_RAD / unit) if robot.ticks_per_revolution else SPIKE_RAD
    faults = [("spike", int(t[k - 1]), int(t[k + 1]))]
    r = pick(0.6, 0.8)
    end = int(np.searchsorted(t, t[r] + round(RESTART_S * 1e9)))
    if end < n:
        pos[end:] -= pos[end - 1]
        if span:
            pos[end:] %= span
        keep = np.ones(n, dtype=np.bool_)
        keep[r + 1:end] = False
        t, pos = t[keep], pos[keep]
        faults.append(("restart", int(rec.stamp_ns[r]), int(rec.stamp_ns[end])))
    if span:
        pos %= span
    return replace(rec, stamp_ns=t, log_ns=t.copy(), position=pos), faults
