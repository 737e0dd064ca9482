"""The steps calibration leaves out: those the gyro's slip test flagged, bridged by the reference.

Pure Python + numpy. Where a run was decoded with the gyro (``use_imu`` and IMU
samples, :func:`diffdrive_odom.core.bulk.batch.wheel_steps`), each slip event the node's
own rule found (:mod:`~diffdrive_odom.core.estimation.gyro.slips`, ``slip_min_angle``) spans a
few wheel steps whose wheels turned more than the robot did: no geometry explains them,
and a fit that keeps them takes a spinning wheel for geometry.

How a whole-trajectory objective leaves a step out: the slipped steps are *bridged*
with the reference's own motion over them (its pose at the last step before the slip
to its pose at the end of the slip, in its body frame, moved onto base_link by the
reference's mount as the rest of the reference is: ``M D M^-1``,
:meth:`~diffdrive_odom.core.geometry.mount.Mount.base_motions`), and the wheels' steps
before and after are
integrated as before. Every other step then weighs on the residuals exactly as it
did: its error carries on through the bridge to the end of the run, as it would
without the slip. The alternative, cutting the run at each slip into pieces each
aligned to the reference at its start, also removes the slip, but throws away what
the steps before a slip say about the heading after it (the separation is seen in
the heading accumulated over many turns; a run cut four times sees a fifth of it).
The bridge's cost is the reference's own error over a slip's half second (on a
motion capture, millimetres), and a reference gap at a slip: the bridge is then
widened to the nearest stamps the reference covers (the steps in between are left
out too), or to the run's end. Residual samples inside a bridge are dropped: the
pose there is neither the wheels' nor the reference's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from diffdrive_odom.core.bulk.batch import WheelSteps, integrate_steps
from diffdrive_odom.core.evaluation.metrics import Trajectory, covered, interpolate
from diffdrive_odom.core.evaluation.recorded_run import Run, start_stamp
from diffdrive_odom.core.geometry.integration import Pose2D, integrate_batch
from diffdrive_odom.core.geometry.kinematics import Geometry, body_increment
from diffdrive_odom.core.geometry.mount import AXLE, Mount
from diffdrive_odom.core.geometry.se2 import between

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]


@dataclass(frozen=True)
class Bridge:
    """Steps ``start`` .. ``end - 1`` replaced by the reference's motion over them.

    ``start``/``end`` are pose indices: pose 0 is the run's start, pose k the one after
    step k - 1. ``motion``: the reference's (dx, dy, dtheta) from pose ``start`` to pose
    ``end`` in its body frame at ``start``; None: the bridge runs to the end of the run.
    """

    start: int
    end: int
    motion: tuple[float, float, float] | None


@dataclass(frozen=True)
class LeftOut:
    """What a run leaves out of the fit (:func:`left_out`).

    ``events``: slip events the gyro found; ``steps``: wheel steps left out (the slips'
    and, where the reference has a gap there, the steps up to where it covers);
    ``travel_m`` / ``turn_rad``: the distance and the turn (absolute sums) the wheels
    claimed over them with the nominal geometry; ``reference_turn_rad``: what the
    reference turned over the bridges (absolute sum).
    """

    bridges: tuple[Bridge, ...]
    events: int
    steps: int
    travel_m: float
    turn_rad: float
    reference_turn_rad: float


def slipped(steps: WheelSteps) -> BoolArray:
    """Which steps lie in a slip event (none when no gyro judged them)."""
    mask = np.zeros(len(steps), dtype=bool)
    for first, last in steps.slip_spans or ():
        lo = np.searchsorted(steps.stamp_ns, first, side="left")
        hi = np.searchsorted(steps.stamp_ns, last, side="right")
        mask[lo:hi] = True
    return mask


def pose_stamps(steps: WheelSteps) -> npt.NDArray[np.int64]:
    """The stamp of each pose: the run's start, then the end of each step."""
    return np.concatenate(([start_stamp(steps)], steps.stamp_ns)).astype(np.int64)


def bridges(run: Run, max_gap: float = 0.5) -> tuple[Bridge, ...]:
    """The run's slip events as bridges over its reference (see the module); () if none."""
    steps, ref = run.steps, run.reference
    mask = slipped(steps)
    if ref is None or not mask.any():
        return ()
    n = len(steps)
    stamps = pose_stamps(steps)
    ok = covered(ref, stamps, max_gap)
    edges = np.diff(np.concatenate(([0], mask.astype(np.int8), [0])))
    spans: list[list[int]] = []
    for i0, i1 in zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1), strict=True):
        a, b = int(i0), int(i1)  # poses a (before the first slipped step), b (after the last)
        while a > 0 and not ok[a]:
            a -= 1
        while b <= n and not ok[b]:
            b += 1
        if spans and a <= spans[-1][1]:
            spans[-1][1] = max(spans[-1][1], b)
        else:
            spans.append([a, b])
    out: list[Bridge] = []
    for a, b in spans:
        if b > n:
            out.append(Bridge(a, n + 1, None))
            break
        poses = interpolate(ref, stamps[[a, b]])
        dx, dy, dth = between(poses[:1], poses[1:])[0]
        out.append(Bridge(a, b, (float(dx), float(dy), float(dth))))
    return tuple(out)


def inside(spans: tuple[Bridge, ...], n: int) -> BoolArray:
    """Which of ``n`` steps end inside a bridge (their pose is neither wheels' nor reference's)."""
    mask = np.zeros(n, dtype=bool)
    for b in spans:
        mask[b.start:b.end - 1 if b.motion is not None else n] = True
    return mask


def replaced(spans: tuple[Bridge, ...], n: int) -> BoolArray:
    """Which of ``n`` steps the bridges replace (left out of the fit and of its figures)."""
    gone = np.zeros(n, dtype=bool)
    for b in spans:
        gone[b.start:min(b.end, n)] = True
    return gone


def integrate(steps: WheelSteps, geometry: Geometry, spans: tuple[Bridge, ...],
              mount: Mount = AXLE) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Pose after every step, the bridges' steps by the reference's motion (NaN inside).

    ``mount``: where the reference sits on the robot (the fit's nuisance): its motion is
    moved onto base_link by it. Without bridges, exactly
    :func:`~diffdrive_odom.core.bulk.batch.integrate_steps`. One segment only.
    """
    if not spans:
        return integrate_steps(steps, geometry)
    ds, dth = body_increment(geometry, steps.d_left, steps.d_right)
    n = len(steps)
    x, y, th = (np.full(n, np.nan) for _ in range(3))
    pose, k = Pose2D(), 0
    for b in (*spans, Bridge(n, n, (0.0, 0.0, 0.0))):
        if b.start > k:
            x[k:b.start], y[k:b.start], th[k:b.start] = integrate_batch(
                ds[k:b.start], dth[k:b.start], pose)
            pose = Pose2D(float(x[b.start - 1]), float(y[b.start - 1]), float(th[b.start - 1]))
        if b.motion is None or b.end == b.start:
            break
        mx, my, mth = mount.base_motions(np.array([b.motion]))[0]
        ct, st = math.cos(pose.theta), math.sin(pose.theta)
        pose = Pose2D(pose.x + ct * mx - st * my, pose.y + st * mx + ct * my, pose.theta + mth)
        x[b.end - 1], y[b.end - 1], th[b.end - 1] = pose.x, pose.y, pose.theta
        k = b.end
    return x, y, th


def trajectory(run: Run, geometry: Geometry, spans: tuple[Bridge, ...],
               mount: Mount = AXLE) -> Trajectory:
    """The odometry of ``run`` for ``geometry`` with the bridges (the poses inside dropped)."""
    x, y, th = integrate(run.steps, geometry, spans, mount)
    zero = np.zeros(1)
    return Trajectory.from_arrays(pose_stamps(run.steps), np.concatenate((zero, x)),
                                  np.concatenate((zero, y)), np.concatenate((zero, th)))


def left_out(run: Run, nominal: Geometry, max_gap: float = 0.5) -> LeftOut | None:
    """What ``run`` leaves out of the fit; None when no gyro judged its steps."""
    steps = run.steps
    if steps.slip_spans is None:
        return None
    spans = bridges(run, max_gap)
    gone = replaced(spans, len(steps))
    ds, dth = body_increment(nominal, steps.d_left[gone], steps.d_right[gone])
    turned = sum(abs(b.motion[2]) for b in spans if b.motion is not None)
    return LeftOut(spans, steps.slip_events, int(gone.sum()), float(np.abs(ds).sum()),
                   float(np.abs(dth).sum()), turned)
