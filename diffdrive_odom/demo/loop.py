"""The closed-loop run: start the four nodes, drive the squares on the recorder, evaluate.

``path_follower_node`` steers on the odometry (``odom`` in, ``cmd_vel`` out);
``cmd_vel_node`` turns the twist into wheel commands for ``sim_node``, a simulated
base whose TRUE geometry is a little off the nominal one; the simulated encoders feed
``odometry_node``, which closes the loop. They talk over DDS on loopback in a private
ROS domain, in lockstep (:mod:`diffdrive_odom.ros.lockstep`): the sim steps its clock
and physics only once every node, and this process's recorder, has answered the last
step, so the run is as fast as the machine allows and the same on every run, however
loaded the machine. This process sends each square's path on ``/path`` at a step of the
loop (:mod:`.drive`), and records everything into a rosbag2 (raw CDR as received, so
every reader can decode it; log times in simulated time).

The child processes are :mod:`.children`, this process's node :mod:`.recorder`. Every
resource is held by an ExitStack: the child processes are stopped and the ROS context
and bag are closed when the demo ends, fails (a constructor included) or is
interrupted. While they are held, a stop signal is raised only at the waiting loop's
check (:mod:`.interrupts`), never inside the code that polls or stops the children; the
children end by themselves if this process is killed (:mod:`.children`).

Everything is written into a hidden directory beside ``--output`` and moved into place only
when the run has finished (:func:`diffdrive_odom.tools.cmdline.outputs.staged`), so a failed or
interrupted demo leaves no partial output, and a previous one stays until a new one replaces
it.
"""

from __future__ import annotations

import json
import os
import random
import shutil
import time
from collections.abc import Callable, Sequence
from contextlib import ExitStack
from pathlib import Path

import numpy as np

from diffdrive_odom.ros import discovery
from diffdrive_odom.settings.params import ParamValue
from diffdrive_odom.tools.cmdline.outputs import staged, through_link

from . import evaluation, interrupts, recorder
from .children import Children
from .drive import Drive, Leg
from .recorder import Recorder
from .report import DemoResult, Square
from .settings import (
    FOLLOWER,
    SETTLE_S,
    STARTUP_TIMEOUT_S,
    DemoError,
    DemoOptions,
    Settings,
    check_options,
    follower_values,
    load_settings,
    square_path,
    write_run_params,
    yaml_value,
)

# The nodes of the loop, each answering every step (the recorder too).
LOOP_NODES = ("odometry_node", FOLLOWER, "cmd_vel_node")

NODES = ("sim_node", "cmd_vel_node", "odometry_node", FOLLOWER)


class _Waiter:
    """Spin the recorder until a condition holds, watching the children and a deadline."""

    def __init__(self, recorder: Recorder, children: Children) -> None:
        self.recorder, self.children = recorder, children

    def until(self, done: Callable[[], bool], deadline: float,
              what: Callable[[], str]) -> None:
        """Return once ``done()``; at the deadline DemoError saying ``what()`` it waited for.

        A stop signal held meanwhile is raised here (KeyboardInterrupt), between spins.
        """
        while not done():
            interrupts.check()
            self.children.check(what())
            if time.monotonic() > deadline:
                raise DemoError(f"timed out {what()} ({self.recorder.status()}):\n"
                                f"{self.children.tails()}")
            self.recorder.spin_once(0.05)


def _run_params(opts: DemoOptions, output: Path) -> Path:
    """The params file for this run: lockstep for the loop, the follower's settings."""
    sim_changes: dict[str, ParamValue] = {
        k: yaml_value(v) for k, v in opts.sim_overrides.items()}
    # In lockstep every timer of the loop runs on simulated time: the heartbeat, the
    # watchdogs and the limits keep their own values, whatever the machine's load.
    sim_changes.update(lockstep=True, lockstep_nodes=[*LOOP_NODES, recorder.NODE_NAME])
    in_loop: dict[str, ParamValue] = {"use_sim_time": True, "lockstep": True}
    return write_run_params(opts.params_file, {
        "sim_node": sim_changes,
        "cmd_vel_node": in_loop,
        "odometry_node": in_loop,
        FOLLOWER: {**in_loop, **follower_values(opts)},
    }, output / "params.yaml")


def _legs(opts: DemoOptions, look_ahead: float) -> list[Leg]:
    """The squares to drive, each with the points the follower is sent."""
    return [Leg(cw, tuple(square_path(opts.side, cw, look_ahead))) for cw in opts.squares]


def run(opts: DemoOptions) -> DemoResult:
    """Start the nodes, drive the squares, record, calibrate, plot; everything released.

    Written into a staging directory, moved to ``opts.output`` (replacing a previous
    demo's, which :func:`check_options` made sure it is) only once all went well.
    """
    check_options(opts)
    settings = load_settings(opts)
    final = through_link(opts.output)  # a symlink is written through and stays a link
    final.parent.mkdir(parents=True, exist_ok=True)
    with staged(final) as output:
        output.mkdir()
        result = _run(opts, settings, output)
        if final.exists():  # a previous demo's (check_output): replaced now
            shutil.rmtree(final)
    return result


def _run(opts: DemoOptions, settings: Settings, output: Path) -> DemoResult:
    """The run, writing into ``output`` (the staging directory)."""
    logs = output / "logs"
    logs.mkdir()
    bag_path = output / "bag" if opts.write_bag else None

    domain = opts.domain_id if opts.domain_id is not None else random.randint(1, 100)
    env = discovery.with_profile({**os.environ, "ROS_DOMAIN_ID": str(domain),
                                  "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"})
    env.pop("ROS_LOCALHOST_ONLY", None)
    args = ["--params-file", str(_run_params(opts, output))]

    wall0 = time.monotonic()
    with interrupts.deferred(), discovery.in_this_process(), ExitStack() as stack:
        rec = stack.enter_context(Recorder(domain, bag_path))
        drive = Drive(rec, _legs(opts, settings.follower.gains.look_ahead))
        rec.on_step = drive.step
        children = stack.enter_context(Children(env, logs))
        for name in NODES:
            children.start(name, args)
        print(f"[{opts.route}] ROS_DOMAIN_ID={domain}; "
              + ", ".join(f"{c.name} pid {c.proc.pid}" for c in children.started)
              + f"; logs in {logs}", flush=True)
        waiter = _Waiter(rec, children)
        waiter.until(lambda: rec.now_ns is not None, wall0 + STARTUP_TIMEOUT_S,
                     lambda: "starting the nodes")
        print(f"[{opts.route}] nodes up after {time.monotonic() - wall0:.1f} s; driving",
              flush=True)
        waiter.until(lambda: drive.finished, wall0 + opts.timeout, lambda: drive.doing)
    wall = time.monotonic() - wall0
    print(f"[{opts.route}] driven in {wall:.1f} s (wall); calibrating and replaying",
          flush=True)
    return _evaluate(opts, settings, rec, drive.squares, wall, output)


def _evaluate(opts: DemoOptions, s: Settings, recorder: Recorder, squares: Sequence[Square],
              wall: float, output: Path) -> DemoResult:
    """Calibrate, plot and write results.json into ``output``.

    The paths the result names are where they will be: under ``opts.output``.
    """
    rec = recorder.recording(squares)
    cal = evaluation.calibrate_rows(rec, s.odometry, s.sim.config.geometry, opts.side,
                                    s.gyro_odometry)
    rows, paths = cal.rows, cal.paths
    replayed, replay_paths, aided = evaluation.replay_rows(rec, s.odometry, s.gyro_odometry)
    rows.update(replayed)
    paths.update(replay_paths)
    slips = () if aided is None else aided.slips
    trace = [] if aided is None else aided.online
    true_multipliers = evaluation.true_multipliers(s.odometry.geometry, s.sim.config.geometry)
    truth = rec.truth
    xy = np.column_stack((truth.x, truth.y))
    off_path = 0.0
    for sq in squares:
        inside = (truth.stamp_ns >= sq.start_ns) & (truth.stamp_ns <= sq.end_ns)
        if inside.any():
            off_path = max(off_path, float(evaluation.distance_to_polyline(
                xy[inside], sq.points).max()))
    if opts.write_plot:
        from .plot import plot

        plot(output / "trajectory.png", truth, paths, [sq.points for sq in squares],
             f"{opts.route}: the follower drives on wheel odometry; the truth drifts",
             slips, trace, true_multipliers)
    distance = float(truth.path_length()[-1]) if len(truth) else 0.0
    result = DemoResult(
        route=opts.route, side_m=opts.side, distance_m=distance,
        sim_seconds=(squares[-1].end_ns - squares[0].start_ns) * 1e-9 + SETTLE_S,
        wall_seconds=wall,
        truth_final_pose=(float(truth.x[-1]), float(truth.y[-1]), float(truth.yaw[-1])),
        rows=rows, cross_track_odom_m=rec.cross_track_odom_m,
        cross_track_truth_m=off_path, squares=tuple(squares),
        messages=dict(recorder.counts),
        bag=str(opts.output / "bag") if opts.write_bag else None,
        plot=str(opts.output / "trajectory.png") if opts.write_plot else None,
        slips=slips, left_out=cal.left_out,
        online=trace[-1][1] if trace else None, true_multipliers=true_multipliers,
    )
    (output / "results.json").write_text(
        json.dumps(result.as_dict(), indent=2) + "\n", encoding="utf-8")
    return result
