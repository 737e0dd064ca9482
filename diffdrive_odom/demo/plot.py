"""The demo's picture: commanded path, belief, truth, calibrated and gyro-aided odometry.

Left the paths (the slip events the gyro found marked on the truth), right the drift
over distance; below, on a panel of its own, the gyro-aided replay's online geometry
estimate with its 1-sigma bands (:mod:`diffdrive_odom.tools.replaying.online_plot`).

Pure matplotlib (Agg), imported only when a plot is written.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path

from diffdrive_odom.core.evaluation.metrics import Trajectory, match, path_length
from diffdrive_odom.core.motion.paths import Point
from diffdrive_odom.tools.replaying import online_plot

from .report import FIT, GYRO, NOMINAL, UMBMARK

# key -> colour, line style, legend label (the paths' legend, which says it all), short
# label (the drift panel's, inside its axes). The wheels-only replay is not drawn: it is
# the nominal line (the node's own odometry) to the encoder tick.
STYLES = {
    NOMINAL: ("tab:red", "-", "wheel odometry, nominal geometry (what the robot believes)",
              "wheel odometry, nominal"),
    FIT: ("tab:green", "--", "wheel odometry re-integrated, calibrated (fit){}",
          "calibrated (fit){}"),
    UMBMARK: ("tab:blue", ":", "wheel odometry re-integrated, calibrated (UMBmark){}",
              "calibrated (UMBmark){}"),
    GYRO: ("tab:purple", "-", "gyro-aided odometry (replay, use_imu; nominal geometry)",
           "gyro-aided (use_imu)"),
}


def plot(path: Path, truth: Trajectory, odometry: Mapping[str, Trajectory],
         commanded: Sequence[Sequence[Point]], title: str,
         slips: Sequence[tuple[int, float]] = (), online: online_plot.Trace = (),
         true_multipliers: Sequence[float] | None = None) -> None:
    """Where the robot was told to go, believed it went, really went; the gap growing.

    ``slips``: the slip events, (stamp, size), by the one rule
    (:mod:`~diffdrive_odom.core.estimation.gyro.slips`), marked on the truth and on the
    distance axis; the calibrated lines are then drawn with those steps bridged by the
    truth (as the calibration left them out). ``online``: the online estimate's trace,
    drawn below (``true_multipliers`` dashed).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    fig = plt.figure(figsize=(13, 10.5 if online else 6.5))
    grid = fig.add_gridspec(2 if online else 1, 2, width_ratios=[1.15, 1.0],
                            height_ratios=[2.2, 1.0] if online else [1.0])
    ax1, ax2 = fig.add_subplot(grid[0, 0]), fig.add_subplot(grid[0, 1])
    bridged = " with the slip steps left out" if slips else ""
    for i, points in enumerate(commanded):
        xs, ys = zip(*points, strict=True)
        ax1.plot(xs, ys, "-", color="0.75", lw=6, solid_capstyle="round", zorder=0,
                 label="commanded path (corners; the follower rounds them)" if i == 0
                 else None)
    ax1.plot(truth.x, truth.y, "-", color="black", lw=1.8,
             label="ground truth (where the robot really went)")
    for key, (color, style, label, _) in STYLES.items():
        if key in odometry:
            traj = odometry[key]
            ax1.plot(traj.x, traj.y, style, color=color, lw=1.3, label=label.format(bridged))
    marks = [t for t, _ in slips]
    if marks and len(truth):
        at = np.clip(np.searchsorted(truth.stamp_ns, np.asarray(marks, dtype=np.int64)),
                     0, len(truth) - 1)
        ax1.plot(truth.x[at], truth.y[at], "*", color="tab:orange", ms=14, mec="black",
                 mew=0.6, zorder=5, label="wheel slip (found by the gyro-aided odometry)")
    ax1.plot([0.0], [0.0], "o", color="black", ms=8, label="start (both squares)")
    nominal = odometry[NOMINAL]
    tx, ty = float(truth.x[-1]), float(truth.y[-1])
    ox, oy = float(nominal.x[-1]), float(nominal.y[-1])
    ax1.plot([tx], [ty], "s", color="black", ms=7, label="end: where it really is")
    ax1.plot([ox], [oy], "s", color="tab:red", ms=7, label="end: where odometry says it is")
    ax1.annotate(f"drift at the end: {math.hypot(ox - tx, oy - ty):.2f} m",
                 xy=(0.5 * (ox + tx), 0.5 * (oy + ty)), xytext=(60, 60),
                 textcoords="offset points", color="tab:red", fontsize=10,
                 fontweight="bold", arrowprops={"arrowstyle": "-", "color": "tab:red"},
                 bbox={"boxstyle": "round", "facecolor": "white", "alpha": 0.8,
                       "edgecolor": "none"})
    ax1.set_aspect("equal", adjustable="datalim")
    ax1.set_xlabel("x [m]")
    ax1.set_ylabel("y [m]")
    ax1.grid(True, alpha=0.3)
    ax1.legend(loc="upper center", bbox_to_anchor=(0.5, -0.12), fontsize=8.5, ncol=1)
    ax1.set_title(title)

    top = 0.0
    for key, (color, style, _, short) in STYLES.items():
        if key not in odometry:
            continue
        m = match(odometry[key], truth)
        err = np.hypot(*(m.est[:, :2] - m.ref[:, :2]).T)
        top = max(top, float(err.max()))
        ax2.plot(path_length(m.ref[:, :2]), err, style, color=color, lw=1.5,
                 label=short.format(", slip steps left out" if slips else ""))
    if marks and len(truth):
        travelled = np.interp(np.asarray(marks, dtype=np.float64),
                              truth.stamp_ns.astype(np.float64), truth.path_length())
        for i, d in enumerate(travelled):
            ax2.axvline(float(d), color="tab:orange", lw=1.0, ls="-.",
                        label="wheel slip" if i == 0 else None)
    ax2.set_ylim(0.0, 1.7 * top if top > 0.0 else 1.0)  # room above for the legend
    ax2.set_xlabel("distance driven [m]")
    ax2.set_ylabel("position error of odometry [m]")
    ax2.set_title("odometry drift: distance between belief and truth")
    ax2.grid(True, alpha=0.3)
    ax2.legend(loc="upper left", fontsize=8.5)
    ax2.text(0.0, -0.16,
             "The follower keeps the robot on the path as its wheel odometry sees it;\n"
             "wheel radii or track width slightly off the drawing bend every step the\n"
             "same way, so the real path drifts off. Calibrating from this very run (fit\n"
             "to the ground truth, or UMBmark from where the squares ended) removes that\n"
             "systematic part. A wheel spinning for a moment turns wheel odometry by what\n"
             "the robot never turned: calibration leaves those steps out (found by the\n"
             "gyro); gyro-aided odometry takes their heading from the gyro (Borenstein and\n"
             "Feng's gyrodometry) and their distance from the other wheel.",
             transform=ax2.transAxes, ha="left", va="top", fontsize=8.5,
             bbox={"boxstyle": "round", "facecolor": "white", "alpha": 0.9})
    if online:
        ax3 = fig.add_subplot(grid[1, :])
        online_plot.draw(ax3, online, true_multipliers)
        ax3.set_title("online geometry estimate from the gyro (gyro-aided replay, "
                      "online_calibration: monitor)", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
