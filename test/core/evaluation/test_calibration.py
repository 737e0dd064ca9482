"""Calibration: simulated runs with a known true geometry, the OptiOdom squares, the CLI.

Simulated runs: the route is commanded with the NOMINAL inverse kinematics, as a robot's
cmd_vel node would, and the base moves with its TRUE geometry; the ground truth comes
from test/oracle.py's closed-form arcs, independent of the package's step.
"""

from __future__ import annotations

import math
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
import yaml

from diffdrive_odom.core.bulk import batch
from diffdrive_odom.core.evaluation import calibration, crossval, umbmark
from diffdrive_odom.core.evaluation.metrics import Trajectory
from diffdrive_odom.core.evaluation.recorded_run import Run, values_of
from diffdrive_odom.core.geometry.kinematics import Geometry, wheel_rates
from diffdrive_odom.core.motion import routes
from diffdrive_odom.settings import odometry as odometry_settings
from diffdrive_odom.settings import params
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


def simulate(route: routes.Route, slip: float = 0.0, seed: int = 0) -> Run:
    """Drive ``route`` on the true base; readings at RATE and the true pose at each.

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
        s_l, s_r = TRUE.left_radius * d_l, TRUE.right_radius * d_r
        s_l += slip * math.sqrt(abs(s_l)) * rng.standard_normal()
        s_r += slip * math.sqrt(abs(s_r)) * rng.standard_normal()
        pose = oracle.wheel_arc(s_l, s_r, TRUE.separation, pose)
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
    assert abs(fit.start_yaw) < 1e-4, fit.start_yaw  # the reference is not turned
    for r in fit.runs:  # the nominal geometry is visibly wrong, the fitted one is not
        assert r.before.final_position_error_aligned_m > 0.1
        assert r.after.final_position_error_aligned_m < 1e-3


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


def test_held_out_check_beats_nominal_on_simulated_runs() -> None:
    """The nominal geometry is wrong by ~3 %: a geometry fitted on the other runs wins."""
    runs = [simulate(routes.umbmark(SIDE, clockwise=True), 0.002, seed=5),
            simulate(routes.umbmark(SIDE, clockwise=False), 0.002, seed=6),
            simulate(routes.figure_eight(1.0), 0.002, seed=7)]
    c = crossval.check(crossval.held_out(runs, NOMINAL))
    assert c is not None and c.runs == 3 and c.better
    assert c.fpe_held_out < 0.2 * c.fpe_nominal, c


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
    from diffdrive_odom.tools import bagio, evaluate

    settings = odometry_settings.odometry_settings({"wheel_radius": 0.042, "wheel_separation": 0.2})
    return [Run(name, batch.wheel_steps(bagio.read_joint_states(OPTIODOM / name), settings),
                evaluate.read_trajectory(OPTIODOM / name, "/ground_truth/pose"))
            for name in (CW_RUN, CCW_RUN)]


def test_optiodom_fit_is_physical_and_cuts_the_final_error() -> None:
    runs = _optiodom_runs()
    fit = calibration.fit(runs, Geometry(0.042, 0.2))
    left, right, b = fit.values
    # Sousa et al. (OptiOdom) calibrate this robot to r ~ 0.0418-0.0419 m, b ~ 0.2006 m.
    assert left == pytest.approx(0.0418, rel=5e-3) and right == pytest.approx(0.0418, rel=5e-3)
    assert b == pytest.approx(0.2008, rel=5e-3)
    before = max(r.before.final_position_error_aligned_m for r in fit.runs)
    after = max(r.after.final_position_error_aligned_m for r in fit.runs)
    assert before == pytest.approx(0.1075, abs=1e-3)  # the paper's nominal worst error
    assert after < 0.4 * before, (before, after)
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


def test_cli_refuses_when_held_out_runs_do_better_with_the_nominal_geometry(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """One square each way: a geometry fitted on one direction alone (Type A and B errors
    are not separable from one square, Borenstein and Feng) ends the other further off
    than the nominal one. calibrate says so first, exits 1 and prints no block."""
    saved = tmp_path / "fit.yaml"
    args = ["calibrate", str(OPTIODOM / CW_RUN), str(OPTIODOM / CCW_RUN),
            "--ground-truth", "/ground_truth/pose", *NOMINAL_ARGS, "--yaml", str(saved)]
    assert cli(args) == 1
    out = capsys.readouterr().out
    assert out.startswith("NOT BETTER THAN NOMINAL on held-out runs"), out
    assert "/**:" not in out and not saved.exists()
    assert "fixed, not fitted: clock lag" in out and "reference offset from the axle" in out
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
    assert out.startswith("NOT BETTER THAN NOMINAL on held-out runs (--force")
    assert plot.stat().st_size > 10_000
    block = _block(out)
    assert saved.read_text(encoding="utf-8").endswith(block)
    entry = yaml.safe_load(block)["/**"]["ros__parameters"]
    assert "wheel_radius_stddev_ratio" not in entry  # no sigma from 2 runs
    path = tmp_path / "calibrated.yaml"
    path.write_text(block, encoding="utf-8")
    values = params.load_params_file(path, "odometry_node")
    settings = odometry_settings.odometry_settings(values)
    fit = calibration.fit(_optiodom_runs(), Geometry(0.042, 0.2))
    got = values_of(settings.geometry)
    assert np.allclose(got, fit.values, rtol=1e-6), (got, fit.values)
    for line in ("left wheel radius", "1-sigma", "final position error", CW_RUN):
        assert line in out


def test_cli_with_one_run_says_the_check_cannot_be_made(
    capsys: pytest.CaptureFixture[str]
) -> None:
    assert cli(["calibrate", str(OPTIODOM / CCW_RUN), *NOMINAL_ARGS]) == 0
    out = capsys.readouterr().out
    assert out.startswith("held-out check: cannot be made with 1 run"), out
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
    bags = [str(OPTIODOM / CW_RUN), str(OPTIODOM / CCW_RUN)]
    assert cli(["calibrate", "--umbmark", *bags, "--side", "1.7", *NOMINAL_ARGS]) == 0
    from_topic = yaml.safe_load(_block(capsys.readouterr().out))
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
    ([str(OPTIODOM / CW_RUN)], "--params-file"),
    ([str(OPTIODOM / CW_RUN), "-p", "wheel_radius:=-1", "-p", "wheel_separation:=0.2"],
     "wheel_radius"),
    (["/no/such/bag", *NOMINAL_ARGS], "/no/such/bag"),
    ([str(OPTIODOM / CW_RUN), "--window", "0.25", *NOMINAL_ARGS], "--window"),
    ([str(OPTIODOM / CW_RUN), "--no-mount", *NOMINAL_ARGS], "--no-mount"),
    ([str(OPTIODOM / CW_RUN), "--session-drift", "-0.01", *NOMINAL_ARGS], "--session-drift"),
    ([str(OPTIODOM / CW_RUN), "--session-drift", "nan", *NOMINAL_ARGS], "--session-drift"),
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
