"""``diffdrive-odom calibrate``'s bags decoded into runs: wheel steps by the node's pipeline.

Readings are decoded with the odometry node's own parameters and pipeline
(:func:`diffdrive_odom.core.bulk.batch.wheel_steps`), ground truth with ``eval``'s
readers, so a bag that replays or evaluates also calibrates. Where a bag has an IMU
(``--imu-topic``, default: its only ``sensor_msgs/Imu`` topic), its readings go through
the pipeline with the gyro (``use_imu``, the params' gyro settings), which judges each
step for slip; those steps are left out of the fit
(:mod:`diffdrive_odom.core.evaluation.leftout`). rosbags is imported past the parsing
(the command imports this module for its ``--help``).
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from collections.abc import Callable
from pathlib import Path

from diffdrive_odom.core.bulk import batch
from diffdrive_odom.core.estimation.config import OdometrySettings
from diffdrive_odom.core.estimation.stamps import StampSource
from diffdrive_odom.core.estimation.wheels.encoders import Reason
from diffdrive_odom.core.evaluation.recorded_run import CalibrationError, Run
from diffdrive_odom.tools.cmdline.args import settings_from_args

PREFIX = "[calibrate]"  # its lines on stderr
# The node's settings as given, and with the gyro on (for the bags with an IMU).
# (str: why the gyro's settings cannot work, said only for a bag that has an IMU).
Settings = tuple[OdometrySettings, "OdometrySettings | str"]

def decode(bag: str, settings: Settings, args: argparse.Namespace, reference: bool) -> Run:
    """Decode one bag into its wheel steps (and read its ground truth when asked).

    With an IMU topic (:func:`imu_topic`) the readings go through the pipeline with the
    gyro, which judges each step for slip (``WheelSteps.slip_spans``).
    """
    from diffdrive_odom.tools.bags import bagblocks, bagio, bagreadings, poses

    def notify(text: str) -> None:
        print(f"{PREFIX} {text}", file=sys.stderr)

    ref = None
    if reference:
        topic = poses.reference_topic(bag, args.ground_truth, (args.topic,), notify)
        ref = poses.read_trajectory(bag, topic, args.child_frame)
    plain, gyro = settings
    imu = imu_topic(bag, args.imu_topic, notify)
    if imu is not None and isinstance(gyro, str):
        raise CalibrationError(f"{bag} has an IMU ({imu}) to find slips with, but the gyro's "
                               f"settings cannot work: {gyro} (or --imu-topic none)")
    # Without an IMU the wheels alone, even with use_imu in the params: the gyro path would
    # run its slip test on no samples (and say so) and lose the fast lane.
    used = (dataclasses.replace(plain, gyro=None, online=None) if imu is None
            else plain if isinstance(gyro, str) else gyro)
    jump = int(used.estimator.time_jump_threshold * 1e9)
    if imu is None:
        steps = batch.wheel_steps(bagblocks.read_joint_blocks(bag, args.topic, jump), used)
    else:
        by_log = used.gyro is not None and used.gyro.stamp_source is StampSource.RECEIVE_TIME
        with bagio.open_bag(bag) as reader:
            steps = batch.wheel_steps(bagreadings.iter_readings(
                reader, args.topic, imu, stream=bagreadings.Stream(
                    jump_back_ns=jump, imu_by_log_time=by_log)), used)
    name = Path(bag).name
    _said_skipped(name, args.topic, steps, used, notify)
    return Run(name, steps, ref)


def _said_skipped(name: str, topic: str, steps: batch.WheelSteps, settings: OdometrySettings,
                  notify: Callable[[str], None]) -> None:
    """What the node's rules kept out of a run, said rather than fitted around in silence.

    No usable step: CalibrationError with the main reason in the node's words (the
    missing joints named, as replay names them). Skipped steps (``too_fast``), whose
    motion the fit never sees: one line, with the likely cause where raw counts are read
    with no counter width (a counter wrapping: ``encoder_counter_bits``).
    """
    skipped = {code: (n, text) for code, n, text in steps.skipped}
    if len(steps) < 2:
        main = sorted(skipped.items(), key=lambda kv: -kv[1][0])[:1]
        why = "".join(f"; {n} x {code}: {text}" for code, (n, text) in main)
        raise CalibrationError(f"{name}: fewer than 2 usable readings on {topic}{why}")
    if Reason.TOO_FAST not in skipped:
        return
    n, text = skipped[Reason.TOO_FAST]
    enc = settings.encoders
    cause = ("likely cause: wheel counters that wrap, read as raw ticks with "
             "encoder_counter_bits 0: set encoder_counter_bits to the counter's width "
             "(16 for a 16-bit counter)" if enc.ticks_per_revolution > 0 and not enc.counter_bits
             else f"check max_wheel_speed ({settings.estimator.max_wheel_speed:g} rad/s) and "
             "encoder_counter_bits")
    notify(f"{name}: {n} x too_fast ({text}), so the fit misses their motion; {cause}")


def imu_topic(bag: str, requested: str | None, notify: Callable[[str], None]) -> str | None:
    """The Imu topic whose gyro judges the slips: ``requested``, else the bag's only one.

    None: no slip test (``none`` asked for, or no Imu topic in the bag); BagError when
    the bag has several and none is named.
    """
    if requested is not None:
        return None if requested.lower() == "none" else requested
    from diffdrive_odom.tools.bags import bagio

    with bagio.open_bag(bag) as reader:
        found = sorted({str(c.topic) for c in reader.connections if c.msgtype == bagio.IMU})
    if len(found) > 1:
        raise bagio.BagError(f"{bag}: several Imu topics ({', '.join(found)}): name the one "
                             "to find slips with, --imu-topic TOPIC (or none)")
    if found:
        notify(f"{Path(bag).name}: the gyro on {found[0]} finds the slips to leave out of the "
               "fit (--imu-topic none: keep every step)")
    return found[0] if found else None


def gyro_settings(args: argparse.Namespace, settings: OdometrySettings) -> OdometrySettings | str:
    """How a bag with an IMU is decoded: the node's settings with the gyro on.

    ``use_imu`` true, its gyro parameters from the params given, no online estimate.
    use_imu is set after every params source, as ``replay --online-calibration`` sets
    it: a ``-p`` would lose to a params file's own ``odometry_node`` section (the demo's
    says ``use_imu: false``). The sources were loaded (and their problems said) once.
    """
    if settings.gyro is None:
        got = settings_from_args(args, None, {"use_imu": True})
        if isinstance(got, str):
            return got
        settings = got
    return dataclasses.replace(settings, online=None)
