"""``replay --online-calibration``: the gyro's online geometry estimate over a bag.

The estimate is the node's own (:mod:`diffdrive_odom.core.estimation.online_geometry`,
through the one pipeline); this module only turns its trace into a few lines: the
estimate at a few points of the run, by distance, then the final one as a block of
ddc's multipliers to paste into the parameter file, as ``calibrate`` prints its own.
Without ``use_imu`` there is nothing to estimate from, which is said.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

from diffdrive_odom.core.estimation.config import OdometrySettings
from diffdrive_odom.core.estimation.online_geometry import (
    CHI2_2DOF_3SIGMA,
    OnlineConfig,
    OnlineEstimate,
)

ROWS = 6  # estimates printed over the run besides the final one
NEEDS_IMU = ("--online-calibration needs the gyro: set use_imu: true in the parameters "
             "(or -p use_imu:=true) and give the bag's Imu topic (--imu-topic)")


def online_settings(settings: OdometrySettings) -> OdometrySettings | str:
    """The settings with the online estimate on (monitor), or why it cannot run."""
    if settings.gyro is None:
        return NEEDS_IMU
    return settings if settings.online is not None else replace(settings, online=OnlineConfig())


def report(trace: list[tuple[int, OnlineEstimate]], final: OnlineEstimate | None) -> str:
    """The lines ``replay --online-calibration`` prints (see the module)."""
    if final is None:
        return "online calibration: not run (no use_imu)"
    lines = ["online calibration (gyro; mean radius held at the configured one):",
             "   time [s]  distance [m]  " + final_header()]
    if trace:
        t0 = trace[0][0]
        picks = _spread(trace, ROWS)
        lines += [f"  {(ns - t0) * 1e-9:9.1f}  {e.distance:12.1f}  {row(e)}" for ns, e in picks]
    excluded = ", ".join(f"{k} {v}" for k, v in sorted(final.excluded.items())) or "none"
    lines.append(f"  final: {final.line()}")
    lines.append(f"  steps used {final.steps} in {final.windows} windows; excluded: {excluded}")
    if not final.determined:
        lines.append("  not yet determined: drive turns both ways (online_calibration_min_turn "
                     "each way); nothing to paste")
        return "\n".join(lines)
    verdict = (f"outside the estimate's 3-sigma region (d^2 {final.mahalanobis2:.1f} > "
               f"{CHI2_2DOF_3SIGMA:.2f}): recalibrate" if final.outside else
               f"inside the estimate's 3-sigma region (d^2 {final.mahalanobis2:.1f})")
    lines.append(f"  configured geometry: {verdict}")
    lines.append("  paste into the parameter file (the scale stays the configured one; the "
                 "gyro cannot see it):")
    lines += ["    " + b for b in final.block().splitlines()]
    return "\n".join(lines)


def plot_path(plot: str | None, online: bool, evaluated: object) -> str | None:
    """Where ``--online-calibration --plot FILE`` draws the estimate (None: not asked).

    FILE itself, or beside it as ``<name>_online.png`` when ``--eval`` draws its own there.
    """
    if not (plot and online):
        return None
    if not evaluated:
        return plot
    p = Path(plot)
    return str(p.with_name(f"{p.stem}_online{p.suffix or '.png'}"))


def plot(path: str | None, trace: list[tuple[int, OnlineEstimate]], name: str) -> str:
    """Draw the estimate over the run into ``path`` (matplotlib, imported only here).

    Returns the line that says where ('' when nothing was asked or there is no estimate).
    """
    if path is None:
        return ""
    if not trace:
        return "online calibration plot: not written (no estimate: no step counted)\n"
    from diffdrive_odom.tools import online_plot

    online_plot.write(path, trace, f"{name}: online geometry estimate from the gyro")
    return f"online calibration plot: {path}\n"


def final_header() -> str:
    """The column heads of :func:`row`."""
    return "left (+- 1 sigma)     right (+- 1 sigma)    separation (+- 1 sigma)  turned L/R [rad]"


def row(e: OnlineEstimate) -> str:
    """One estimate as a table row."""
    cells = [f"{m:.5f} +- {s:.5f}" for m, s in zip(e.multipliers, e.stddevs, strict=True)]
    mark = "" if e.determined else "  (not yet determined)"
    return (f"{cells[0]:20s}  {cells[1]:20s}  {cells[2]:22s}  "
            f"{e.turned[0]:5.1f} / {e.turned[1]:5.1f}{mark}")


def _spread(trace: list[tuple[int, OnlineEstimate]], n: int
            ) -> list[tuple[int, OnlineEstimate]]:
    """``n`` entries evenly spread by distance, the last one included."""
    total = trace[-1][1].distance
    if total <= 0.0 or len(trace) <= n:
        return trace[-n:]
    out: list[tuple[int, OnlineEstimate]] = []
    k = 0
    for i in range(1, n + 1):
        goal = total * i / n
        while k < len(trace) - 1 and trace[k][1].distance < goal:
            k += 1
        if not out or out[-1] is not trace[k]:
            out.append(trace[k])
    return out
