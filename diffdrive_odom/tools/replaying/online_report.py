"""``replay --online-calibration``: the gyro's online geometry estimate over a bag.

The estimate is the node's own (:mod:`diffdrive_odom.core.estimation.online.online_geometry`,
through the one pipeline); this module only turns its trace into a few lines: the
estimate at a few points of the run, by distance, then the final one as a block of
ddc's multipliers to paste into the parameter file, as ``calibrate`` prints its own;
with ``--reference-topic`` the reference's scale too (the same as the node's parameter
``online_calibration_reference_topic``).
Without ``use_imu`` there is nothing to estimate from: ``--online-calibration`` turns it
on where the bag has the gyro (its Imu topic), and says so; it is set after every params
source, since a params file's own ``odometry_node`` section beats any ``-p`` (rclpy's
order: ``/**``, where every ``-p`` goes, then the node's own). A bag without the gyro is
said in one line.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable, Mapping
from dataclasses import replace
from pathlib import Path

from diffdrive_odom.core.estimation.config import OdometrySettings
from diffdrive_odom.core.estimation.online.online_estimate import CHI2_2DOF_3SIGMA, OnlineEstimate
from diffdrive_odom.core.geometry.mount import Mount
from diffdrive_odom.settings.errors import ParameterError
from diffdrive_odom.settings.rcl import ParamValue, resolve_parameters
from diffdrive_odom.tools.replaying import online_plot  # matplotlib only where it draws

ROWS = 6  # estimates printed over the run besides the final one
NEEDS_IMU = ("--online-calibration needs the gyro: {bag} has no sensor_msgs/Imu on {topic} "
             "(name the bag's Imu topic with --imu-topic)")


def add_arguments(ap: argparse.ArgumentParser) -> None:
    """``--online-calibration`` and ``--reference-topic`` (replay's flags)."""
    ap.add_argument("--online-calibration", action="store_true",
                    help="print the gyro's online geometry estimate over the run and a block "
                    "to paste (turns use_imu on where the bag has the gyro on --imu-topic)")
    ap.add_argument("--reference-topic", default=None, metavar="TOPIC",
                    help="with --online-calibration: a reference pose in the bag (Odometry or "
                    "PoseStamped: lidar odometry, motion capture, AMCL) for the scale and the "
                    "gyro's scale factor (online_calibration_reference_topic, over the "
                    "params; default: the params' (none): the scale stays the configured one)")


def replay_settings(
    args: argparse.Namespace,
    load: Callable[[argparse.Namespace, Mapping[str, ParamValue] | None], OdometrySettings | str],
    notify: Callable[[str], None],
) -> OdometrySettings | str:
    """The settings replay runs with, or the one line why not.

    ``--reference-topic`` as the node's parameter; with ``--online-calibration`` the
    gyro (where the bag has it: ``notify`` is told) and the estimate on, set after every
    params source (``load``'s second argument: the values settled after them).
    """
    if args.reference_topic and not args.online_calibration:
        return "--reference-topic needs --online-calibration"
    if not args.online_calibration:
        return load(args, None)
    settled = _online_settled(args, notify)
    if isinstance(settled, str):
        return settled
    return load(args, settled)


def _online_settled(args: argparse.Namespace,
                    notify: Callable[[str], None]) -> dict[str, ParamValue] | str:
    """What ``--online-calibration`` sets after the params, or why the bag gives no estimate.

    use_imu where they leave it off and the bag has the gyro; online_calibration monitor
    where they disable it (as the node in monitor: the reference and the other
    online_calibration_* read as it reads them); ``--reference-topic`` as
    online_calibration_reference_topic.
    """
    try:
        values = resolve_parameters(args.ros_params or [], args.node_name, args.namespace)
    except (ParameterError, OSError):
        return {}  # loading the settings says what is wrong
    settled: dict[str, ParamValue] = {}
    if values.get("use_imu") is not True:
        missing = _no_gyro(args.bag, args.imu_topic)
        if missing:
            return missing
        settled["use_imu"] = True
        notify(f"--online-calibration: use_imu on (the parameters leave it off; the bag's "
               f"gyro is on {args.imu_topic})")
    if values.get("online_calibration") == "disabled":
        settled["online_calibration"] = "monitor"
    if args.reference_topic:
        settled["online_calibration_reference_topic"] = args.reference_topic
    return settled


def _no_gyro(bag: str, topic: str) -> str:
    """Why ``bag`` gives no gyro on ``topic`` ('' when it has sensor_msgs/Imu there)."""
    from diffdrive_odom.tools.bags import bagio  # the bag library only now: --help needs none

    try:
        with bagio.open_bag(bag) as reader:
            found = any(c.topic == topic and c.msgtype == bagio.IMU
                        for c in reader.connections)
    except bagio.BagError as err:
        return str(err)
    return "" if found else NEEDS_IMU.format(bag=bag, topic=topic)


def reference_topic(settings: OdometrySettings) -> str | None:
    """The reference topic replay reads, None when the estimate or its reference is off."""
    online = settings.online
    ref = None if settings.gyro is None or online is None else online.reference
    return None if ref is None else ref.topic


def with_static_mount(bag: str, settings: OdometrySettings) -> OdometrySettings:
    """The settings with the reference's mount read from the bag's /tf_static, when asked.

    ``online_calibration_reference_frame`` names the reference's frame: replay takes the
    transform to it from the bag (the node from the live /tf_static); BagError when the
    bag has none.
    """
    online = settings.online
    ref = None if reference_topic(settings) is None or online is None else online.reference
    if online is None or ref is None or not ref.frame:
        return settings
    from diffdrive_odom.tools.bags import bagio, poses

    try:
        found = poses.read_trajectory(bag, "/tf_static", ref.frame,
                                      "online_calibration_reference_frame")
    except bagio.BagError as err:
        raise bagio.BagError(f"{bag}: the reference's mount (online_calibration_reference_"
                             f"frame {ref.frame}) is not on its /tf_static ({err}): give "
                             "online_calibration_reference_offset instead") from None
    mount = Mount(float(found.x[0]), float(found.y[0]), float(found.yaw[0]))
    reference = replace(ref, mount=mount, frame="")
    return replace(settings, online=replace(online, reference=reference))


def report(trace: list[tuple[int, OnlineEstimate]], final: OnlineEstimate | None) -> str:
    """The lines ``replay --online-calibration`` prints (see the module)."""
    if final is None:
        return "online calibration: not run (no use_imu)"
    sc = final.scale
    lines = ["online calibration (gyro; " + ("the scale from the reference topic, the rows "
                                             "with the mean radius held):" if sc is not None
                                             else "mean radius held at the configured one):"),
             "   time [s]  distance [m]  " + final_header()]
    if trace:
        t0 = trace[0][0]
        picks = _spread(trace, ROWS)
        lines += [f"  {(ns - t0) * 1e-9:9.1f}  {e.distance:12.1f}  {row(e)}" for ns, e in picks]
    excluded = ", ".join(f"{k} {v}" for k, v in sorted(final.excluded.items())) or "none"
    lines.append(f"  final: {final.line()}")
    lines.append(f"  steps used {final.steps} in {final.windows} windows; excluded: {excluded}")
    if sc is None:
        lines.append("  scale: the configured one (no reference topic: the mean radius is held "
                     "and the gyro's scale factor taken as 1)")
    else:
        refused = ", ".join(f"{k} {v}" for k, v in sorted(sc.excluded.items())) or "none"
        lines.append(f"  {sc.line()}")
        lines.append(f"  reference poses {sc.poses}; excluded: {refused}")
    if not final.determined:
        lines.append("  not yet determined: drive turns both ways (online_calibration_min_turn "
                     "each way); nothing to paste")
        return "\n".join(lines)
    verdict = (f"outside the estimate's 3-sigma region (d^2 {final.mahalanobis2:.1f} > "
               f"{CHI2_2DOF_3SIGMA:.2f}): recalibrate" if final.outside else
               f"inside the estimate's 3-sigma region (d^2 {final.mahalanobis2:.1f})")
    lines.append(f"  configured geometry: {verdict}")
    if sc is not None and sc.determined:
        lines.append("  paste into the parameter file (the scale from the reference):")
        scaled = replace(final, multipliers=sc.multipliers, stddevs=sc.stddevs)
        lines += ["    " + b for b in scaled.block().splitlines()]
        return "\n".join(lines)
    lines.append("  paste into the parameter file (the scale stays the configured one; the "
                 "gyro cannot see it" + (", the reference has not yet determined it" if sc
                                         else "") + "):")
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
    """Draw the estimate over the run into ``path`` (matplotlib, imported only there).

    Returns the line that says where ('' when nothing was asked or there is no estimate).
    """
    if path is None:
        return ""
    if not trace:
        return "online calibration plot: not written (no estimate: no step counted)\n"
    online_plot.write(path, trace, f"online calibration of {name}: the wheel geometry "
                      "estimated from the gyro over the run")
    return f"online calibration plot: {path}\n"


def final_header() -> str:
    """The column heads of :func:`row`."""
    return "left (+- 1 sigma)     right (+- 1 sigma)    separation (+- 1 sigma)  turned L/R [rad]"


def row(e: OnlineEstimate) -> str:
    """One estimate as a table row."""
    cells = [f"{m:.5f} +- {s:.5f}" for m, s in zip(e.multipliers, e.stddevs, strict=True)]
    mark = "" if e.determined else "  (not yet determined)"
    sc = e.scale  # with a reference: the mean radius and the gyro scale, as they converge
    scale = "" if sc is None else (f"  radius x {sc.mean_radius[0]:.5f}, gyro x "
                                   f"{sc.gyro_scale[0]:.5f}")
    return (f"{cells[0]:20s}  {cells[1]:20s}  {cells[2]:22s}  "
            f"{e.turned[0]:5.1f} / {e.turned[1]:5.1f}{mark}{scale}")


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
