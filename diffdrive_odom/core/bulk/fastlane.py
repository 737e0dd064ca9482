"""The fast lane: stretches of readings where no rule can fire, integrated in bulk.

Offline work (``replay``) feeds millions of readings, and the one
:class:`~diffdrive_odom.core.estimation.pipeline.ReadingPipeline` costs microseconds a
reading in Python. The pipeline stays the only definition of the rules: this module
decides nothing on its own, and where it needs a rule in array form it calls the form
that lives beside the scalar one in the rule's own module (the counter unwrap and the
increments: :func:`~diffdrive_odom.core.estimation.wheels.encoders.position_increments`; the
plausibility limits: :func:`~diffdrive_odom.core.estimation.wheels.plausibility.plausible_steps`;
the publish gate: :meth:`~diffdrive_odom.core.estimation.gate.PublishGate.passed`;
the chord: :func:`~diffdrive_odom.core.geometry.integration.chord_array`; whether bulk
is allowed at all:
:attr:`~diffdrive_odom.core.estimation.config.OdometrySettings.takes_bulk`). A
conservative array pre-check (:func:`_arrays`) marks each reading that the pipeline
would merely integrate from the one before: the configured joints present with one
value per name, positions finite and in the counter's range, a positive stamp later
than the last by at most ``max_reading_gap``, a plausible step by a margin, no clock
offset still to be named. A run of them that starts where the pipeline has nothing
pending (:meth:`ReadingPipeline.handover`: no held reading, stale stamps or timeline on
trial, the reference being the reading before, from positions) is integrated in bulk
here and its end state handed back (:meth:`ReadingPipeline.take_back`). Every other
reading goes through the pipeline.

The bulk step is the pipeline's arithmetic in array form, in the same order where it
matters: headings wrapped one step at a time, positions and the geometry sensitivity
``J`` summed in the scalar's order of additions (interleaved cumulative sums), so
poses agree to the last bits. The pose covariance uses the closed form of the
recursion ``P <- F_pose P F_pose^T + N``: every ``F_pose`` is ``[[1, 0, a], [0, 1, b],
[0, 0, 1]]`` (``a, b`` the step's world displacement, ``-dy`` and ``dx``), so their
product from step ``k`` to ``n`` is the same form with the sums of ``a`` and ``b``
between them, and ``P_n = sum_k Phi(n, k) N_k Phi(n, k)^T`` (``N_0`` the start ``P``)
expands into cumulative sums of ``N`` weighted by 1, ``A_k``, ``B_k`` and their
products (:func:`~diffdrive_odom.core.uncertainty.fastcov.propagated`). A run never
exceeds :data:`CHUNK` steps, with ``A`` and ``B`` counted from its start, so the
expansion does not cancel badly.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass
from typing import Protocol, TypeVar

import numpy as np
import numpy.typing as npt

from diffdrive_odom.core.bulk.readings import JointBlock, JointReading
from diffdrive_odom.core.estimation.gate import PublishGate
from diffdrive_odom.core.estimation.pipeline import ReadingPipeline
from diffdrive_odom.core.estimation.results import Handover, Outcome
from diffdrive_odom.core.estimation.stamps import StampSource, in_sync
from diffdrive_odom.core.estimation.wheels.counts import judged_steps
from diffdrive_odom.core.estimation.wheels.encoders import (
    JointLookup,
    WheelIncrement,
    WheelReading,
    counter_range,
    position_increments,
)
from diffdrive_odom.core.estimation.wheels.estimator import Step
from diffdrive_odom.core.estimation.wheels.plausibility import plausible_steps
from diffdrive_odom.core.geometry.integration import Pose2D, chord_array
from diffdrive_odom.core.geometry.kinematics import body_from_arcs, wheel_arcs
from diffdrive_odom.core.geometry.se2 import wrap_angle
from diffdrive_odom.core.uncertainty.fastcov import (
    BulkModel,
    BulkSteps,
    CovarianceState,
    bulk_covariance,
    chain_sum,
)
from diffdrive_odom.core.uncertainty.propagation import (
    pose_message_covariance,
    twist_message_covariance,
)

Array = npt.NDArray[np.float64]
CHUNK = 1024  # readings decoded into arrays at a time (memory stays flat)
MARGIN = 1.0 - 1e-9  # the plausibility limits, tightened: borderline steps go the scalar way


class Reading(Protocol):
    """One JointState as the estimator takes it (``core.bulk.readings.JointReading`` is one).

    Replay's readings also carry ``log_ns``, the receive time (read where present).
    """

    @property
    def stamp_ns(self) -> int:
        """Header stamp (measurement time) [ns]."""

    @property
    def names(self) -> Sequence[str]:
        """Joint names, in the order of the arrays."""

    @property
    def position(self) -> Sequence[float]:
        """Joint angles [rad] (may be empty: velocities are integrated instead)."""

    @property
    def velocity(self) -> Sequence[float]:
        """Joint rates [rad/s]."""


R = TypeVar("R", bound=Reading)


@dataclass(frozen=True)
class Stretch:
    """Readings integrated in bulk: all ``updated``; the poses of those the gate passed."""

    count: int
    # every reading's step (the estimator's last_increment after each): header stamps,
    # dt, d_left, d_right, as core.bulk.batch.wheel_steps collects them
    steps: tuple[npt.NDArray[np.int64], Array, Array, Array]
    stamp_ns: list[int]
    log_ns: list[int]
    pose: Array  # (published, 3): x, y, theta
    twist: Array  # (published, 2): linear, angular
    # (published, 6) / (published, 3) entries of the propagated covariances; None: static
    pose_covariance: Array | None
    twist_covariance: Array | None
    static: tuple[list[float], list[float]]

    def poses(self) -> Iterator[tuple[int, int, Pose2D, float, float, list[float], list[float]]]:
        """Each published pose: stamp, log time, pose, twist, 6x6 covariances (built lazily)."""
        pcov, tcov = self.static
        for k, (stamp, log) in enumerate(zip(self.stamp_ns, self.log_ns, strict=True)):
            x, y, th = self.pose[k].tolist()
            lin, ang = self.twist[k].tolist()
            if self.pose_covariance is not None and self.twist_covariance is not None:
                p = self.pose_covariance[k].tolist()
                t = self.twist_covariance[k].tolist()
                pcov = pose_message_covariance(((p[0], p[1], p[2]), (p[1], p[3], p[4]),
                                                (p[2], p[4], p[5])))
                tcov = twist_message_covariance(((t[0], t[1]), (t[1], t[2])))
            yield stamp, log, Pose2D(x, y, th), lin, ang, pcov, tcov


@dataclass(frozen=True)
class _Chunk:
    """A chunk's readings as arrays; row 0 of ``values`` / ``stamps`` is the reference."""

    values: Array  # (n + 1, wheels)
    header: npt.NDArray[np.int64]  # (n,) header stamps
    logs: npt.NDArray[np.int64]  # (n,) receive times (0: unknown)
    stamps: npt.NDArray[np.int64]  # (n + 1,) stamps as the pipeline uses them
    # (n + 1,) where each row's counts were first seen, each row the reference in turn
    changed: npt.NDArray[np.int64]
    moved: npt.NDArray[np.bool_]  # (n,) the step changes the counts
    dt: Array  # (n,) the interval each step is judged over (CountTrack.judged)
    before: npt.NDArray[np.int64]  # (n + 1,) the last step before each row that moved (-1)
    d_left: Array
    d_right: Array
    peak: Array
    ds: Array
    dtheta: Array
    plain: npt.NDArray[np.bool_]

    def last_move(self, i: int, first: WheelIncrement | None) -> WheelIncrement | None:
        """The last step before row ``i`` that moved the counts (``first``: none in it)."""
        m = int(self.before[i])
        if m < 0:
            return first
        return WheelIncrement(float(self.dt[m]), float(self.d_left[m]), float(self.d_right[m]),
                              float(self.peak[m]))


def lanes(
    pipe: ReadingPipeline, readings: Iterable[R | JointBlock], check_clock: bool = True,
    chunk: int = CHUNK, receive: bool = True,
) -> Iterator[tuple[R | JointReading, Outcome] | Stretch]:
    """Feed ``readings`` to ``pipe``: each reading's outcome, or a stretch done in bulk.

    A :class:`~diffdrive_odom.core.bulk.readings.JointBlock` among them is taken as its
    readings in order, its arrays as they are. The readings' ``log_ns`` is their receive
    time, as ``replay`` feeds them (``receive`` False: not known, and readings need no
    ``log_ns``); ``check_clock`` as in :meth:`ReadingPipeline.feed`.
    """
    lookup = JointLookup(pipe.settings.encoders)
    pending: list[R] = []
    for item in readings:
        if isinstance(item, JointBlock):
            if pending:
                yield from _chunk_lanes(pipe, pending, lookup, check_clock, receive)
                pending = []
            for start in range(0, len(item), chunk):
                yield from _chunk_lanes(pipe, item[start:start + chunk], lookup, check_clock,
                                        receive)
            continue
        pending.append(item)
        if len(pending) >= chunk:
            yield from _chunk_lanes(pipe, pending, lookup, check_clock, receive)
            pending = []  # before the next is read: one chunk in memory, not two
    if pending:
        yield from _chunk_lanes(pipe, pending, lookup, check_clock, receive)


def _chunk_lanes(
    pipe: ReadingPipeline, block: Sequence[R] | JointBlock, lookup: JointLookup,
    check_clock: bool, receive: bool,
) -> Iterator[tuple[R | JointReading, Outcome] | Stretch]:
    first_moved = pipe.handover().counts[1]  # the last step that moved, as the chunk starts
    c = _arrays(pipe, block, lookup, check_clock, receive)
    n = len(block)
    ends = np.append(np.flatnonzero(~c.plain), n)
    i = scalar_until = 0
    while i < n:
        if i >= scalar_until and c.plain[i]:
            state = pipe.handover()
            ref = state.reference
            if (ref is not None and not ref.from_velocity and ref.stamp_ns == c.stamps[i]
                    and state.counts == (c.changed[i], c.last_move(i, first_moved))
                    and ref.values == tuple(c.values[i].tolist())):
                j = int(ends[np.searchsorted(ends, i)])
                stretch = _bulk(pipe, state, c, i, j)
                if stretch is not None:
                    yield stretch
                    i = j
                    continue
                scalar_until = j  # something not finite: the pipeline says what
        r = block[i]
        outcome = pipe.feed(r.stamp_ns, r.names, r.position, r.velocity,
                            _log_ns(r) if receive else None, check_clock)
        yield r, outcome
        i += 1
        if outcome.warning and i < n:  # the driver's clock is named: no longer a reason
            yield from _chunk_lanes(pipe, block[i:], lookup, check_clock, receive)
            return


def _log_ns(reading: Reading) -> int:
    """The reading's receive time (``log_ns``; 0: it has none)."""
    return int(getattr(reading, "log_ns", 0))


def _arrays(
    pipe: ReadingPipeline, block: Sequence[Reading] | JointBlock, lookup: JointLookup,
    check_clock: bool, receive: bool,
) -> _Chunk:
    """Decode a chunk into arrays and mark its plain readings (see the module's text)."""
    settings = pipe.settings
    enc, cfg = settings.encoders, settings.estimator
    wheels = 2 * len(enc.left_wheel_names)
    bad = [math.nan] * wheels
    rows: Sequence[Sequence[float]] | Array
    if isinstance(block, JointBlock):  # one layout: the same test for every row at once
        idx = lookup.indices(block.names)
        joints = len(block.names)
        if (idx is None or block.position.shape[1] != joints
                or block.velocity.shape[1] not in (0, joints)):
            rows = np.full((len(block), wheels), math.nan)
        else:
            rows = block.position[:, idx]
        header, logs = block.stamp_ns, block.log_ns
        if not receive:
            logs = np.zeros(len(block), dtype=np.int64)
    else:
        listed: list[Sequence[float]] = []
        for r in block:
            names, pos = r.names, r.position
            found = lookup.indices(names)
            if (found is None or len(pos) != len(names)
                    or len(r.velocity) not in (0, len(names))):
                listed.append(bad)
            else:
                listed.append([pos[k] for k in found])
        rows = listed
        header = np.array([r.stamp_ns for r in block], dtype=np.int64)
        logs = (np.array([_log_ns(r) for r in block], dtype=np.int64) if receive
                else np.zeros(len(block), dtype=np.int64))
    state = pipe.handover()
    ref = state.reference
    usable = ref is not None and not ref.from_velocity
    with np.errstate(all="ignore"):
        first = np.asarray([ref.values if usable and ref else bad], dtype=np.float64)
        values = np.concatenate((first, np.asarray(rows, dtype=np.float64).reshape(-1, wheels)))
        receive = settings.stamp_source is StampSource.RECEIVE_TIME
        used = np.where(logs > 0, logs, header) if receive else header
        stamps = np.concatenate(([ref.stamp_ns if usable and ref else 0], used))
        clock_ok = np.ones(len(block), dtype=np.bool_)
        if check_clock and not receive and not state.clock_named:
            clock_ok = (logs <= 0) | (used <= 0) | in_sync(used - logs)
        cur = values[1:]
        ok = np.isfinite(cur).all(axis=1) & (used > 0) & clock_ok
        if enc.counter_bits > 0:
            low, high = counter_range(enc.counter_bits)
            ok &= (cur.min(axis=1) >= low) & (cur.max(axis=1) < high)
        dt_ns = stamps[1:] - stamps[:-1]
        d_left, d_right, peak = position_increments(enc, values)
        judged = judged_steps(values, stamps, state.counts if usable else (0, None),
                              dt_ns * 1e-9, (d_left, d_right), cfg, MARGIN)
        arcs = wheel_arcs(settings.geometry, d_left, d_right)
        ds, dtheta = body_from_arcs(settings.geometry, *arcs)
        dt = judged.dt
        ok &= ((dt_ns > 0) & (dt_ns * 1e-9 <= cfg.max_reading_gap) & judged.carried_on
               & plausible_steps(cfg, dt, d_left, d_right, peak, arcs, MARGIN)
               & np.isfinite(ds / dt) & np.isfinite(dtheta / dt))
    if not settings.takes_bulk:
        ok[:] = False
    return _Chunk(values=values, header=header, logs=logs, stamps=stamps,
                  changed=judged.changed, moved=judged.moved, dt=dt, before=judged.before,
                  d_left=d_left, d_right=d_right, peak=peak, ds=ds, dtheta=dtheta, plain=ok)


SAFE_HEADING = 3.0  # below pi: a heading within (-3, 3) is its own wrap_angle


def _headings(start: float, dth: Array) -> Array:
    """``start`` and the heading after each step, bit for bit as the pipeline wraps them.

    The pipeline wraps one step at a time (``wrap_angle(theta + dtheta)``).
    Why not a Python loop: where no heading leaves (-SAFE_HEADING, SAFE_HEADING),
    wrapping changes nothing (``math.remainder`` returns such an angle as it is), and
    ``np.cumsum`` adds one after another in order, so it rounds as the loop does. Only
    the steps near +-pi go one by one.
    """
    n = len(dth)
    out = np.empty(n + 1)
    out[0] = t = start
    k = 0
    while k < n:
        run = np.cumsum(np.concatenate(([t], dth[k:])))[1:]
        over = np.flatnonzero(np.abs(run) > SAFE_HEADING)
        m = int(over[0]) if len(over) else n - k
        out[k + 1:k + 1 + m] = run[:m]
        k += m
        t = float(out[k])
        while k < n:  # near +-pi: the pipeline's own step, until well inside again
            t = wrap_angle(t + float(dth[k]))
            k += 1
            out[k] = t
            if abs(t) <= SAFE_HEADING:
                break
    return out


def _rolling(prior: Sequence[float], new: Array, size: int) -> tuple[Array, Array]:
    """Sums and counts of the last ``size`` values after each of ``new`` (``prior`` before)."""
    comb = np.concatenate((np.asarray(prior, dtype=np.float64), new))
    start = len(prior)
    counts = np.minimum(np.arange(start + 1, start + len(new) + 1), size).astype(np.float64)
    if size == 1:
        return new, counts
    padded = np.concatenate((np.zeros(size - 1), comb))
    windows = np.lib.stride_tricks.sliding_window_view(padded, size)[start:start + len(new)]
    return windows.sum(axis=1), counts


def _bulk(
    pipe: ReadingPipeline, state: Handover, c: _Chunk, i: int, j: int
) -> Stretch | None:
    """Integrate readings ``i..j-1`` of the chunk from ``state``; hand the end state back.

    None (and nothing changed) if any result is not finite.
    """
    settings, est = pipe.settings, pipe.estimator
    geo, unc = settings.geometry, est.uncertainty
    sl = slice(i, j)
    dt, ds, dth = c.dt[sl], c.ds[sl], c.dtheta[sl]
    d_left, d_right = c.d_left[sl], c.d_right[sl]
    thetas = _headings(state.pose.theta, dth)
    before, after = thetas[:-1], thetas[1:]
    half = 0.5 * dth
    sh, chord = chord_array(ds, dth)
    dx, dy = chord * np.cos(half), chord * np.sin(half)
    cos_b, sin_b = np.cos(before), np.sin(before)
    x = chain_sum(state.pose.x, cos_b * dx, -(sin_b * dy))
    y = chain_sum(state.pose.y, sin_b * dx, cos_b * dy)
    size = settings.estimator.velocity_rolling_window_size
    lin_sum, counts = _rolling(state.windows[0], ds / dt, size)
    ang_sum, _ = _rolling(state.windows[1], dth / dt, size)
    linear, angular = lin_sum / counts, ang_sum / counts
    windows = (tuple(np.concatenate((state.windows[0], ds / dt))[-size:].tolist()),
               tuple(np.concatenate((state.windows[1], dth / dt))[-size:].tolist()))
    gate = PublishGate(settings.publish_rate, state.gate)
    pub = gate.passed(c.stamps[i + 1:j + 1])
    cov = CovarianceState(covariance=state.covariance, sensitivity=state.sensitivity,
                          rates=state.rates)
    static = pipe.covariances()
    pose_covs: Array | None = None
    twist_covs: Array | None = None
    if unc is not None:
        enc = settings.encoders
        props = bulk_covariance(
            BulkModel(noise=unc.model, geometry=geo, ticks_per_revolution=enc.ticks_per_revolution,
                      wheels_per_side=len(enc.left_wheel_names), window=size),
            cov,
            BulkSteps(dt=dt, ds=ds, dtheta=dth, d_left=d_left, d_right=d_right, sinc_half=sh,
                      chord=chord, before=before, after=after))
        if props is None:
            return None
        cov = props.end
        pose_covs, twist_covs = props.pose[pub], props.twist[pub]
    pose = np.column_stack((x, y, after))
    twist = np.column_stack((linear, angular))
    if not (np.isfinite(pose).all() and np.isfinite(twist).all()):
        return None
    k = j - 1
    last_log = int(c.logs[k])
    ref = WheelReading(int(c.stamps[j]), tuple(c.values[j].tolist()), False,
                       last_log if last_log > 0 else None)
    changes = np.flatnonzero(c.moved[sl])  # the last step that moved the counts, if any
    last_move = state.counts[1]
    if len(changes):
        m = i + int(changes[-1])
        last_move = WheelIncrement(float(c.dt[m]), float(c.d_left[m]), float(c.d_right[m]),
                                   float(c.peak[m]))
    end = Handover(reference=ref, counts=(int(c.changed[j]), last_move),
                   pose=Pose2D(float(x[-1]), float(y[-1]), float(thetas[-1])),
                   windows=windows, covariance=cov.covariance, sensitivity=cov.sensitivity,
                   rates=cov.rates, gate=gate.state, clock_named=state.clock_named)
    pipe.take_back(end, j - i, len(pub),
                   WheelIncrement(float(c.dt[k]), float(c.d_left[k]), float(c.d_right[k]),
                                  float(c.peak[k])),
                   Step(float(c.dt[k]), float(c.ds[k]), float(c.dtheta[k])))
    return Stretch(count=j - i, steps=(c.header[sl], dt, d_left, d_right),
                   stamp_ns=c.stamps[i + 1:j + 1][pub].tolist(),
                   log_ns=c.logs[sl][pub].tolist(), pose=pose[pub], twist=twist[pub],
                   pose_covariance=pose_covs, twist_covariance=twist_covs, static=static)
