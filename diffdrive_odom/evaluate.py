"""``diffdrive-odom eval``: how far odometry is from ground truth, in numbers and a plot.

The metrics are a pure function of two planar trajectories (:func:`evaluate`), so the
demo, calibration and tests call it on arrays; the CLI only reads the bag(s).

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
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Callable, Iterable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from diffdrive_odom import bagio
from diffdrive_odom.cli import HelpFormatter
from diffdrive_odom.odometry import quaternion_to_yaw, stamp_to_ns

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]

POSE_TYPES = (
    "geometry_msgs/msg/PoseStamped",
    "geometry_msgs/msg/PoseWithCovarianceStamped",
    "nav_msgs/msg/Odometry",
    "geometry_msgs/msg/TransformStamped",
    bagio.TF_MESSAGE,
)


@dataclass(frozen=True)
class Trajectory:
    """Planar poses sorted by stamp; ``yaw`` continuous (unwrapped)."""

    stamp_ns: IntArray
    x: FloatArray
    y: FloatArray
    yaw: FloatArray

    @classmethod
    def from_arrays(
        cls, stamp_ns: Any, x: Any, y: Any, yaw: Any
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


def match(est: Trajectory, ref: Trajectory, max_gap: float = 0.5) -> Matched:
    """Interpolate the reference at each odometry stamp inside its span (no extrapolation)."""
    if len(ref) < 2 or len(est) < 1:
        raise ValueError("need at least 2 reference poses and 1 odometry pose")
    t = est.stamp_ns
    inside = (t >= ref.stamp_ns[0]) & (t <= ref.stamp_ns[-1])
    i = np.clip(np.searchsorted(ref.stamp_ns, t, side="right"), 1, len(ref) - 1)
    gap = (ref.stamp_ns[i] - ref.stamp_ns[i - 1]) * 1e-9
    exact = ref.stamp_ns[i - 1] == t
    ok = inside & ((gap <= max_gap) | exact)
    if not ok.any():
        raise ValueError("odometry and reference stamps do not overlap")
    t, i = t[ok], i[ok]
    t0 = ref.stamp_ns[0]
    # Interpolate on stamps relative to the first: float64 keeps ns precision there.
    tr = (ref.stamp_ns - t0).astype(np.float64)
    tq = (t - t0).astype(np.float64)
    ref_xyz = np.column_stack([np.interp(tq, tr, a) for a in (ref.x, ref.y, ref.yaw)])
    est_xyz = np.column_stack((est.x[ok], est.y[ok], est.yaw[ok]))
    return Matched(t, est_xyz, ref_xyz)


def _rot(theta: FloatArray | float) -> tuple[Any, Any]:
    return np.cos(theta), np.sin(theta)


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


def _wrap(a: Any) -> Any:
    return np.remainder(np.asarray(a) + np.pi, 2.0 * np.pi) - np.pi


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

    def local(p: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        c, s = _rot(p[i, 2])
        dx, dy = p[j, 0] - p[i, 0], p[j, 1] - p[i, 1]
        return c * dx + s * dy, -s * dx + c * dy, p[j, 2] - p[i, 2]

    ex, ey, eth = local(est)
    rx, ry, rth = local(ref)
    length = dist[j] - dist[i]
    trans = np.hypot(ex - rx, ey - ry) / length
    head = np.abs(_wrap(eth - rth)) / length
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
        final_heading_error_rad=float(_wrap(e[-1, 2] - r[-1, 2])),
        final_position_error_aligned_m=final_aligned,
        final_heading_error_aligned_rad=float(_wrap(aligned[-1, 2] - r[-1, 2])),
        ate_rmse_m=_rmse(e, r),
        ate_rmse_aligned_m=_rmse(aligned, r),
        ate_rmse_best_fit_m=_rmse(fitted, r),
        final_error_per_m=final_aligned / dist if dist > 0 else math.nan,
        rpe_translation_per_m=trans,
        rpe_heading_rad_per_m=head,
        segment_length_m=segment_length,
        rpe_segments=n_seg,
    )


# --- reading trajectories from bags ------------------------------------------------------


def _pose_of(msg: Any, msgtype: str) -> tuple[Any, Any]:
    """(position-like, quaternion) of one message of a supported type."""
    if msgtype == "geometry_msgs/msg/PoseStamped":
        return msg.pose.position, msg.pose.orientation
    if msgtype in ("nav_msgs/msg/Odometry", "geometry_msgs/msg/PoseWithCovarianceStamped"):
        return msg.pose.pose.position, msg.pose.pose.orientation
    return msg.transform.translation, msg.transform.rotation  # TransformStamped


Notify = Callable[[str], None]
DEFAULT_REFERENCE = "/ground_truth/pose"
# Name parts that mark a topic as ground truth (sim_node and the demo write
# /ground_truth/odom; motion-capture bridges use mocap/vicon/optitrack names).
REFERENCE_HINTS = ("ground_truth", "groundtruth", "mocap", "vicon", "optitrack")


def reference_topic(
    bag: str | Path, requested: str | None, exclude: Iterable[str] = (),
    notify: Notify | None = None,
) -> str:
    """The reference topic to read: ``requested``, else the default, else the one candidate.

    With no topic asked for and no :data:`DEFAULT_REFERENCE` in the bag, a pose-typed
    topic whose name looks like ground truth is taken when it is the only one (and
    ``notify`` is told); otherwise BagError lists what there is.
    """
    if requested is not None:
        return requested
    with bagio.open_bag(bag) as reader:
        posed: list[str] = sorted(
            {str(c.topic) for c in reader.connections if c.msgtype in POSE_TYPES}
            - set(exclude))
    if DEFAULT_REFERENCE in posed:
        return DEFAULT_REFERENCE
    plausible = [t for t in posed if any(h in t.lower() for h in REFERENCE_HINTS)]
    if len(plausible) == 1:
        if notify is not None:
            notify(f"{DEFAULT_REFERENCE} is not in {bag}; using {plausible[0]}, its only "
                   "ground-truth topic (--ground-truth to choose another)")
        return plausible[0]
    which = "several ground-truth topics" if plausible else "no ground-truth topic"
    raise bagio.BagError(
        f"{bag}: {DEFAULT_REFERENCE} is absent and there are {which}; name one with "
        f"--ground-truth (pose topics: {', '.join(posed) or 'none'})")


def read_trajectory(
    bag: str | Path, topic: str, child_frame: str | None = None,
    frame_flag: str = "--child-frame", notify: Notify | None = None,
) -> Trajectory:
    """Poses on ``topic`` by header stamp; for /tf, the transforms to ``child_frame``.

    On a TFMessage topic without ``child_frame``, the only child frame is used (and
    ``notify`` told); with several, BagError names them and ``frame_flag``, the
    option that chooses one.
    """
    by_child: dict[str, tuple[list[int], list[float], list[float], list[float]]] = {}
    seen: set[str] = set()
    with bagio.open_bag(bag) as reader:
        conns = bagio.connections_for(reader, topic, POSE_TYPES)
        for conn, _, raw in reader.messages(connections=conns):
            msg: Any = reader.deserialize(raw, conn.msgtype)
            items = list(msg.transforms) if conn.msgtype == bagio.TF_MESSAGE else [msg]
            for item in items:
                key = ""  # every pose of a topic that is not a TFMessage
                if conn.msgtype in (bagio.TF_MESSAGE, "geometry_msgs/msg/TransformStamped"):
                    child = str(item.child_frame_id).lstrip("/")
                    seen.add(child)
                    if child_frame is not None and child != child_frame.lstrip("/"):
                        continue
                    key = child if conn.msgtype == bagio.TF_MESSAGE else ""
                    p, q = _pose_of(item, "geometry_msgs/msg/TransformStamped")
                else:
                    p, q = _pose_of(item, conn.msgtype)
                ts, xs, ys, yaws = by_child.setdefault(key, ([], [], [], []))
                ts.append(stamp_to_ns(item.header.stamp))
                xs.append(float(p.x))
                ys.append(float(p.y))
                yaws.append(quaternion_to_yaw(q))
    frames = sorted(k for k in by_child if k)
    if child_frame is None and len(frames) > 1:
        raise bagio.BagError(f"{topic}: name the child frame ({frame_flag}); frames: {frames}")
    if child_frame is None and len(frames) == 1 and notify is not None:
        notify(f"{topic}: using child frame '{frames[0]}', the only one ({frame_flag} to "
               "choose)")
    if not by_child:
        if seen:
            raise bagio.BagError(
                f"{topic}: no transform to '{child_frame}' ({frame_flag}); frames: "
                f"{sorted(seen)}")
        raise bagio.BagError(f"{topic}: no poses")
    ((ts, xs, ys, yaws),) = by_child.values()
    return Trajectory.from_arrays(ts, xs, ys, yaws)


# --- output ---------------------------------------------------------------------------------


def plot(
    est: Trajectory,
    ref: Trajectory,
    path: str | Path,
    labels: tuple[str, str] = ("odometry", "reference"),
    max_gap: float = 0.5,
) -> None:
    """PNG: the paths (raw and start-aligned odometry) and the position error over time."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    m = match(est, ref, max_gap)
    aligned = align_start(m.est, m.ref)
    t = (m.stamp_ns - m.stamp_ns[0]) * 1e-9
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(12, 5.5))
    ax1.plot(ref.x, ref.y, "k-", lw=1.5, label=labels[1])
    ax1.plot(est.x, est.y, "-", color="tab:blue", lw=1.0, label=labels[0])
    ax1.plot(aligned[:, 0], aligned[:, 1], "--", color="tab:orange", lw=1.0,
             label=f"{labels[0]}, start aligned")
    ax1.plot(m.ref[-1, 0], m.ref[-1, 1], "ko")
    ax1.plot(m.est[-1, 0], m.est[-1, 1], "o", color="tab:blue")
    ax1.set_aspect("equal", adjustable="datalim")
    ax1.set_xlabel("x [m]")
    ax1.set_ylabel("y [m]")
    ax1.grid(True, alpha=0.3)
    ax1.legend(loc="best", fontsize=8)
    ax1.set_title("path")
    ax2.plot(t, np.hypot(*(m.est[:, :2] - m.ref[:, :2]).T), color="tab:blue", label="raw")
    ax2.plot(t, np.hypot(*(aligned[:, :2] - m.ref[:, :2]).T), "--", color="tab:orange",
             label="start aligned")
    ax2.set_xlabel("time [s]")
    ax2.set_ylabel("position error [m]")
    ax2.grid(True, alpha=0.3)
    ax2.legend(loc="best", fontsize=8)
    ax2.set_title("error against the reference")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def report(
    metrics: Metrics,
    est: Trajectory,
    ref: Trajectory,
    json_path: str | None,
    plot_path: str | None,
    labels: tuple[str, str] = ("odometry", "reference"),
) -> None:
    """Write JSON and PNG when asked, then print the table.

    Files first: a closed pipe on stdout must not lose them.
    """
    if json_path:
        figures = {k: (None if isinstance(v, float) and not math.isfinite(v) else v)
                   for k, v in metrics.as_dict().items()}
        Path(json_path).write_text(json.dumps(figures, indent=2) + "\n", encoding="utf-8")
    if plot_path:
        plot(est, ref, plot_path, labels)
    print(metrics.table())


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog="diffdrive-odom eval",
        description="Compare odometry with ground truth recorded in a bag.",
        formatter_class=HelpFormatter,
    )
    ap.add_argument("bag", help="bag with the odometry (and, by default, the ground truth)")
    ap.add_argument("--odom", default="/odom", metavar="TOPIC",
                    help="odometry topic (any pose type, or /tf)")
    ap.add_argument("--odom-child-frame", default=None, metavar="FRAME",
                    help="odometry child frame on /tf (default: the only one there)")
    ap.add_argument("--ground-truth", default=None, metavar="TOPIC",
                    help="reference topic: PoseStamped, PoseWithCovarianceStamped, Odometry, "
                    f"or TransformStamped on /tf (default: {DEFAULT_REFERENCE}, else the "
                    "bag's only ground-truth topic, e.g. sim_node's /ground_truth/odom)")
    ap.add_argument("--child-frame", default=None, metavar="FRAME",
                    help="reference child frame on /tf (default: the only one there)")
    ap.add_argument("--reference-bag", default=None, metavar="BAG",
                    help="read the reference from this bag instead, e.g. replay's input "
                    "(default: BAG)")
    ap.add_argument("--segment-length", type=float, default=1.0, metavar="M",
                    help="stretch length for the relative error [m]")
    ap.add_argument("--max-gap", type=float, default=0.5, metavar="S",
                    help="longest reference gap to interpolate across [s]")
    ap.add_argument("--json", metavar="FILE",
                    help="write the figures as JSON (default: not written)")
    ap.add_argument("--plot", metavar="FILE", help="write a PNG plot (default: not written)")
    return ap


def output_problem(json_path: str | None, plot_path: str | None) -> str | None:
    """Why ``--json`` / ``--plot`` cannot be written, checked before any work."""
    for flag, path in (("--json", json_path), ("--plot", plot_path)):
        problem = bagio.output_problem(path, flag) if path else None
        if problem:
            return problem
    return None


def main(argv: Sequence[str]) -> int:
    """``diffdrive-odom eval``; exit 2 when a topic, bag or output path cannot be used."""
    args = _parser().parse_args(list(argv))
    if not (args.segment_length > 0 and args.max_gap > 0):
        print("[eval] --segment-length and --max-gap must be > 0", file=sys.stderr)
        return 2
    problem = output_problem(args.json, args.plot)
    if problem:
        print(f"[eval] {problem}", file=sys.stderr)
        return 2

    def notify(text: str) -> None:
        print(f"[eval] {text}", file=sys.stderr)

    ref_bag = args.reference_bag or args.bag
    try:
        est = read_trajectory(args.bag, args.odom, args.odom_child_frame,
                              "--odom-child-frame", notify)
        exclude = [args.odom] if ref_bag == args.bag else []
        gt = reference_topic(ref_bag, args.ground_truth, exclude, notify)
        ref = read_trajectory(ref_bag, gt, args.child_frame, "--child-frame", notify)
        metrics = evaluate(est, ref, args.segment_length, args.max_gap)
        report(metrics, est, ref, args.json, args.plot, (args.odom, gt))
    except (bagio.BagError, ValueError) as err:
        print(f"[eval] {err}", file=sys.stderr)
        return 2
    except OSError as err:  # the output vanished or filled up after the check
        print(f"[eval] cannot write: {err}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
