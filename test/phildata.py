"""The real TurtleBot2 recordings of ``../shared/data/phil_train``, read in place (GPL-3.0).

For the tests and ``bench/bench_real_gyro.py``: each run in receive order through the
node's ``ReadingPipeline``, and the anchor every gyro-aided result is judged against, a
ten-line gyrodometry written here without the package (heading = the gyro's trapezoid
integral less its mean rate over the first 2 s standing, distance = the wheels' mean arc
per reading, poses by the midpoint heading). Nominal geometry from the recordings' own
processing script: radius 0.035 m, track 0.23 m, 2578.33 ticks per revolution.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from diffdrive_odom.core.estimation.pipeline import ReadingPipeline
from diffdrive_odom.core.evaluation.metrics import Trajectory
from diffdrive_odom.settings.odometry import odometry_settings
from diffdrive_odom.tools.bags.bagio import open_bag

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "phil_train"
MISSING = f"{DATA} is not here (a user's clone): phil_train is read from ../shared/data"
RUNS = (0, 2, 4, 5, 6, 7, 9)
RADIUS, TRACK, TICKS = 0.035, 0.23, 2578.33
NOMINAL: dict[str, Any] = {"wheel_radius": RADIUS, "wheel_separation": TRACK,
           "left_wheel_names": ["wheel_left_joint"], "right_wheel_names": ["wheel_right_joint"],
           "ticks_per_revolution": TICKS, "encoder_counter_bits": 16}


@dataclass
class Run:
    """One recording in receive order: (kind, log ns, message)."""

    messages: list[tuple[str, int, Any]]
    truth: Trajectory | None


def stamp(msg: Any) -> int:
    """A header's stamp [ns]."""
    return int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)


def load(path: Path) -> Run:
    """One run: its sensor messages in receive order, the Vicon as a trajectory."""
    messages: list[tuple[str, int, Any]] = []
    gt: list[tuple[int, float, float, float]] = []
    with open_bag(path) as reader:
        for conn, log_ns, raw in reader.messages():
            msg = reader.deserialize(raw, conn.msgtype)
            if conn.topic == "/ground_truth/pose":
                q = msg.pose.orientation
                yaw = math.atan2(2 * (q.w * q.z + q.x * q.y), 1 - 2 * (q.y * q.y + q.z * q.z))
                gt.append((stamp(msg), msg.pose.position.x, msg.pose.position.y, yaw))
            else:
                messages.append((conn.topic, log_ns, msg))
    truth = Trajectory.from_arrays(*zip(*gt, strict=True)) if gt else None
    return Run(messages, truth)


# A gyro step judged for good: (t0, t1, wheel arcs, slip, standing), from GyroHeading.observer.
Judged = tuple[int, int, tuple[float, float], bool, bool]


def package(run: Run, params: dict[str, Any], judged: list[Judged] | None = None
            ) -> tuple[Trajectory, ReadingPipeline]:
    """The node's estimator over the run (nominal geometry + ``params``): poses, pipeline.

    ``judged``: filled with every gyro step judged for good, through the observer the
    online calibration listens on (it is called in turn).
    """
    pipe = ReadingPipeline(odometry_settings({**NOMINAL, **params}))
    gyro = pipe.gyro
    if judged is not None and gyro is not None:
        listener = gyro.observer

        def observe(g: Any, t0: int, t1: int, arcs: tuple[float, float], raw: float | None,
                    slip: bool, standing: bool) -> None:
            judged.append((t0, t1, arcs, slip, standing))
            if listener is not None:
                listener(g, t0, t1, arcs, raw, slip, standing)

        gyro.observer = observe
    ts: list[int] = []
    poses: list[tuple[float, float, float]] = []
    for topic, log_ns, msg in run.messages:
        if topic == "/imu":
            w = msg.angular_velocity
            pipe.feed_imu(stamp(msg), w.x, w.y, w.z, receive_ns=log_ns)
        elif topic == "/joint_states":
            pipe.feed(stamp(msg), list(msg.name), list(msg.position), receive_ns=log_ns)
            p = pipe.estimator.pose
            ts.append(stamp(msg))
            poses.append((p.x, p.y, p.theta))
    x, y, th = zip(*poses, strict=True)
    return Trajectory.from_arrays(ts, x, y, th), pipe


def wheel_angles(run: Run, held: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The wheels' stamps [ns] and joint angles [rad] from 0, the 16-bit counters unwrapped.

    ``held`` False: the readings the driver held (counters repeated) left out.
    """
    js = [(stamp(m), *m.position) for t, _, m in run.messages if t == "/joint_states"]
    t, left, right = (np.array(c, dtype=float) for c in zip(*js, strict=True))
    if not held:
        moved = np.concatenate(([True], (np.diff(left) != 0) | (np.diff(right) != 0)))
        t, left, right = t[moved], left[moved], right[moved]
    tick = 2 * math.pi / TICKS
    phi_l, phi_r = (np.concatenate(([0.0], np.cumsum(tick * ((np.diff(c) + 32768) % 65536
                                                              - 32768)))) for c in (left, right))
    return t, phi_l, phi_r


def anchor(run: Run) -> Trajectory:
    """The ten-line gyrodometry: the gyro's heading (less its first 2 s), the wheels' distance."""
    imu = [(stamp(m), m.angular_velocity.z) for t, _, m in run.messages if t == "/imu"]
    tj, phi_l, phi_r = wheel_angles(run)
    ti, w = (np.array(c, dtype=float) for c in zip(*sorted(imu), strict=True))
    arc = [RADIUS * np.diff(phi) for phi in (phi_l, phi_r)]
    bias = w[ti < ti[0] + 2e9].mean()
    heading = np.concatenate(([0.0], np.cumsum(0.5 * (w[1:] + w[:-1]) * np.diff(ti) * 1e-9)))
    th = np.interp(tj, ti, heading - bias * (ti - ti[0]) * 1e-9)
    mid, ds = 0.5 * (th[1:] + th[:-1]), 0.5 * (arc[0] + arc[1])
    x = np.concatenate(([0.0], np.cumsum(ds * np.cos(mid))))
    y = np.concatenate(([0.0], np.cumsum(ds * np.sin(mid))))
    return Trajectory.from_arrays(tj.astype(np.int64), x, y, th)


def turned(traj: Trajectory) -> float:
    """Radians turned either way."""
    return float(np.sum(np.abs(np.diff(traj.yaw))))


@dataclass(frozen=True)
class Ratios:
    """The ratios ``(u, v) = (r_R/b, r_L/b)`` fitted to a heading, and their covariance."""

    x: np.ndarray
    cov: np.ndarray

    def separation(self) -> tuple[float, float]:
        """The track's multiplier (mean radius held at the nominal) and its 1 sigma."""
        s = float(self.x[0] + self.x[1])
        return (2 * RADIUS / s / TRACK, 2 * RADIUS / s ** 2 / TRACK
                * math.sqrt(float(np.sum(self.cov))))

    def left(self) -> tuple[float, float]:
        """The left radius multiplier ``2v/(u+v)`` (the wheel ratio) and its 1 sigma."""
        u, v = (float(c) for c in self.x)
        s = u + v
        jac = np.array([-2 * v / s ** 2, 2 / s - 2 * v / s ** 2])
        return 2 * v / s, math.sqrt(float(jac @ self.cov @ jac))


def _ratios(rows: np.ndarray, turns: np.ndarray) -> tuple[Ratios, float]:
    """Least squares of the heading changes on the joint increments (and any further
    columns, e.g. a bias's time); the covariance of (u, v) from the residuals' spread."""
    x, *_ = np.linalg.lstsq(rows, turns, rcond=None)
    resid = turns - rows @ x
    ss = float(resid @ resid)
    cov = np.linalg.inv(rows.T @ rows) * ss / (len(turns) - rows.shape[1])
    return Ratios(x[:2], cov[:2, :2]), ss


def _increments(run: Run, window_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Window edges [ns] over the run and the joint increments ``(dphi_R, -dphi_L)`` over
    each window, the readings the driver held (counters repeated) left out."""
    tj, phi_l, phi_r = wheel_angles(run, held=False)
    edges = np.arange(tj[0] + 1e9, tj[-1] - 1e9, window_s * 1e9)
    left, right = (np.interp(edges, tj, p) for p in (phi_l, phi_r))
    return edges, np.column_stack([np.diff(right), -np.diff(left)])


def vicon_ratios(runs: list[Run], window_s: float = 0.5) -> Ratios:
    """The ratios fitted to the Vicon's heading, windows pooled over ``runs``.

    Least squares over windows of ``window_s``: the Vicon's heading change against the
    wheels' joint increments, the Vicon taken at the wheels' stamps less their lag
    behind it (:func:`vicon_lag`; without it the residuals are five times larger).
    """
    rows, ys = [], []
    for run in runs:
        assert run.truth is not None
        edges, inc = _increments(run, window_s)
        lag = vicon_lag(run, "/joint_states") * 1e9
        yaw = np.interp(edges - lag, run.truth.stamp_ns.astype(float), np.unwrap(run.truth.yaw))
        rows.append(inc)
        ys.append(np.diff(yaw))
    return _ratios(np.concatenate(rows), np.concatenate(ys))[0]


def gyro_ratios(run: Run, window_s: float = 0.5, span: float = 0.3) -> Ratios:
    """The ratios fitted to the gyro's heading in one batch, over one whole run.

    As :func:`vicon_ratios` with the gyro's trapezoid integral in place of the Vicon, a
    constant bias fitted beside the ratios, and the IMU's shift from the wheels' stamps
    the one of least residual within ``span`` (5 ms steps). The reference for runs
    without motion capture: written here without the package, and where the Vicon is
    there it agrees with the Vicon's fit on the same run.
    """
    imu = sorted((stamp(m), m.angular_velocity.z) for t, _, m in run.messages if t == "/imu")
    ti, w = (np.array(c, dtype=float) for c in zip(*imu, strict=True))
    heading = np.concatenate(([0.0], np.cumsum(0.5 * (w[1:] + w[:-1]) * np.diff(ti) * 1e-9)))
    edges, inc = _increments(run, window_s)
    rows = np.column_stack([inc, np.diff(edges) * 1e-9])
    fits = [_ratios(rows, np.diff(np.interp(edges + shift * 1e9, ti, heading)))
            for shift in np.arange(-span, span + 1e-9, 0.005)]
    return min(fits, key=lambda fit: fit[1])[0]


def vicon_lag(run: Run, stream: str, span: float = 0.3) -> float:
    """How much later [s] ``stream``'s stamps ("/imu" or "/joint_states") are than the Vicon's.

    The shift that best fits the stream's turn over 0.25 s windows to the Vicon's
    (least squares, a scale fitted per shift), searched within ``span`` in 2 ms steps.
    """
    assert run.truth is not None
    if stream == "/imu":
        imu = sorted((stamp(m), m.angular_velocity.z) for t, _, m in run.messages if t == stream)
        t, w = (np.array(c, dtype=float) for c in zip(*imu, strict=True))
        turn = np.concatenate(([0.0], np.cumsum(0.5 * (w[1:] + w[:-1]) * np.diff(t) * 1e-9)))
    else:
        t, phi_l, phi_r = wheel_angles(run, held=False)
        turn = RADIUS * (phi_r - phi_l) / TRACK
    edges = np.arange(t[0] + 1e9, t[-1] - 1e9, 0.25e9)
    dv = np.diff(np.interp(edges, run.truth.stamp_ns.astype(float), run.truth.yaw))
    best = (math.inf, 0.0)
    for shift in np.arange(-span, span + 1e-9, 0.002):
        d = np.diff(np.interp(edges + shift * 1e9, t, turn))
        k = float(d @ dv) / float(d @ d)
        best = min(best, (float(np.sum((dv - k * d) ** 2)), float(shift)))
    return best[1]


def verdicts(run: Run, judged: list[Judged]) -> tuple[int, int, int, int]:
    """The slip and standstill verdicts against the Vicon (its stamps aligned to the wheels').

    Returns (flagged, flagged where the wheels' turn is off the Vicon's by over 5 mrad + 3 %
    of it: a slip the Vicon confirms; standing, standing where the Vicon moved over 2 mm or
    3 mrad: a wrong standstill). The wheels' turn is taken over the nominal track / 1.02
    (the Vicon says it is 1-4 % wider).
    """
    truth = run.truth
    assert truth is not None
    lag = vicon_lag(run, "/joint_states") * 1e9
    tv = truth.stamp_ns.astype(float)

    def at(t: int) -> tuple[float, float, float]:
        return (float(np.interp(t + lag, tv, truth.x)), float(np.interp(t + lag, tv, truth.y)),
                float(np.interp(t + lag, tv, truth.yaw)))

    flagged = confirmed = standing = moved = 0
    for t0, t1, (s_l, s_r), slip, still in judged:
        (x0, y0, h0), (x1, y1, h1) = at(t0), at(t1)
        turn = h1 - h0
        if slip:
            flagged += 1
            confirmed += abs((s_r - s_l) / TRACK / 1.02 - turn) > 0.005 + 0.03 * abs(turn)
        if still:
            standing += 1
            moved += math.hypot(x1 - x0, y1 - y0) > 0.002 or abs(turn) > 0.003
    return flagged, confirmed, standing, moved
