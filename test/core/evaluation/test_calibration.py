"""Calibration: simulated runs with a known true geometry, the OptiOdom squares, the CLI.

Simulated runs: the route is commanded with the NOMINAL inverse kinematics, as a robot's
cmd_vel node would, and the base moves with its TRUE geometry; the ground truth comes
from test/oracle.py's closed-form arcs, independent of the package's step.
"""

from __future__ import annotations

import dataclasses
import math
import re
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
import yaml

from diffdrive_odom.core.bulk import batch
from diffdrive_odom.core.evaluation import (
    assessment,
    calibration,
    crossval,
    determinacy,
    objective,
    umbmark,
)
from diffdrive_odom.core.evaluation.metrics import Trajectory
from diffdrive_odom.core.evaluation.recorded_run import Run, start_stamp, values_of
from diffdrive_odom.core.geometry.kinematics import Geometry, wheel_rates
from diffdrive_odom.core.geometry.mount import AXLE
from diffdrive_odom.core.motion import routes
from diffdrive_odom.settings import odometry as odometry_settings
from diffdrive_odom.settings import rcl
from diffdrive_odom.tools.cli import main as cli

import oracle
from rosutil import DATA

NOMINAL = Geometry(0.05, 0.30)
# Radii off by +1.2 % and -0.7 %, separation off by +3.5 %.
TRUE = Geometry(0.05, 0.30, left_wheel_radius_multiplier=1.012,
                right_wheel_radius_multiplier=0.993, wheel_separation_multiplier=1.035)
SETTINGS = odometry_settings.odometry_settings({"wheel_radius": 0.05, "wheel_separation": 0.30})
RATE = 50.0
SIDE = 2.0
OPTIODOM = DATA / "optiodom"
CW_RUN, CCW_RUN = "square_231220200029_run-01", "square_231220200029_run-04"
NOMINAL_ARGS = ["-p", "wheel_radius:=0.042", "-p", "wheel_separation:=0.2"]


@dataclass(frozen=True)
class Reading:
    stamp_ns: int
    names: tuple[str, ...]
    position: tuple[float, ...]
    velocity: tuple[float, ...]


def simulate(route: routes.Route, slip: float = 0.0, seed: int = 0,
             true: Geometry = TRUE) -> Run:
    """Drive ``route`` on the ``true`` base; readings at RATE and the true pose at each.

    The wheels turn at the rates the NOMINAL inverse kinematics commands; the ground
    rolls under them with the TRUE radii (plus slip of variance ``slip^2 |arc|`` per
    side), and the true pose integrates those arcs with the TRUE separation by
    ``test/oracle.py``'s textbook arcs: not the package's step, so an error shared by
    the estimator and the truth cannot cancel.
    """
    rng = np.random.default_rng(seed)
    names = ("left_wheel_joint", "right_wheel_joint")
    dt = 1.0 / RATE
    t0 = 10**9
    left = right = 0.0
    pose = oracle.ORIGIN
    readings = [Reading(t0, names, (0.0, 0.0), ())]
    stamps, poses = [t0], [pose]
    for k in range(1, round((route.duration + 1.0) * RATE) + 1):
        rate_l, rate_r = wheel_rates(NOMINAL, *route.command_at((k - 1) * dt))
        d_l, d_r = rate_l * dt, rate_r * dt
        s_l, s_r = true.left_radius * d_l, true.right_radius * d_r
        s_l += slip * math.sqrt(abs(s_l)) * rng.standard_normal()
        s_r += slip * math.sqrt(abs(s_r)) * rng.standard_normal()
        pose = oracle.wheel_arc(s_l, s_r, true.separation, pose)
        left, right = left + d_l, right + d_r
        stamp = t0 + round(k * dt * 1e9)
        readings.append(Reading(stamp, names, (left, right), ()))
        stamps.append(stamp)
        poses.append(pose)
    x, y, th = np.array(poses).T
    return Run(route.name, batch.wheel_steps(readings, SETTINGS),
               Trajectory.from_arrays(stamps, x, y, th))


def true_values() -> np.ndarray:
    return values_of(TRUE)


@pytest.mark.process
def test_core_modules_import_no_ros_or_bag_library() -> None:
    code = ("import sys, diffdrive_odom.core.bulk.batch, diffdrive_odom.core.evaluation.metrics, "
            "diffdrive_odom.core.evaluation.calibration, diffdrive_odom.core.evaluation.umbmark; "
            "print([m for m in ('rclpy', 'rosbags') if m in sys.modules])")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout
    assert out.strip() == "[]"


# --- least squares ---------------------------------------------------------------------


def test_fit_recovers_the_true_geometry_without_noise() -> None:
    runs = [simulate(routes.umbmark(SIDE, clockwise=True)),
            simulate(routes.umbmark(SIDE, clockwise=False))]
    fit = calibration.fit(runs, NOMINAL)
    assert np.all(np.abs(fit.values / true_values() - 1.0) < 1e-3), fit.values
    assert abs(fit.mount.yaw) < 1e-4, fit.mount  # the reference is not turned
    for r in fit.runs:  # the nominal geometry is visibly wrong, the fitted one is not
        assert r.before.error > 0.05 and r.before.end > 0.05, r.before
        assert r.after.error < 1e-3, r.after


def test_fit_with_wheel_noise_is_within_its_bootstrap_uncertainty() -> None:
    slip = 0.003  # m after 1 m rolled
    runs = [simulate(routes.umbmark(SIDE, clockwise=True), slip, seed=1),
            simulate(routes.umbmark(SIDE, clockwise=False), slip, seed=2),
            simulate(routes.figure_eight(1.0), slip, seed=3),
            simulate(routes.umbmark(SIDE, clockwise=True), slip, seed=4)]
    fit = calibration.fit(runs, NOMINAL)
    cov = crossval.bootstrap(runs, NOMINAL)
    assert cov is not None
    std = np.sqrt(np.diag(cov))
    err = fit.values - true_values()
    assert np.all(std < 5e-3 * true_values()), std  # a real constraint, not a shrug
    assert np.all(np.abs(err) < 3.0 * std), (err, std)
    assert np.all(np.abs(err) > 0.0)
    assert crossval.bootstrap(runs[:2], NOMINAL) is None  # 2 runs: no sigma


def test_end_weight_trades_the_path_for_the_final_error() -> None:
    """``end_weight`` adds each run's end position error (the reference moved onto
    base_link, from the start) to the whole-trajectory residuals, in plain squares
    beside the robust loss. With slip, no geometry fits every sample: a heavy end weight
    brings the worst final error down (towards the end-pose fit), at the path's cost."""
    runs = [simulate(routes.umbmark(SIDE, clockwise=c), slip=0.01, seed=s)
            for c, s in ((True, 3), (False, 4))]

    def worst(end_weight: float = 0.0, loss: str = "cauchy") -> float:
        fit = calibration.fit(runs, NOMINAL, end_weight=end_weight, loss=loss)
        return max(calibration.figures_of(r, fit.geometry, mount=fit.mount)
                   .final_position_error_aligned_m for r in runs)

    plain, heavy = worst(), worst(end_weight=10.0)
    assert heavy < plain, (heavy, plain)
    assert worst(end_weight=10.0, loss="linear") < worst(loss="linear")


def test_held_out_check_beats_nominal_on_simulated_runs() -> None:
    """The nominal geometry is wrong by ~3 %: a geometry fitted on the other runs wins."""
    runs = [simulate(routes.umbmark(SIDE, clockwise=True), 0.002, seed=5),
            simulate(routes.umbmark(SIDE, clockwise=False), 0.002, seed=6),
            simulate(routes.figure_eight(1.0), 0.002, seed=7)]
    c = crossval.check(crossval.held_out(runs, NOMINAL))
    assert c is not None and c.runs == 3 and c.better
    assert c.held_out < 0.2 * c.nominal, c


def _named(run: Run, name: str) -> Run:
    return dataclasses.replace(run, name=name)


def _spin(turn: float) -> routes.Route:
    """A turn on the spot by ``turn`` rad (sign: direction) at 0.6 rad/s."""
    return routes.Route("spin", (routes.Segment(abs(turn) / 0.6, 0.0, math.copysign(0.6, turn)),))


def _line(length: float) -> routes.Route:
    return routes.Route("line", (routes.Segment(length / 0.3, 0.3, 0.0),))


def test_a_constant_wheel_ratio_leaves_one_combination_of_the_geometry_free() -> None:
    """Per step the wheels give an arc and a turn: with one wheel ratio all along (a
    circle) they are 2 combinations of 3 values, so the fit's information on the
    geometry (the mount's yaw eliminated) has rank 2; circles both ways have 2 ratios,
    rank 3."""
    cw, ccw = (simulate(routes.circle(1.0, clockwise=c)) for c in (True, False))

    def eig(*runs: Run) -> np.ndarray:
        info = sum((determinacy.information(r, NOMINAL) for r in runs), np.zeros((6, 6)))
        return np.linalg.eigvalsh(determinacy.geometry_part(info))

    one = eig(cw)
    assert one[0] < 1e-9 * one[-1], one
    both = eig(cw, ccw)
    assert both[0] > 1e-4 * both[-1], both
    # On a base that is the nominal one, each circle mirrored IS the other (wheels
    # swapped, path reflected): the pair's information equals its mirror's, ratio 1.
    exact = [determinacy.shape(simulate(routes.circle(1.0, clockwise=c), true=NOMINAL),
                               NOMINAL) for c in (True, False)]
    assert determinacy.mirror_ratio(exact) == pytest.approx(1.0, abs=1e-6)
    shapes = [determinacy.shape(r, NOMINAL) for r in (cw, ccw)]
    assert determinacy.coverage(shapes).determined
    alone = determinacy.coverage(shapes[:1])
    assert alone.reason.startswith("turning one way only (clockwise"), alone


def test_spins_alone_and_lines_alone_do_not_determine_the_geometry() -> None:
    """A spin on the spot commanded with the nominal geometry rolls its wheels equally
    and oppositely: no travel at all, and its end moves at most sqrt(2) x half a wheel's
    1 % arc for a 1 % change (the separation does not move it). A straight line turns 0."""
    spin = simulate(_spin(math.pi / 2))
    line = simulate(_line(2.0))
    s_spin, s_line = determinacy.shape(spin, NOMINAL), determinacy.shape(line, NOMINAL)
    assert s_spin.travel < 1e-9 and s_line.turn_span < 1e-9
    wheel_arc = (math.pi / 2) * NOMINAL.separation / 2  # each wheel's arc [m]
    assert s_spin.end_shift <= math.sqrt(2) * 0.5 * 0.01 * wheel_arc + 1e-9
    assert determinacy.judges(s_spin).startswith("the held-out run ends in place")
    # a 1 % change of the mean radius moves the line's end by 1 % of 2 m at least
    assert s_line.end_shift >= 0.01 * 2.0 and determinacy.judges(s_line) == ""
    spins = determinacy.coverage([s_spin, determinacy.shape(simulate(_spin(-math.pi / 2)),
                                                            NOMINAL)])
    assert spins.reason.startswith("too little travel"), spins
    lines = determinacy.coverage([s_line, s_line])
    assert lines.reason.startswith("too little turning"), lines
    assert determinacy.coverage([s_line, s_spin]).determined


def test_a_line_judged_by_a_fit_to_another_line_extrapolates() -> None:
    """Leverage, the held-out end's shift per unit of the training runs' residual. A
    straight line of length S driven at constant speed, whose wheel ratio is off by k,
    drifts sideways as k s^2; the start yaw the fit eliminates takes its part along s
    (least squares on uniform samples: 3 S s / 4), leaving k (s^2 - 3 S s / 4), whose
    RMS over [0, S] is k S^2 sqrt(1/80): the end moves sqrt(80) = 8.9 times that. The
    heading rows and a spin in training only add information, so the leverage of a line
    judged by a fit to a line and a spin is at most 8.9, and (the OptiOdom lines: 4.9 to
    7.4) above MAX_LEVERAGE. Circles both ways: a circle's end moves no more than its
    path does along the way (OptiOdom circles and squares: 1.0 to 2.1)."""
    line_a, line_b = (determinacy.shape(simulate(_line(2.0), true=NOMINAL), NOMINAL)
                      for _ in range(2))
    spin = determinacy.shape(simulate(_spin(math.pi), true=NOMINAL), NOMINAL)
    lev = determinacy.leverage([line_a, spin], line_b)
    assert determinacy.MAX_LEVERAGE < lev <= math.sqrt(80) * 1.01, lev
    assert "moves" in determinacy.extrapolates([line_a, spin], line_b)
    cw, ccw, cw2 = (determinacy.shape(simulate(routes.circle(1.0, clockwise=c), true=NOMINAL),
                                      NOMINAL) for c in (True, False, True))
    assert determinacy.leverage([cw, ccw], cw2) < determinacy.MAX_LEVERAGE
    assert determinacy.extrapolates([cw, ccw], cw2) == ""
    # lines alone leave the separation free: nothing determines the held-out end
    assert determinacy.leverage([line_a], line_b) == math.inf


def test_held_out_verdict_on_lines_and_spins_cannot_tell() -> None:
    """Two lines and a spin (the OptiOdom lines-and-spins experiments): each line's fold
    trains on the other line and the spin and extrapolates, the spin's ends in place
    whatever the geometry: no fold remains, the verdict cannot tell (the rule before,
    ``max_leverage=inf``, rested on the two line folds)."""
    runs = [_named(simulate(_line(2.0), slip=0.002, seed=s), f"line{s}") for s in (1, 2)]
    runs.append(_named(simulate(_spin(math.pi)), "spin"))
    results = crossval.held_out(runs, NOMINAL)
    v = crossval.judge(runs, results, NOMINAL)
    assert v is not None and v.check is None and v.cannot_tell, v
    assert [run for run, _ in v.left_out] == ["line1", "line2", "spin"]
    assert all("x more with the geometry" in why for _, why in v.left_out[:2]), v.left_out
    before = crossval.judge(runs, results, NOMINAL, max_leverage=math.inf)
    assert before is not None and before.check is not None and before.check.runs == 2
    # nor can any fold choose an objective: the whole trajectory stays, nothing refitted
    choice = objective.choose(runs, NOMINAL)
    assert choice.objective == objective.TRAJECTORY and not choice.scores, choice
    assert choice.why.startswith("none of the 3 folds can judge"), choice.why


def test_held_out_verdict_names_a_one_direction_fold_and_rests_on_the_others() -> None:
    """Two squares clockwise, one counter-clockwise (noise-free, nominal 3 % off): the
    fold that holds out the CCW square trains on CW squares only and is left out, named;
    the two others train on both directions, which recover the true geometry (Borenstein
    and Feng), so each held-out CW square ends where its reference does, nominal > 0.1 m
    off (test_fit_recovers_the_true_geometry_without_noise): better, not refused."""
    runs = [_named(simulate(routes.umbmark(SIDE, clockwise=True)), "cw1"),
            _named(simulate(routes.umbmark(SIDE, clockwise=False)), "ccw"),
            _named(simulate(routes.umbmark(SIDE, clockwise=True)), "cw2")]
    fit = calibration.fit(runs, NOMINAL)
    v = crossval.judge(runs, crossval.held_out(runs, NOMINAL), NOMINAL,
                       [r.after.error for r in fit.runs])
    assert v is not None
    assert [run for run, _ in v.left_out] == ["ccw"], v.left_out
    assert "turning one way only (clockwise" in v.left_out[0][1]
    assert v.check is not None and v.check.runs == 2 and v.every_fold.runs == 3
    assert v.check.nominal > 0.05 and v.check.held_out < 1e-3, v.check
    assert v.better and not v.cannot_tell


def test_held_out_verdict_still_refuses_a_geometry_that_really_is_worse() -> None:
    """Runs that the nominal geometry integrates exactly (the true one here), both ways
    twice and a figure eight: every fold counts (each trains on both ways; with one
    square each way and the eight, the CW square judged by the CCW one and the eight has
    leverage 3.4: an extrapolation, left out), the least-squares fit leaves ~0 on its own
    runs (no noise: the margin is ~0). A fitter dragged 2 % off (as a slipping run would
    drag it) ends every held-out run further off than nominal: refused."""
    runs = [_named(simulate(routes.umbmark(SIDE, clockwise=c), true=NOMINAL), n)
            for c, n in ((True, "cw"), (False, "ccw"), (True, "cw2"), (False, "ccw2"))]
    runs.append(_named(simulate(routes.figure_eight(1.0), true=NOMINAL), "eight"))
    fit = calibration.fit(runs, NOMINAL)
    in_sample = [r.after.error for r in fit.runs]
    assert max(in_sample) < 1e-3, in_sample
    dragged = dataclasses.replace(fit, geometry=Geometry(0.05, 0.30,
                                                         wheel_separation_multiplier=1.02))
    results = crossval.held_out(runs, NOMINAL, fitter=lambda _: dragged)
    v = crossval.judge(runs, results, NOMINAL, in_sample)
    assert v is not None
    assert not v.left_out, v.left_out
    assert v.check is not None and v.check.held_out > v.check.nominal + v.margin
    assert not v.better and not v.cannot_tell


# --- UMBmark ---------------------------------------------------------------------------


def test_umbmark_formulas_on_hand_worked_end_errors() -> None:
    side, b = 2.0, 0.3
    # Type A only: both squares end 0.04 m short in x (the turns are too small).
    p = umbmark.umbmark_pass((-0.04, -0.03), (-0.04, 0.03), side, b)
    alpha = 0.08 / (4 * side)
    assert p.alpha == pytest.approx(alpha) and p.beta == pytest.approx(0.0)
    assert p.alpha_y == pytest.approx(alpha * 0.75)
    assert p.e_b == pytest.approx(90.0 / (90.0 - math.degrees(alpha)))
    assert p.e_d == pytest.approx(1.0)
    # Type B only: x errors opposite, the legs bend the same way.
    p = umbmark.umbmark_pass((-0.05, 0.0), (0.05, 0.0), side, b)
    beta = 0.1 / (4 * side)
    radius = (side / 2) / math.sin(beta / 2)
    assert p.beta == pytest.approx(beta) and p.alpha == pytest.approx(0.0)
    assert p.e_d == pytest.approx((radius + b / 2) / (radius - b / 2))
    g = umbmark.umbmark_correct(NOMINAL, p)
    assert g.right_radius / g.left_radius == pytest.approx(p.e_d)
    assert g.left_radius + g.right_radius == pytest.approx(2 * NOMINAL.wheel_radius)
    assert g.left_radius == pytest.approx(NOMINAL.wheel_radius * 2 / (p.e_d + 1))


def test_umbmark_recovers_the_ratio_and_the_separation_without_noise() -> None:
    cw = simulate(routes.umbmark(SIDE, clockwise=True))
    ccw = simulate(routes.umbmark(SIDE, clockwise=False))
    assert cw.reference is not None and ccw.reference is not None
    u = umbmark.umbmark(cw, ccw, umbmark.reference_end(cw, cw.reference),
                        umbmark.reference_end(ccw, ccw.reference),
                        side=SIDE, nominal=NOMINAL)
    g = u.geometry
    # UMBmark keeps the mean radius; scaling both radii by s = r_nominal / r_true_mean
    # leaves every heading unchanged when the separation is scaled by s too.
    s = 2 * NOMINAL.wheel_radius / (TRUE.left_radius + TRUE.right_radius)
    assert g.right_radius / g.left_radius == pytest.approx(
        TRUE.right_radius / TRUE.left_radius, rel=1e-3)
    assert g.separation == pytest.approx(TRUE.separation * s, rel=1e-3)
    assert g.left_radius + g.right_radius == pytest.approx(2 * NOMINAL.wheel_radius)
    assert u.e_max_before > 0.1 and u.e_max_after < 0.01
    assert u.passes > 1  # the paper's single pass is first order only
    one = u.one_pass
    assert abs(one.separation / (TRUE.separation * s) - 1) < 0.02


def test_umbmark_stops_at_its_floor_instead_of_failing() -> None:
    # tolerance 0 is never reached: the passes shrink alpha and beta to float's floor
    # and stall there; that is convergence (below umbmark.FLOOR), not an error, and the
    # geometry is the one a reachable tolerance gives.
    cw = simulate(routes.umbmark(SIDE, clockwise=True), 0.001, seed=4)
    ccw = simulate(routes.umbmark(SIDE, clockwise=False), 0.001, seed=5)
    assert cw.reference is not None and ccw.reference is not None
    ends = (umbmark.reference_end(cw, cw.reference), umbmark.reference_end(ccw, ccw.reference))
    floor = umbmark.umbmark(cw, ccw, *ends, side=SIDE, nominal=NOMINAL, tolerance=0.0)
    reached = umbmark.umbmark(cw, ccw, *ends, side=SIDE, nominal=NOMINAL)
    assert floor.passes < 200
    assert floor.geometry.separation == pytest.approx(reached.geometry.separation, rel=1e-8)
    assert floor.geometry.right_radius == pytest.approx(reached.geometry.right_radius, rel=1e-8)


def test_umbmark_with_noise_stays_near_the_truth() -> None:
    # One square each way states no uncertainty (the paper averages five). With 1 mm
    # slip per sqrt(m), a 2 m leg's heading wanders ~6 mrad (1-sigma), so the end
    # errors, hence alpha and E_b, carry ~0.3 %: the bounds are about 3 sigma.
    cw = simulate(routes.umbmark(SIDE, clockwise=True), 0.001, seed=4)
    ccw = simulate(routes.umbmark(SIDE, clockwise=False), 0.001, seed=5)
    assert cw.reference is not None and ccw.reference is not None
    u = umbmark.umbmark(cw, ccw, umbmark.reference_end(cw, cw.reference),
                        umbmark.reference_end(ccw, ccw.reference),
                        side=SIDE, nominal=NOMINAL)
    s = 2 * NOMINAL.wheel_radius / (TRUE.left_radius + TRUE.right_radius)
    assert u.geometry.separation == pytest.approx(TRUE.separation * s, rel=1e-2)
    assert u.geometry.right_radius / u.geometry.left_radius == pytest.approx(
        TRUE.right_radius / TRUE.left_radius, rel=5e-3)


# --- OptiOdom --------------------------------------------------------------------------


def _optiodom_runs() -> list[Run]:
    from diffdrive_odom.tools.bags import bagreadings, poses

    settings = odometry_settings.odometry_settings({"wheel_radius": 0.042, "wheel_separation": 0.2})
    return [Run(name, batch.wheel_steps(bagreadings.read_joint_states(OPTIODOM / name), settings),
                poses.read_trajectory(OPTIODOM / name, "/ground_truth/pose"))
            for name in (CW_RUN, CCW_RUN)]


def test_optiodom_fit_is_physical_and_cuts_the_final_error() -> None:
    runs = _optiodom_runs()
    fit = calibration.fit(runs, Geometry(0.042, 0.2))
    left, right, b = fit.values
    # Sousa et al. (OptiOdom) calibrate this robot to r ~ 0.0418-0.0419 m, b ~ 0.2006 m.
    assert left == pytest.approx(0.0418, rel=5e-3) and right == pytest.approx(0.0418, rel=5e-3)
    assert b == pytest.approx(0.2008, rel=5e-3)
    before = max(calibration.figures_of(r, fit.nominal).final_position_error_aligned_m
                 for r in runs)
    after = max(calibration.figures_of(r, fit.geometry, mount=fit.mount)
                .final_position_error_aligned_m for r in runs)
    assert before == pytest.approx(0.1075, abs=1e-3)  # the paper's nominal worst error
    assert after < 0.4 * before, (before, after)
    assert max(r.after.error for r in fit.runs) < 0.5 * max(r.before.error for r in fit.runs)
    assert fit.seconds < 5.0


def test_optiodom_umbmark_cuts_the_final_error() -> None:
    cw, ccw = _optiodom_runs()
    assert cw.reference is not None and ccw.reference is not None
    u = umbmark.umbmark(cw, ccw, umbmark.reference_end(cw, cw.reference),
                        umbmark.reference_end(ccw, ccw.reference), side=1.7,
                        nominal=Geometry(0.042, 0.2))
    assert u.e_max_before == pytest.approx(0.1075, abs=1e-3)
    assert u.e_max_after < 0.4 * u.e_max_before
    assert u.geometry.separation == pytest.approx(0.2008, rel=5e-3)


# --- CLI -------------------------------------------------------------------------------


def _block(out: str) -> str:
    start = out.index("/**:")
    return out[start:]


def test_cli_cannot_tell_from_one_square_each_way_and_prints_the_block_with_a_warning(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """One square each way: each fold trains on one direction alone (Type A and B errors
    are not separable from one square, Borenstein and Feng), so no fold can judge the
    fit. calibrate says it cannot tell first, names both folds, prints the block with
    the warning in it and exits 0: the user decides."""
    saved = tmp_path / "fit.yaml"
    args = ["calibrate", str(OPTIODOM / CW_RUN), str(OPTIODOM / CCW_RUN),
            "--ground-truth", "/ground_truth/pose", *NOMINAL_ARGS, "--yaml", str(saved)]
    assert cli(args) == 0
    out = capsys.readouterr().out
    lines = out.splitlines()
    assert lines[0].startswith("CANNOT TELL on held-out runs: none of the 2 folds"), out
    # the CCW square's fold trained on the CW one, and the other way round
    assert lines[1].startswith(f"held-out fold left out: {CW_RUN}: its training runs do not "
                               "determine the geometry: turning one way only "
                               "(counter-clockwise"), out
    assert lines[2].startswith(f"held-out fold left out: {CCW_RUN}: its training runs do "
                               "not determine the geometry: turning one way only (clockwise"), out
    block = _block(out)
    assert saved.read_text(encoding="utf-8").endswith(block)
    assert "held-out check CANNOT TELL" in saved.read_text(encoding="utf-8")
    assert "fixed, not fitted: clock lag" in out
    assert "reference mount (its frame in base_link), fitted: x " in out, out
    assert "it needs 3 or more runs" in out  # 2 runs: no bootstrap sigma


def test_cli_force_prints_a_params_block_the_node_accepts(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    plot, saved = tmp_path / "fit.png", tmp_path / "fit.yaml"
    code = cli(["calibrate", str(OPTIODOM / CW_RUN), str(OPTIODOM / CCW_RUN),
                "--ground-truth", "/ground_truth/pose", *NOMINAL_ARGS, "--force",
                "--plot", str(plot), "--yaml", str(saved)])
    out = capsys.readouterr().out
    assert code == 0, out
    assert out.startswith("CANNOT TELL on held-out runs")  # --force changes nothing there
    assert plot.stat().st_size > 10_000
    block = _block(out)
    assert saved.read_text(encoding="utf-8").endswith(block)
    entry = yaml.safe_load(block)["/**"]["ros__parameters"]
    assert "wheel_radius_stddev_ratio" not in entry  # no sigma from 2 runs
    path = tmp_path / "calibrated.yaml"
    path.write_text(block, encoding="utf-8")
    values = rcl.load_params_file(path, "odometry_node")
    settings = odometry_settings.odometry_settings(values)
    fit = assessment.assess(_optiodom_runs(), Geometry(0.042, 0.2)).fit
    got = values_of(settings.geometry)
    assert np.allclose(got, fit.values, rtol=1e-6), (got, fit.values)
    for line in ("left wheel radius", "1-sigma", "whole-trajectory error", CW_RUN):
        assert line in out


def test_cli_end_weight_fits_the_final_positions_and_judges_that_fit(
        capsys: pytest.CaptureFixture[str]) -> None:
    """``--end-weight W``: the block holds :func:`calibration.fit` with ``end_weight=W``,
    the report names the objective, and the held-out folds refit with the same W."""
    code = cli(["calibrate", str(OPTIODOM / CW_RUN), str(OPTIODOM / CCW_RUN),
                "--ground-truth", "/ground_truth/pose", *NOMINAL_ARGS, "--end-weight", "0.5"])
    out = capsys.readouterr().out
    assert code == 0, out
    assert "whole trajectory + end positions x0.5" in out
    assert "objective: whole trajectory + end positions x0.5 (as asked" in out, out
    entry = yaml.safe_load(_block(out))["/**"]["ros__parameters"]
    runs, free = _optiodom_runs(), calibration.MountSpec(lever=True)  # both ways: the lever too
    fit = calibration.fit(runs, Geometry(0.042, 0.2), end_weight=0.5, mount=free)
    assert entry["wheel_separation_multiplier"] == pytest.approx(
        fit.geometry.wheel_separation_multiplier, rel=1e-6)
    plain = calibration.fit(runs, Geometry(0.042, 0.2), mount=free)

    def worst(f: calibration.Fit) -> float:
        return max(calibration.figures_of(r, f.geometry, mount=f.mount)
                   .final_position_error_aligned_m for r in runs)

    assert worst(fit) < worst(plain)


def _arcs_with_the_reference_clock_off(lag: float) -> list[Run]:
    """Four open runs (a line, an arc of 130 or 100 deg either way, a line) on a base that
    IS the nominal one, each reference pose stamped ``lag`` before it happened (a motion
    capture's clock that far behind; the fit takes the offset as 0). The robot stands
    still for a second at the start and the end, so the start-aligned final errors do
    not see the offset; the whole-trajectory fit does, and is dragged by it."""
    runs = []
    for i, turn in enumerate((0.45, -0.45, 0.35, -0.35)):
        route = routes.Route(f"arc{i}", (routes.Segment(1.0, 0.0, 0.0),
                                         routes.Segment(2.0, 0.3, 0.0),
                                         routes.Segment(5.0, 0.3, turn),
                                         routes.Segment(2.0, 0.3, 0.0)))
        run = simulate(route, true=NOMINAL)
        assert run.reference is not None
        late = dataclasses.replace(run.reference,
                                   stamp_ns=run.reference.stamp_ns - round(lag * 1e9))
        runs.append(dataclasses.replace(run, name=f"arc{i}", reference=late))
    return runs


def _write_bag(path: Path, run: Run) -> None:
    """``run`` as a recording: /joint_states (wheel angles from 0 at the start, stamped
    and logged at each reading) and /ground_truth/odom (the reference, at its stamps)."""
    from diffdrive_odom.tools.bags import bagio, bagwriter

    from bagutil import OdomMessages, joint_state_msg

    steps, ref = run.steps, run.reference
    assert ref is not None
    stamps = np.concatenate(([start_stamp(steps)], steps.stamp_ns))
    left = np.concatenate(([0.0], np.cumsum(steps.d_left)))
    right = np.concatenate(([0.0], np.cumsum(steps.d_right)))
    cov = [0.0] * 36
    with bagwriter.BagWriter(path) as w:
        w.add_topic("/joint_states", bagio.JOINT_STATE)
        w.add_topic("/ground_truth/odom", bagio.ODOMETRY)
        t = w.typestore.types
        odom = OdomMessages(w.typestore, "world", "base_link")
        for ns, x, y, yaw in zip(ref.stamp_ns, ref.x, ref.y, ref.yaw, strict=True):
            w.write("/ground_truth/odom", int(ns), odom.odometry(
                int(ns), float(x), float(y), float(yaw), linear=0.0, angular=0.0,
                pose_covariance=cov, twist_covariance=cov))
        for ns, lw, rw in zip(stamps, left, right, strict=True):
            w.write("/joint_states", int(ns), joint_state_msg(t, int(ns), lw, rw))


def test_cli_refuses_a_fit_that_is_worse_on_every_held_out_run(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The refused branch end to end, bags in (calibrate's own fit, held-out folds and
    verdict; nothing forced): four runs on a base that IS the nominal one, the reference
    on the axle, but given as turned 5 deg (``--reference-offset=0,0,5``, a marker body's
    yaw typed wrong). The fit turns the paths by 5 deg it cannot explain and takes a
    geometry that bends them (radii off by -1.2 and +0.4 %); judged on every held-out run
    (the best SE(2) fit: a turn of the whole path costs nothing there), the nominal
    geometry ends each exactly where its reference does, the calibrated one centimetres
    off, twice the margin: NOT BETTER THAN NOMINAL, no block, exit 1."""
    bags = _arc_bags(tmp_path, _arcs_with_the_reference_clock_off(0.0))
    code = cli(["calibrate", *bags, "-p", "wheel_radius:=0.05", "-p", "wheel_separation:=0.3",
                "--objective", "trajectory", "--reference-offset=0,0,5"])
    out = capsys.readouterr().out
    assert code == 1, out
    assert "objective: whole trajectory (as asked" in out, out
    assert "reference mount (--reference-offset, held): x +0.0000 m, y +0.0000 m, yaw +5.00" in out
    first = out.splitlines()[0]
    assert first.startswith("NOT BETTER THAN NOMINAL on held-out runs"), out
    assert "left out" not in out, out  # every fold judged
    assert "ros__parameters" not in out and "no params block" in out, out
    nominal, held_out = (float(v) for v in re.findall(r"([\d.]+) m (?:nominal|calibrated)",
                                                       first))
    assert nominal < 1e-6 and held_out > 0.02, first


def _arc_bags(tmp_path: Path, runs: list[Run]) -> list[str]:
    """``runs`` written as bags; their paths."""
    bags = []
    for run in runs:
        bags.append(str(tmp_path / run.name))
        _write_bag(tmp_path / run.name, run)
    return bags


def _late_reference_bags(tmp_path: Path) -> list[str]:
    """:func:`_arcs_with_the_reference_clock_off` (0.2 s) written as bags; their paths."""
    return _arc_bags(tmp_path, _arcs_with_the_reference_clock_off(0.2))


def test_cli_chooses_the_end_poses_where_a_late_reference_drags_the_path(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Four runs on a base that IS the nominal one, each reference pose stamped 0.2 s late
    (a motion capture's clock that far behind; the fit takes the offset as 0), the robot
    at rest at both ends; nothing asked for: calibrate chooses the objective held out.
    The end poses are right by construction, the path is not: the end-pose fit (OptiOdom's
    objective) of any three runs is the true geometry, and each held-out run is off its
    reference by the lag alone (3.7 cm by the one judge: the lag along the path); the
    whole trajectory is dragged (radii ~4 % up) and its held-out runs are off by more
    (6 cm). The table names the end poses as taken (the row starred, the lowest worst),
    the block holds the true geometry, and it is not refused."""
    bags = _late_reference_bags(tmp_path)
    code = cli(["calibrate", *bags, "-p", "wheel_radius:=0.05", "-p", "wheel_separation:=0.3",
                "--reference-offset=0,0,0"])
    out = capsys.readouterr().out
    assert code == 0, out
    assert ("objective: end poses only (OptiOdom's), chosen by leave-one-run-out on the 4 "
            "runs") in out, out
    rows = {name: (mark, float(worst), float(mean), force) for mark, name, worst, mean, force
            in re.findall(r"^([* ]) (\S.*?)\s+([\d.]+)\s+([\d.]+)  (--.*)$", out, re.M)}
    assert list(rows) == ["whole trajectory", "whole trajectory + end positions x0.5",
                          "whole trajectory + end positions x1", "end poses only (OptiOdom's)"]
    assert [r[0] for r in rows.values()] == [" ", " ", " ", "*"], out
    ends = rows["end poses only (OptiOdom's)"][1]
    assert ends == min(r[1] for r in rows.values()), out
    assert rows["end poses only (OptiOdom's)"][3] == "--objective end-poses"
    assert rows["whole trajectory"][1] > ends + 0.02, out
    entry = yaml.safe_load(_block(out))["/**"]["ros__parameters"]
    for key in ("left_wheel_radius_multiplier", "right_wheel_radius_multiplier",
                "wheel_separation_multiplier"):
        assert entry[key] == pytest.approx(1.0, abs=1e-3), entry


def test_cli_with_one_run_says_the_check_cannot_be_made(
    capsys: pytest.CaptureFixture[str]
) -> None:
    assert cli(["calibrate", str(OPTIODOM / CCW_RUN), *NOMINAL_ARGS]) == 0
    out = capsys.readouterr().out
    assert out.startswith("held-out check: cannot be made with 1 run"), out
    assert "objective: whole trajectory (the default, not chosen: one run" in out, out
    assert "/**:" in out


def test_bootstrap_ratios_go_into_a_block_the_node_accepts() -> None:
    """Three simulated runs: sigma printed as the node's stddev ratios, pasteable."""
    from diffdrive_odom.tools.calibrate import params_block

    runs = [simulate(routes.umbmark(SIDE, clockwise=True), 0.002, seed=8),
            simulate(routes.umbmark(SIDE, clockwise=False), 0.002, seed=9),
            simulate(routes.figure_eight(1.0), 0.002, seed=10)]
    fit = calibration.fit(runs, NOMINAL)
    cov = crossval.bootstrap(runs, NOMINAL)
    assert cov is not None
    ratios = crossval.stddev_ratios(fit.values, cov)
    rel = np.sqrt(np.diag(cov)) / fit.values
    assert ratios == (max(rel[0], rel[1]), rel[2])
    entry = yaml.safe_load(params_block(fit.geometry, ratios, "test"))["/**"]["ros__parameters"]
    settings = odometry_settings.odometry_settings(entry)
    assert settings.noise is not None
    assert settings.noise.radius_stddev_ratio == pytest.approx(ratios[0], rel=1e-6)
    assert settings.noise.separation_stddev_ratio == pytest.approx(ratios[1], rel=1e-6)
    assert 0.0 < ratios[0] < 0.01 and 0.0 < ratios[1] < 0.02


def test_fit_report_prints_the_bootstrap_and_the_sigma_with_the_session_drift() -> None:
    """The 1-sigma column is sqrt(bootstrap^2 + (drift * value)^2), named on one line;
    --session-drift 0 leaves the bootstrap alone."""
    from diffdrive_odom.tools.calibrate import fit_report

    fit = calibration.fit(_optiodom_runs(), Geometry(0.042, 0.2))
    boot = np.array([3e-5, 4e-5, 5e-4])
    cov = np.diag(boot**2)
    for drift in (0.0019, 0.0):
        text = fit_report(fit, cov, drift)
        rows = [ln.split() for ln in text.splitlines() if ln.startswith(("left wheel",
                                                                          "right wheel",
                                                                          "wheel separation"))]
        assert len(rows) == 3, text
        for row, b, v in zip(rows, boot, fit.values, strict=True):
            assert float(row[-2]) == pytest.approx(b, abs=1e-6)
            assert float(row[-1]) == pytest.approx(math.hypot(b, drift * v), abs=1e-6)
        assert (f"drift between sessions of {100 * drift:.2f} % of each value "
                "(--session-drift)") in text
        assert "1-sigma: covers the geometry on other days" in text
    assert "1-sigma: not given: it needs 3 or more runs" in fit_report(fit, None)


def test_cli_umbmark_from_topic_and_from_typed_end_points(
    capsys: pytest.CaptureFixture[str]
) -> None:
    """The reference's ends held on the axle (--reference-offset 0,0,0) and typed give the
    same block; left to calibrate, the mount it finds (the squares turn both ways: its
    lever arm too) is this reference's, on the axle up to millimetres: nearly the same."""
    bags = [str(OPTIODOM / CW_RUN), str(OPTIODOM / CCW_RUN)]
    assert cli(["calibrate", "--umbmark", *bags, "--side", "1.7", *NOMINAL_ARGS]) == 0
    out = capsys.readouterr().out
    assert "reference mount (its frame in base_link), fitted: x " in out, out
    found = yaml.safe_load(_block(out))["/**"]["ros__parameters"]
    assert cli(["calibrate", "--umbmark", *bags, "--side", "1.7", *NOMINAL_ARGS,
                "--reference-offset=0,0,0"]) == 0
    from_topic = yaml.safe_load(_block(capsys.readouterr().out))
    for key, value in from_topic["/**"]["ros__parameters"].items():
        assert found[key] == pytest.approx(value, rel=2e-3), key
    cw, ccw = _optiodom_runs()
    assert cw.reference is not None and ccw.reference is not None
    ends = [umbmark.reference_end(cw, cw.reference),
            umbmark.reference_end(ccw, ccw.reference)]
    typed = [f"{x!r},{y!r}" for x, y in ends]
    assert cli(["calibrate", "--umbmark", *bags, "--side", "1.7", *NOMINAL_ARGS,
                f"--cw-end={typed[0]}", f"--ccw-end={typed[1]}"]) == 0
    out = capsys.readouterr().out
    assert yaml.safe_load(_block(out)) == from_topic
    assert "E_d" in out and "E_b" in out
    values = from_topic["/**"]["ros__parameters"]
    assert "wheel_radius_stddev_ratio" not in values  # UMBmark states no uncertainty
    odometry_settings.odometry_settings(values)


@pytest.mark.parametrize(("args", "needle"), [
    ([str(OPTIODOM / CW_RUN), "--ground-truth", "/nothing", *NOMINAL_ARGS], "/nothing"),
    ([str(OPTIODOM / CW_RUN), "--topic", "/nothing", *NOMINAL_ARGS], "/nothing"),
    ([str(OPTIODOM / CW_RUN), "--imu-topic", "/no_imu", *NOMINAL_ARGS], "/no_imu"),
    ([str(OPTIODOM / CW_RUN)], "--params-file"),
    ([str(OPTIODOM / CW_RUN), "-p", "wheel_radius:=-1", "-p", "wheel_separation:=0.2"],
     "wheel_radius"),
    (["/no/such/bag", *NOMINAL_ARGS], "/no/such/bag"),
    ([str(OPTIODOM / CW_RUN), "--window", "0.25", *NOMINAL_ARGS], "--window"),
    ([str(OPTIODOM / CW_RUN), "--no-mount", *NOMINAL_ARGS], "--no-mount"),
    ([str(OPTIODOM / CW_RUN), "--session-drift", "-0.01", *NOMINAL_ARGS], "--session-drift"),
    ([str(OPTIODOM / CW_RUN), "--session-drift", "nan", *NOMINAL_ARGS], "--session-drift"),
    ([str(OPTIODOM / CW_RUN), "--end-weight", "-1", *NOMINAL_ARGS], "--end-weight"),
    ([str(OPTIODOM / CW_RUN), "--end-weight", "inf", *NOMINAL_ARGS], "--end-weight"),
    ([str(OPTIODOM / CW_RUN), "--end-weight", "1", "--objective", "end-poses", *NOMINAL_ARGS],
     "--end-weight"),
    ([str(OPTIODOM / CW_RUN), "--end-weight", "1", "--objective", "auto", *NOMINAL_ARGS],
     "--end-weight"),
    (["--umbmark", str(OPTIODOM / CW_RUN), str(OPTIODOM / CCW_RUN), *NOMINAL_ARGS], "--side"),
    (["--umbmark", str(OPTIODOM / CW_RUN), str(OPTIODOM / CCW_RUN), "--side", "1.7",
      "--cw-end", "1,2", "--ccw-end", "x", *NOMINAL_ARGS], "--ccw-end"),
    (["--umbmark", str(OPTIODOM / CW_RUN), str(OPTIODOM / CCW_RUN), "--side", "1.7",
      "--cw-end", "1,2", *NOMINAL_ARGS], "--ccw-end"),
])
def test_cli_bad_input_is_one_line_and_exit_2(
    capsys: pytest.CaptureFixture[str], args: list[str], needle: str
) -> None:
    assert cli(["calibrate", *args]) == 2
    captured = capsys.readouterr()
    lines = [ln for ln in captured.err.splitlines() if ln.strip()]
    assert len(lines) == 1 and needle in lines[0], captured.err
    assert captured.out == ""


def test_rotation_noise_fit_on_held_out_runs_goes_into_a_block_the_node_accepts() -> None:
    """Four runs whose only random error is the wheels' (k = slip^2): each judged with a
    geometry fitted on the others, the final poses do not want a rotation term (its
    likelihood ratio against 0 under the 5 % threshold), and the value printed goes into
    a block the node accepts."""
    from diffdrive_odom.core.evaluation import consistency
    from diffdrive_odom.tools.calibrate import params_block, rotation_fit, rotation_line

    slip = 0.002
    runs = [simulate(routes.umbmark(SIDE, clockwise=True), slip, seed=21),
            simulate(routes.umbmark(SIDE, clockwise=False), slip, seed=22),
            simulate(routes.figure_eight(1.0), slip, seed=23),
            simulate(routes.umbmark(SIDE, clockwise=True), slip, seed=24)]
    settings = odometry_settings.odometry_settings({
        "wheel_radius": 0.05, "wheel_separation": 0.30, "wheel_noise_k_left": slip**2,
        "wheel_noise_k_right": slip**2})
    folds = crossval.held_out(runs, NOMINAL)
    fit = rotation_fit(runs, [(h.geometry, h.mount) if h.geometry and h.mount else None
                              for h in folds], settings, (0.002, 0.004), (0.0, 0.0), AXLE)
    assert fit.noise.k == pytest.approx(slip**2) and fit.noise.radius_ratio == 0.002
    assert fit.lr_rotation < consistency.LR_5_PERCENT, fit
    text = rotation_line(fit, len(runs), (0.0, 0.0))
    assert text.startswith("rotation_noise_k: ") and "not distinguishable from 0" in text
    block = params_block(NOMINAL, (0.002, 0.004), "test", 3.5e-5)
    entry = yaml.safe_load(block)["/**"]["ros__parameters"]
    noise = odometry_settings.odometry_settings(entry).noise
    assert noise is not None and noise.k_rotation == pytest.approx(3.5e-5)
