"""The anchor calibration: a plain least squares on the reference's positions, without the package.

Issue 38's yardstick for ``calibrate``, written here from the textbook and imported by
``bench_anchor.py`` (nothing of ``diffdrive_odom`` is imported: an error shared by the
product and its yardstick cannot cancel):

- each run's wheel angle increments integrated with exact circular arcs (left and right
  arcs ``r_L dphi_L``, ``r_R dphi_R``, turn ``(s_R - s_L) / b``, the chord along the
  mid-heading);
- the reference's point is ``p + R(theta) l``: ``l``, its lever arm from the axle centre
  (x forward, y left), fitted; its heading is never read, so a marker body's yaw on the
  robot does not matter;
- every run's start pose is fitted too (a rotation and a translation per run, solved in
  closed form for any geometry and lever arm: the 2-D Kabsch fit of the run's points on
  the reference's); steps left out (the slips ``calibrate`` leaves out, given as stamp
  spans) cut a run into pieces, each with a start pose of its own;
- the three multipliers and the lever arm minimise the sum of squared position errors
  over every reading the reference covers (no robust loss, no weights): 1-sigma from
  the Gauss-Newton covariance with the residuals' variance.

The figure it judges a geometry by (:func:`judge`): a run's RMS position error with the
run's own start pose fitted (the same Kabsch), the lever arm given.

Two more yardsticks for phil_train, where the anchor and ``calibrate`` part:
:func:`turns` (a gyro's turn beside the wheels' angles over the turns each way, so a
geometry's turning is judged on runs without a reference) and :func:`start_fit` (the fit
on the runs whole, their slips' turn the reference's, each start pinned at the
reference's first pose as ``calibrate``'s objective pins it, or fitted as here).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy import optimize

FloatArray = npt.NDArray[np.float64]
Values = Sequence[float] | FloatArray
MAX_GAP_NS = 500_000_000  # the reference is not interpolated across a longer gap


@dataclass(frozen=True)
class Piece:
    """Steps without a gap: wheel increments [rad] and the reference at each pose after a step.

    ``sample``: which poses (0 = the piece's start, k = after step k - 1) the reference
    covers; ``ref``: its positions there (m, 2).
    """

    d_left: FloatArray
    d_right: FloatArray
    sample: npt.NDArray[np.int64]
    ref: FloatArray


@dataclass(frozen=True)
class AnchorRun:
    """A run as the anchor reads it: its pieces."""

    name: str
    pieces: tuple[Piece, ...]


@dataclass(frozen=True)
class AnchorFit:
    """The anchor's fit: multipliers (left, right, separation), lever arm [m], 5x5 covariance."""

    multipliers: FloatArray
    lever: FloatArray
    covariance: FloatArray
    rms: float
    information: FloatArray  # J^T J / residual variance (the covariance's inverse)

    @property
    def sigma(self) -> FloatArray:
        """1-sigma of the multipliers and the lever arm."""
        return np.sqrt(np.clip(np.diag(self.covariance), 0.0, None))


# --- reading ------------------------------------------------------------------------


def _stamp(header: Any) -> int:
    return int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)


def read_bag(bag: Path | str, left: str, right: str, reference: str = "/ground_truth/pose",
             ticks: float | None = None, counter_bits: int | None = None, yaw: bool = False
             ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """Wheel stamps [ns], left and right wheel angles [rad] from 0; reference (n, 3): ns, x, y
    (``yaw``: (n, 4), its yaw [rad] after them, unwrapped).

    ``ticks``: raw counters per wheel turn (angles otherwise), wrapping at ``2^counter_bits``.
    Readings sorted by header stamp.
    """
    from rosbags.highlevel import AnyReader

    wheels: list[tuple[int, float, float]] = []
    ref: list[tuple[int, float, float, float]] = []
    with AnyReader([Path(bag)]) as reader:
        conns = [c for c in reader.connections if c.topic in ("/joint_states", reference)]
        for conn, _, raw in reader.messages(connections=conns):
            msg = reader.deserialize(raw, conn.msgtype)
            if conn.topic == reference:
                pose = msg.pose.pose if hasattr(msg.pose, "pose") else msg.pose
                q = pose.orientation
                ref.append((_stamp(msg.header), float(pose.position.x), float(pose.position.y),
                            math.atan2(2.0 * (q.w * q.z + q.x * q.y),
                                       1.0 - 2.0 * (q.y * q.y + q.z * q.z))))
            else:
                names = list(msg.name)
                wheels.append((_stamp(msg.header), float(msg.position[names.index(left)]),
                               float(msg.position[names.index(right)])))
    w = np.array(sorted(wheels), dtype=np.float64)
    r = np.array(sorted(ref), dtype=np.float64).reshape(-1, 4)  # none: (0, 4)
    r = np.column_stack((r[:, :3], np.unwrap(r[:, 3]))) if yaw else r[:, :3]
    angles = []
    for col in (w[:, 1], w[:, 2]):
        step = np.diff(col)
        if counter_bits is not None:
            span = 2.0 ** counter_bits
            step = (step + span / 2) % span - span / 2
        if ticks is not None:
            step = step * 2.0 * math.pi / ticks
        angles.append(np.concatenate(([0.0], np.cumsum(step))))
    return w[:, 0], angles[0], angles[1], r


def _in_spans(stamps: npt.NDArray[np.float64] | npt.NDArray[np.int64],
              spans: Sequence[tuple[int, int]]) -> npt.NDArray[np.bool_]:
    """Which steps (between consecutive ``stamps``) end inside one of the stamp ``spans``."""
    end = stamps[1:]
    gone = np.zeros(len(end), dtype=bool)
    for first, last in spans:
        gone |= (end >= first) & (end <= last)
    return gone


def _covered(t: npt.NDArray[np.int64], rt: npt.NDArray[np.int64]) -> npt.NDArray[np.bool_]:
    """Which stamps ``t`` the reference stamped ``rt`` covers (no gap over MAX_GAP_NS)."""
    i = np.clip(np.searchsorted(rt, t, side="right"), 1, len(rt) - 1)
    return np.asarray((t >= rt[0]) & (t <= rt[-1])
                      & ((rt[i] - rt[i - 1] <= MAX_GAP_NS) | (rt[i - 1] == t)))


def anchor_run(name: str, stamps: FloatArray, left: FloatArray, right: FloatArray,
               ref: FloatArray, left_out: Sequence[tuple[int, int]] = ()) -> AnchorRun:
    """The pieces of a run: steps whose end stamp lies in a ``left_out`` span cut it."""
    t = stamps.astype(np.int64)
    rt = ref[:, 0].astype(np.int64)
    dl, dr = np.diff(left), np.diff(right)
    cut = _in_spans(t, left_out)
    covered = _covered(t, rt)
    xy = np.column_stack([np.interp((t - rt[0]).astype(np.float64),
                                    (rt - rt[0]).astype(np.float64), ref[:, k]) for k in (1, 2)])
    pieces = []
    start = 0
    for k in [*np.flatnonzero(cut), len(dl)]:
        if k - start >= 2:  # steps start .. k - 1; poses start .. k
            poses = np.arange(start, k + 1)
            ok = covered[poses]
            if ok.sum() >= 3:
                pieces.append(Piece(dl[start:k], dr[start:k], np.flatnonzero(ok),
                                    xy[poses[ok]]))
        start = k + 1
    return AnchorRun(name, tuple(pieces))


# --- the model ----------------------------------------------------------------------


def integrate(d_left: FloatArray, d_right: FloatArray, r_left: float, r_right: float,
              separation: float, turns: tuple[npt.NDArray[np.bool_], FloatArray] | None = None
              ) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Poses (x, y, theta) at the start and after every step, exact arcs.

    ``turns`` (which steps, their turns [rad]): those steps turn so, not as the wheels say.
    """
    sl, sr = r_left * d_left, r_right * d_right
    ds, dth = 0.5 * (sl + sr), (sr - sl) / separation
    if turns is not None:
        dth = np.where(turns[0], turns[1], dth)
    th = np.concatenate(([0.0], np.cumsum(dth)))
    chord = ds * np.sinc(dth / (2.0 * math.pi))  # sin(dth/2) / (dth/2)
    mid = th[:-1] + 0.5 * dth
    x = np.concatenate(([0.0], np.cumsum(chord * np.cos(mid))))
    y = np.concatenate(([0.0], np.cumsum(chord * np.sin(mid))))
    return x, y, th


def _kabsch(p: FloatArray, q: FloatArray) -> FloatArray:
    """``q`` minus ``p`` moved by the rigid motion that lays it best on ``q`` (m, 2)."""
    mp, mq = p.mean(axis=0), q.mean(axis=0)
    a, b = p - mp, q - mq
    angle = math.atan2(float(np.sum(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0])),
                       float(np.sum(a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1])))
    c, s = math.cos(angle), math.sin(angle)
    moved = np.column_stack((c * a[:, 0] - s * a[:, 1], s * a[:, 0] + c * a[:, 1]))
    return np.asarray(b - moved, dtype=np.float64)


def _points(x: FloatArray, y: FloatArray, th: FloatArray, i: npt.NDArray[np.int64],
            lever: Values) -> FloatArray:
    """The reference's point (``lever`` from the axle centre, x forward, y left) at poses
    ``i`` (m, 2)."""
    c, s = np.cos(th[i]), np.sin(th[i])
    return np.column_stack((x[i] + c * lever[0] - s * lever[1],
                            y[i] + s * lever[0] + c * lever[1]))


def piece_errors(piece: Piece, multipliers: Values, lever: Values,
                 radius: float, separation: float) -> FloatArray:
    """The reference's point minus the odometry's, start pose fitted (m, 2)."""
    x, y, th = integrate(piece.d_left, piece.d_right, radius * multipliers[0],
                         radius * multipliers[1], separation * multipliers[2])
    i = piece.sample
    p = _points(x, y, th, i, lever)
    return _kabsch(p, piece.ref)


def fit(runs: Sequence[AnchorRun], radius: float, separation: float,
        lever: bool = True, multipliers: Values | None = None) -> AnchorFit:
    """The anchor's least squares (see the module); ``lever`` False: held at 0;
    ``multipliers`` given: held, the lever arm alone fitted."""
    pieces = [p for r in runs for p in r.pieces]
    held = None if multipliers is None else np.asarray(multipliers, dtype=np.float64)

    def unpack(v: FloatArray) -> tuple[FloatArray, FloatArray]:
        m = held if held is not None else v[:3]
        rest = v[3:] if held is None else v
        return m, (rest[:2] if lever else np.zeros(2))

    def res(v: FloatArray) -> FloatArray:
        m, lv = unpack(v)
        return np.concatenate([piece_errors(p, m, lv, radius, separation).ravel()
                               for p in pieces])

    x0 = np.array(([] if held is not None else [1.0, 1.0, 1.0]) + ([0.0, 0.0] if lever else []))
    scale = np.array(([] if held is not None else [1e-3] * 3) + ([1e-2] * 2 if lever else []))
    sol = optimize.least_squares(res, x0, x_scale=scale, xtol=1e-12, ftol=1e-12, gtol=1e-12)
    r = np.asarray(sol.fun)
    dof = max(len(r) - len(x0) - 3 * len(pieces), 1)
    variance = float(np.sum(r**2)) / dof
    jac = np.asarray(sol.jac)
    info = jac.T @ jac / variance
    full = np.zeros((5, 5))
    idx = ([0, 1, 2] if held is None else []) + ([3, 4] if lever else [])
    full[np.ix_(idx, idx)] = np.linalg.pinv(info)
    full_info = np.zeros((5, 5))
    full_info[np.ix_(idx, idx)] = info
    m, lv = unpack(np.asarray(sol.x))
    return AnchorFit(np.asarray(m, dtype=np.float64), np.asarray(lv, dtype=np.float64), full,
                     math.sqrt(float(np.mean(r**2))), full_info)


def judge(run: AnchorRun, multipliers: Values, lever: Values, radius: float,
          separation: float) -> float:
    """A run's RMS position error [m] with this geometry and lever arm, its start pose fitted."""
    errs = np.concatenate([piece_errors(p, multipliers, lever, radius, separation)
                           for p in run.pieces])
    return float(np.sqrt(np.mean(np.sum(errs**2, axis=1))))


# --- the gyro's judgment of the turning -------------------------------------------------

STILL_NS = 500_000_000  # a gyro sample this far from any wheel motion is at a standstill
WINDOW_NS = 500_000_000  # the turns are summed over windows this long
MIN_RATE = 0.05  # rad/s: a window turning slower than this (by the gyro) is not a turn


def read_gyro(bag: Path | str, topic: str = "/imu") -> FloatArray:
    """(n, 2): the gyro's stamps [ns] and yaw rates [rad/s], sorted by stamp."""
    from rosbags.highlevel import AnyReader

    out: list[tuple[int, float]] = []
    with AnyReader([Path(bag)]) as reader:
        conns = [c for c in reader.connections if c.topic == topic]
        for conn, _, raw in reader.messages(connections=conns):
            msg = reader.deserialize(raw, conn.msgtype)
            out.append((_stamp(msg.header), float(msg.angular_velocity.z)))
    return np.array(sorted(out), dtype=np.float64)


def gyro_heading(stamps: FloatArray, left: FloatArray, right: FloatArray,
                 gyro: FloatArray) -> FloatArray:
    """The gyro's heading [rad] at each wheel stamp: its rate integrated (trapezoids), less
    its bias (the mean rate where no wheel moved within :data:`STILL_NS`)."""
    moved = stamps[1:][(np.diff(left) != 0) | (np.diff(right) != 0)]
    t, rate = gyro[:, 0], gyro[:, 1]
    k = np.clip(np.searchsorted(moved, t), 1, max(len(moved) - 1, 1))
    near = np.minimum(np.abs(moved[k - 1] - t), np.abs(moved[np.minimum(k, len(moved) - 1)] - t))
    still = near > STILL_NS if len(moved) else np.ones(len(t), dtype=bool)
    bias = float(np.mean(rate[still])) if still.sum() >= 10 else 0.0
    heading = np.concatenate(([0.0], np.cumsum(0.5 * (rate[1:] + rate[:-1] - 2.0 * bias)
                                                * np.diff(t) * 1e-9)))
    return np.interp(stamps, t, heading)


def turns(stamps: FloatArray, left: FloatArray, right: FloatArray, gyro: FloatArray,
          left_out: Sequence[tuple[int, int]] = ()) -> dict[str, tuple[float, FloatArray]]:
    """The gyro's turn and the wheels' angles over the run's turns, each way.

    Per direction ("ccw", "cw"): the gyro's heading change summed over the
    :data:`WINDOW_NS` windows turning that way faster than :data:`MIN_RATE`, and the
    right and left wheel angle changes [rad] summed over the same windows; steps in a
    ``left_out`` span (the slips) counted in neither. A geometry's predicted turn is then
    ``(r_R dphi_R - r_L dphi_L) / b``.
    """
    h = gyro_heading(stamps, left, right, gyro)
    keep = ~_in_spans(stamps, left_out)
    cum = [np.concatenate(([0.0], np.cumsum(np.where(keep, np.diff(v), 0.0))))
           for v in (h, right, left)]
    edges = np.searchsorted(stamps, np.arange(stamps[0], stamps[-1], WINDOW_NS))
    dh, dr, dl = (np.diff(c[edges]) for c in cum)
    rate = MIN_RATE * WINDOW_NS * 1e-9
    return {way: (float(dh[sel].sum()), np.array([dr[sel].sum(), dl[sel].sum()]))
            for way, sel in (("ccw", dh > rate), ("cw", dh < -rate))}


AFTER_SLIP_NS = 500_000_000  # a stretch starts this long after a left-out span ends
MIN_STRETCH_RAD = math.radians(30.0)  # a turn of less than this is not judged
MIN_REVERSAL_RAD = math.radians(10.0)  # the heading turning back this far ends a turn


def _one_way(h: FloatArray, i: int, j: int) -> list[tuple[int, int]]:
    """Poses ``i``..``j`` cut at the heading's turning points: where it has come back
    :data:`MIN_REVERSAL_RAD` from its extreme since the last cut (wobbles do not cut)."""
    out, start, ext = [], i, i
    way = 0.0
    for k in range(i + 1, j + 1):
        d = h[k] - h[ext]
        if way == 0.0:
            if abs(h[k] - h[start]) >= MIN_REVERSAL_RAD:
                way, ext = math.copysign(1.0, h[k] - h[start]), k
        elif d * way > 0.0:
            ext = k
        elif -d * way >= MIN_REVERSAL_RAD:
            out.append((start, ext))
            start, way = ext, -way
            ext = k
    out.append((start, j))
    return out


def stretches(stamps: FloatArray, left: FloatArray, right: FloatArray, gyro: FloatArray,
              left_out: Sequence[tuple[int, int]] = ()) -> list[tuple[int, int, float,
                                                                        FloatArray]]:
    """The gyro's turn and the wheels' over each turn one way between the left-out spans.

    Every step of a turn counts (no window picked by the gyro's own sign: where the body
    lags the wheels, such windows flatter the wheels). A stretch between two spans starts
    :data:`AFTER_SLIP_NS` after the first ends (the body follows the wheels by up to
    0.2 s on these runs) and is cut where the heading turns back (:func:`_one_way`). Per
    turn of :data:`MIN_STRETCH_RAD` or more: first and last pose index, the gyro's heading
    change and the right and left wheel angle changes [rad].
    """
    h = gyro_heading(stamps, left, right, gyro)
    bounds = [(int(stamps[0]), int(stamps[0]))] + [(a, b + AFTER_SLIP_NS) for a, b in left_out]
    out = []
    for (_, start), (stop, _) in zip(bounds, [*bounds[1:], (int(stamps[-1]) + 1, 0)],
                                     strict=True):
        i = int(np.searchsorted(stamps, start))
        j = min(int(np.searchsorted(stamps, stop)) - 1, len(stamps) - 1)
        for a, b in _one_way(h, i, j) if j > i else ():
            if abs(h[b] - h[a]) >= MIN_STRETCH_RAD:
                out.append((a, b, float(h[b] - h[a]),
                            np.array([right[b] - right[a], left[b] - left[a]])))
    return out


def predicted_turn(wheels: FloatArray, multipliers: Values, radius: float,
                   separation: float) -> float:
    """The turn [rad] a geometry gives to the right and left wheel angles ``wheels``."""
    return float(radius * (multipliers[1] * wheels[0] - multipliers[0] * wheels[1])
                 / (separation * multipliers[2]))


# --- a run's start: pinned to the reference's first pose, or fitted -----------------------


@dataclass(frozen=True)
class WholeRun:
    """A run not cut at its slips: its steps left out are bridged by the reference's turn.

    ``left_out``: per step; ``ref``: the reference's x, y, yaw at every pose (the run's
    start, then after each step), interpolated; ``covered``: which poses it covers.
    """

    name: str
    d_left: FloatArray
    d_right: FloatArray
    left_out: npt.NDArray[np.bool_]
    ref: FloatArray
    covered: npt.NDArray[np.bool_]


def whole_run(name: str, stamps: FloatArray, left: FloatArray, right: FloatArray,
              ref: FloatArray, left_out: Sequence[tuple[int, int]] = ()) -> WholeRun:
    """The run whole (``ref``: read with ``yaw``), its ``left_out`` stamp spans marked."""
    t = stamps.astype(np.int64)
    rt = ref[:, 0].astype(np.int64)
    at = np.column_stack([np.interp((t - rt[0]).astype(np.float64),
                                    (rt - rt[0]).astype(np.float64), ref[:, k])
                          for k in (1, 2, 3)])
    return WholeRun(name, np.diff(left), np.diff(right), _in_spans(t, left_out), at,
                    _covered(t, rt))


def later(run: WholeRun, steps: int) -> WholeRun:
    """The run from pose ``steps`` on (its first steps dropped: it starts there)."""
    return WholeRun(run.name, run.d_left[steps:], run.d_right[steps:], run.left_out[steps:],
                    run.ref[steps:], run.covered[steps:])


def start_errors(run: WholeRun, multipliers: Values, lever: Values, radius: float,
                 separation: float, mount_yaw: float | None) -> FloatArray:
    """The reference's point minus the odometry's (m, 2), the slips' turn the reference's.

    ``mount_yaw`` None: the run's start pose fitted (Kabsch); else pinned at the first
    pose the reference covers: its position there, its heading its yaw less ``mount_yaw``.
    """
    x, y, th = integrate(run.d_left, run.d_right, radius * multipliers[0],
                         radius * multipliers[1], separation * multipliers[2],
                         (run.left_out, np.diff(run.ref[:, 2])))
    i = np.flatnonzero(run.covered)
    p = _points(x, y, th, i, lever)
    q = run.ref[i, :2]
    if mount_yaw is None:
        return _kabsch(p, q)
    turn = run.ref[i[0], 2] - mount_yaw - th[i[0]]
    ct, st = math.cos(turn), math.sin(turn)
    d = p - p[0]
    return np.asarray(q - q[0] - np.column_stack((ct * d[:, 0] - st * d[:, 1],
                                                  st * d[:, 0] + ct * d[:, 1])),
                      dtype=np.float64)


def start_fit(runs: Sequence[WholeRun], radius: float, separation: float,
              pinned: bool) -> tuple[FloatArray, FloatArray, float, float]:
    """Multipliers, lever arm [m], the mount's yaw [rad] (NaN: not pinned) and the RMS
    position error [m] of the runs whole, each start pinned or fitted (:func:`start_errors`).
    """
    def res(v: FloatArray) -> FloatArray:
        yaw = float(v[5]) if pinned else None
        return np.concatenate([start_errors(r, v[:3], v[3:5], radius, separation, yaw).ravel()
                               for r in runs])

    x0 = [1.0, 1.0, 1.0, 0.0, 0.0]
    if pinned:  # the mount's yaw to start from: the best of every 10 deg, the rest nominal
        yaws = np.radians(np.arange(-180.0, 180.0, 10.0))
        x0.append(float(min(yaws, key=lambda a: float(np.sum(res(np.array([*x0, a]))**2)))))
    sol = optimize.least_squares(res, np.array(x0), x_scale=[1e-3] * 3 + [1e-2] * (len(x0) - 3),
                                 xtol=1e-12, ftol=1e-12, gtol=1e-12)
    v = np.asarray(sol.x, dtype=np.float64)
    return (v[:3], v[3:5], float(v[5]) if pinned else math.nan,
            math.sqrt(float(np.mean(np.asarray(sol.fun) ** 2))))
