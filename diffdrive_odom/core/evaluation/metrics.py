"""Odometry error against a reference trajectory: the figures of ``diffdrive-odom eval``.

Pure numpy (no bag or message import): ``eval``, ``replay --eval``, the demo and
calibration call the same functions on arrays.

Figures (all in metres / radians; see :class:`Metrics`):

- final position and heading error at the last matched stamp, raw (both trajectories
  in their own frames, which coincide when odometry and ground truth start at the
  same origin) and after an SE(2) alignment of the start (the odometry's first pose
  moved onto the reference's first pose: what dead reckoning can be blamed for);
- absolute trajectory error (ATE) RMSE over all matched stamps, raw, start-aligned,
  and after the least-squares SE(2) fit (a lower bound on shape error);
- relative error per metre travelled: the start-aligned final error divided by the
  distance the reference travelled, and the mean translation/heading drift over every
  stretch of ``segment_length`` metres (KITTI-style relative pose error).

Stamps are matched by interpolating the reference at the odometry's stamps (linear
in x, y and the continuous heading), never extrapolated and never across a gap in
the reference longer than ``max_gap``.

A reference mounted turned on the robot (a marker body's yaw) would turn every
start-aligned figure with it: :func:`travel_yaw` finds that yaw from the reference
alone (its heading against its own direction of travel), for ``eval`` to move the
reference onto base_link before these figures are taken.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np
import numpy.typing as npt

from diffdrive_odom.core.geometry.se2 import between, wrap_angles

BoolArray = npt.NDArray[np.bool_]
FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]


@dataclass(frozen=True)
class Trajectory:
    """Planar poses sorted by stamp; ``yaw`` continuous (unwrapped)."""

    stamp_ns: IntArray
    x: FloatArray
    y: FloatArray
    yaw: FloatArray

    @classmethod
    def from_arrays(
        cls, stamp_ns: npt.ArrayLike, x: npt.ArrayLike, y: npt.ArrayLike, yaw: npt.ArrayLike
    ) -> Trajectory:
        """Sort by stamp, keep the first of repeated stamps, unwrap the heading."""
        t = np.asarray(stamp_ns, dtype=np.int64)
        xs, ys, yaws = (np.asarray(a, dtype=np.float64) for a in (x, y, yaw))
        if not (len(t) == len(xs) == len(ys) == len(yaws)):
            raise ValueError("stamp, x, y and yaw must have the same length")
        order = np.argsort(t, kind="stable")
        t, xs, ys, yaws = t[order], xs[order], ys[order], yaws[order]
        keep = np.concatenate(([True], np.diff(t) > 0)) if len(t) else np.zeros(0, bool)
        finite = np.isfinite(xs) & np.isfinite(ys) & np.isfinite(yaws)
        keep &= finite
        return cls(t[keep], xs[keep], ys[keep], np.unwrap(yaws[keep]))

    def __len__(self) -> int:
        return len(self.stamp_ns)

    def path_length(self) -> FloatArray:
        """Cumulative distance travelled at each pose (0 at the first)."""
        return path_length(np.column_stack((self.x, self.y)))


@dataclass(frozen=True)
class Metrics:
    """Odometry error against a reference; JSON-ready via :meth:`as_dict`."""

    samples: int
    duration_s: float
    distance_m: float  # travelled by the reference over the matched span
    final_position_error_m: float
    final_heading_error_rad: float
    final_position_error_aligned_m: float
    final_heading_error_aligned_rad: float
    ate_rmse_m: float
    ate_rmse_aligned_m: float
    ate_rmse_best_fit_m: float
    final_error_per_m: float  # start-aligned final error / distance_m
    rpe_translation_per_m: float  # mean over stretches of segment_length_m
    rpe_heading_rad_per_m: float
    segment_length_m: float
    rpe_segments: int

    def as_dict(self) -> dict[str, float | int]:
        """Plain dict (NaN where a figure is undefined becomes null in JSON)."""
        return asdict(self)

    def table(self) -> str:
        """Human-readable lines."""
        rows = [
            ("matched samples", f"{self.samples}"),
            ("duration", f"{self.duration_s:.2f} s"),
            ("distance travelled (reference)", f"{self.distance_m:.4f} m"),
            ("final position error", f"{self.final_position_error_m:.4f} m"),
            ("final heading error", f"{math.degrees(self.final_heading_error_rad):.3f} deg"),
            ("final position error, start aligned",
             f"{self.final_position_error_aligned_m:.4f} m"),
            ("final heading error, start aligned",
             f"{math.degrees(self.final_heading_error_aligned_rad):.3f} deg"),
            ("ATE RMSE", f"{self.ate_rmse_m:.4f} m"),
            ("ATE RMSE, start aligned", f"{self.ate_rmse_aligned_m:.4f} m"),
            ("ATE RMSE, best SE(2) fit", f"{self.ate_rmse_best_fit_m:.4f} m"),
            ("final error per metre travelled", f"{100 * self.final_error_per_m:.3f} %"),
            (f"relative error per {self.segment_length_m:g} m ({self.rpe_segments} stretches)",
             f"{100 * self.rpe_translation_per_m:.3f} %, "
             f"{math.degrees(self.rpe_heading_rad_per_m):.3f} deg/m"),
        ]
        width = max(len(k) for k, _ in rows)
        return "\n".join(f"{k:<{width}}  {v}" for k, v in rows)


@dataclass(frozen=True)
class Matched:
    """Odometry poses and the reference interpolated at the same stamps."""

    stamp_ns: IntArray
    est: FloatArray  # (n, 3): x, y, yaw
    ref: FloatArray  # (n, 3)


def covered(ref: Trajectory, stamp_ns: IntArray, max_gap: float) -> BoolArray:
    """Which stamps the reference can be interpolated at (the one matching rule).

    Inside its span (no extrapolation) and not across a gap in the reference longer
    than ``max_gap`` [s]; a stamp equal to a reference pose's always.
    """
    inside = (stamp_ns >= ref.stamp_ns[0]) & (stamp_ns <= ref.stamp_ns[-1])
    i = np.clip(np.searchsorted(ref.stamp_ns, stamp_ns, side="right"), 1, len(ref) - 1)
    gap = (ref.stamp_ns[i] - ref.stamp_ns[i - 1]) * 1e-9
    exact = ref.stamp_ns[i - 1] == stamp_ns
    ok: BoolArray = inside & ((gap <= max_gap) | exact)
    return ok


def interpolate(ref: Trajectory, stamp_ns: IntArray, lag: float = 0.0) -> FloatArray:
    """(n, 3) reference x, y, yaw at ``stamp_ns`` plus ``lag`` [s], linear in each.

    The heading is the continuous one. Check the stamps with :func:`covered` first
    (outside the span the end poses are repeated).
    """
    t0 = ref.stamp_ns[0]
    # Interpolate on stamps relative to the first: float64 keeps ns precision there.
    tr = (ref.stamp_ns - t0).astype(np.float64)
    tq = (stamp_ns - t0).astype(np.float64) + lag * 1e9
    return np.column_stack([np.interp(tq, tr, a) for a in (ref.x, ref.y, ref.yaw)])


def match(est: Trajectory, ref: Trajectory, max_gap: float = 0.5) -> Matched:
    """Interpolate the reference at each odometry stamp inside its span (no extrapolation)."""
    if len(ref) < 2 or len(est) < 1:
        raise ValueError("need at least 2 reference poses and 1 odometry pose")
    ok = covered(ref, est.stamp_ns, max_gap)
    if not ok.any():
        raise ValueError("odometry and reference stamps do not overlap")
    t = est.stamp_ns[ok]
    est_xyz = np.column_stack((est.x[ok], est.y[ok], est.yaw[ok]))
    return Matched(t, est_xyz, interpolate(ref, t))


def align_start(est: FloatArray, ref: FloatArray) -> FloatArray:
    """Move the odometry rigidly so its first pose lies on the reference's first pose."""
    dth = ref[0, 2] - est[0, 2]
    c, s = math.cos(dth), math.sin(dth)
    dx, dy = est[:, 0] - est[0, 0], est[:, 1] - est[0, 1]
    return np.column_stack(
        (ref[0, 0] + c * dx - s * dy, ref[0, 1] + s * dx + c * dy, est[:, 2] + dth)
    )


def align_best_fit(est: FloatArray, ref: FloatArray) -> FloatArray:
    """Least-squares SE(2) fit of the odometry positions onto the reference (2-D Kabsch)."""
    pe, pr = est[:, :2], ref[:, :2]
    me, mr = pe.mean(axis=0), pr.mean(axis=0)
    a, b = pe - me, pr - mr
    dth = math.atan2(float(np.sum(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0])),
                     float(np.sum(a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1])))
    c, s = math.cos(dth), math.sin(dth)
    return np.column_stack(
        (mr[0] + c * a[:, 0] - s * a[:, 1], mr[1] + s * a[:, 0] + c * a[:, 1], est[:, 2] + dth)
    )


def _rmse(est: FloatArray, ref: FloatArray) -> float:
    return float(np.sqrt(np.mean(np.sum((est[:, :2] - ref[:, :2]) ** 2, axis=1))))


def path_length(xy: FloatArray) -> FloatArray:
    """Cumulative distance along rows ``(x, y, ...)`` of ``xy`` (0 at the first)."""
    step = np.hypot(*np.diff(xy[:, :2], axis=0).T)
    return np.concatenate(([0.0], np.cumsum(step)))


def relative_errors(
    est: FloatArray, ref: FloatArray, segment_length: float
) -> tuple[float, float, int]:
    """Mean translation (m/m) and heading (rad/m) error of the motion over each stretch.

    For every matched pose i, j is the first pose at least ``segment_length`` further
    along the reference path; the motion i -> j seen from pose i is compared.
    """
    dist = path_length(ref)
    j = np.searchsorted(dist, dist + segment_length, side="left")
    i = np.flatnonzero(j < len(dist))
    if len(i) == 0:
        return math.nan, math.nan, 0
    j = j[i]
    ex, ey, eth = between(est[i], est[j]).T
    rx, ry, rth = between(ref[i], ref[j]).T
    length = dist[j] - dist[i]
    trans = np.hypot(ex - rx, ey - ry) / length
    head = np.abs(wrap_angles(eth - rth)) / length
    return float(trans.mean()), float(head.mean()), len(i)


def evaluate(
    est: Trajectory, ref: Trajectory, segment_length: float = 1.0, max_gap: float = 0.5
) -> Metrics:
    """Every figure of :class:`Metrics` for odometry ``est`` against reference ``ref``."""
    m = match(est, ref, max_gap)
    e, r = m.est, m.ref
    aligned = align_start(e, r)
    fitted = align_best_fit(e, r) if len(e) >= 2 else aligned
    dist = float(np.sum(np.hypot(*np.diff(r[:, :2], axis=0).T))) if len(r) > 1 else 0.0
    final_aligned = float(np.hypot(*(aligned[-1, :2] - r[-1, :2])))
    trans, head, n_seg = relative_errors(e, r, segment_length)
    return Metrics(
        samples=len(m.stamp_ns),
        duration_s=float((m.stamp_ns[-1] - m.stamp_ns[0]) * 1e-9),
        distance_m=dist,
        final_position_error_m=float(np.hypot(*(e[-1, :2] - r[-1, :2]))),
        final_heading_error_rad=float(wrap_angles(e[-1, 2] - r[-1, 2])),
        final_position_error_aligned_m=final_aligned,
        final_heading_error_aligned_rad=float(wrap_angles(aligned[-1, 2] - r[-1, 2])),
        ate_rmse_m=_rmse(e, r),
        ate_rmse_aligned_m=_rmse(aligned, r),
        ate_rmse_best_fit_m=_rmse(fitted, r),
        final_error_per_m=final_aligned / dist if dist > 0 else math.nan,
        rpe_translation_per_m=trans,
        rpe_heading_rad_per_m=head,
        segment_length_m=segment_length,
        rpe_segments=n_seg,
    )


TRAVEL_MIN_STEP_M = 0.005  # stretches shorter than this are not a direction


def travel_yaw(ref: Trajectory) -> tuple[float, float, float]:
    """The reference frame's yaw in base_link from its direction of travel: (yaw, sigma, m).

    A differential drive's axle centre moves along its heading, never sideways: over a
    stretch, the reference's displacement seen in base_link's heading (the reference's
    less the mount's yaw ``a``) has no sideways part but what a lever arm ``l_x`` ahead of
    the axle adds on a turn, ``dtheta l_x`` (an arm along the axle adds none). Least
    squares over the stretches of ``TRAVEL_MIN_STEP_M`` or more of the reference's own
    path, ``|d| sin(phi - theta + a) = dtheta l_x`` in ``a`` and ``l_x`` (Gauss-Newton
    from the stretches' circular mean): no odometry in it, so nothing of the geometry
    judged. Sigma from the residuals; the third value is the distance it rests on [m]
    (0: the reference never moved: yaw 0, sigma NaN). Driving backwards fits too.
    """
    if len(ref) < 2:
        return 0.0, math.nan, 0.0
    path = ref.path_length()
    ends = np.searchsorted(path, np.arange(0.0, path[-1], TRAVEL_MIN_STEP_M), side="left")
    ends = np.unique(np.append(ends, len(ref) - 1))
    dx, dy = np.diff(ref.x[ends]), np.diff(ref.y[ends])
    length = np.hypot(dx, dy)
    keep = length >= TRAVEL_MIN_STEP_M
    if keep.sum() < 3:
        return 0.0, math.nan, 0.0
    d, turn = length[keep], np.diff(ref.yaw[ends])[keep]
    rel = wrap_angles(np.arctan2(dy, dx) - 0.5 * (ref.yaw[ends[:-1]] + ref.yaw[ends[1:]]))[keep]
    yaw = -math.atan2(float(np.sum(d * np.sin(rel))), float(np.sum(d * np.cos(rel))))
    lever = 0.0
    for _ in range(20):  # Gauss-Newton on (a, l_x)
        r = d * np.sin(rel + yaw) - turn * lever
        jac = np.column_stack((d * np.cos(rel + yaw), -turn))
        step = np.linalg.lstsq(jac, -r, rcond=None)[0]
        yaw, lever = yaw + float(step[0]), lever + float(step[1])
        if abs(step[0]) < 1e-12:
            break
    r = d * np.sin(rel + yaw) - turn * lever
    jac = np.column_stack((d * np.cos(rel + yaw), -turn))
    cov = np.linalg.pinv(jac.T @ jac) * float(np.sum(r**2)) / max(len(r) - 2, 1)
    return math.remainder(yaw, math.tau), math.sqrt(max(float(cov[0, 0]), 0.0)), float(d.sum())
