"""eval: metrics against closed forms and an independent computation on real data."""

from __future__ import annotations

import itertools
import json
import math
import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from diffdrive_odom.core.evaluation import metrics
from diffdrive_odom.core.evaluation.metrics import Trajectory
from diffdrive_odom.tools.bags import bagio, bagwriter, poses
from diffdrive_odom.tools.cli import main as cli

from bagutil import OPTIODOM_PARAMS, OdomMessages, mcap_messages, mounted_copy, write_params
from rosutil import DATA

RUN04 = DATA / "optiodom" / "square_231220200029_run-04"


def _ns(t: Any) -> int:
    return int(t.sec) * 10**9 + int(t.nanosec)


def _yaw(q: Any) -> float:
    return 2.0 * math.atan2(q.z, q.w)


def test_run04_figures_equal_an_independent_computation(tmp_path: Path) -> None:
    """Wheel angles integrated here (exact arcs), ground truth read by mcap-ros2-support."""
    joints = sorted((m for _, _, m in mcap_messages(RUN04, ["/joint_states"])),
                    key=lambda m: _ns(m.header.stamp))
    truth = {_ns(m.header.stamp): m.pose for _, _, m in mcap_messages(RUN04,
                                                                       ["/ground_truth/pose"])}
    r, b = 0.042, 0.200
    x = y = th = 0.0
    est: dict[int, tuple[float, float, float]] = {_ns(joints[0].header.stamp): (0.0, 0.0, 0.0)}
    for prev, cur in itertools.pairwise(joints):
        sl = r * (cur.position[0] - prev.position[0])
        sr = r * (cur.position[1] - prev.position[1])
        ds, dth = 0.5 * (sl + sr), (sr - sl) / b
        if abs(dth) < 1e-12:
            x, y = x + ds * math.cos(th), y + ds * math.sin(th)
        else:
            x += ds / dth * (math.sin(th + dth) - math.sin(th))
            y -= ds / dth * (math.cos(th + dth) - math.cos(th))
        th += dth
        est[_ns(cur.header.stamp)] = (x, y, th)
    # Ground truth and encoders share their stamps in this data: no interpolation needed.
    common = sorted(set(est) & set(truth))
    assert len(common) == len(joints) == 1385
    err = [math.hypot(est[t][0] - truth[t].position.x, est[t][1] - truth[t].position.y)
           for t in common]
    final = err[-1]
    ate = math.sqrt(sum(e * e for e in err) / len(err))
    head = math.remainder(est[common[-1]][2] - _yaw(truth[common[-1]].orientation), 2 * math.pi)
    path = sum(math.hypot(truth[a].position.x - truth[c].position.x,
                          truth[a].position.y - truth[c].position.y)
               for a, c in itertools.pairwise(common))
    assert final == pytest.approx(0.1075, abs=5e-4)  # the figure the data README quotes

    params = write_params(tmp_path / "p.yaml", OPTIODOM_PARAMS)
    out = tmp_path / "out"
    assert cli(["replay", str(RUN04), "--params-file", str(params), "-o", str(out)]) == 0
    figures = tmp_path / "f.json"
    # the motion capture tracks the robot centre, facing forward: the reference on the axle
    assert cli(["eval", str(out), "--odom", "/odom", "--reference-bag", str(RUN04),
                "--ground-truth", "/ground_truth/pose", "--json", str(figures),
                "--plot", str(tmp_path / "f.png"), "--reference-offset=0,0,0"]) == 0
    got = json.loads(figures.read_text())
    assert got["samples"] == 1385
    assert got["final_position_error_m"] == pytest.approx(final, abs=1e-9)
    assert got["ate_rmse_m"] == pytest.approx(ate, abs=1e-9)
    assert got["final_heading_error_rad"] == pytest.approx(head, abs=1e-9)
    assert got["distance_m"] == pytest.approx(path, abs=1e-9)
    assert got["final_error_per_m"] == pytest.approx(got["final_position_error_aligned_m"] / path)
    # Both start at the origin: aligning the start changes (almost) nothing.
    assert got["final_position_error_aligned_m"] == pytest.approx(final, abs=1e-6)
    png = (tmp_path / "f.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 20_000


def _figures(path: Path) -> dict[str, float]:
    return {k: float(v) for k, v in json.loads(path.read_text()).items() if v is not None}


@pytest.mark.parametrize(("x", "y", "yaw_deg"), [(-0.12, 0.20, 150.0), (0.3, -0.3, -104.0)])
def test_a_mounted_reference_with_its_offset_gives_the_axle_s_figures(
        tmp_path: Path, x: float, y: float, yaw_deg: float) -> None:
    """The same run's reference recorded off the axle and turned (bagutil.mounted_copy):
    with --reference-offset it is moved back onto base_link, and every figure equals the
    one against the reference on the axle (to the floats' rounding of the round trip)."""
    params = write_params(tmp_path / "p.yaml", OPTIODOM_PARAMS)
    out = tmp_path / "out"
    assert cli(["replay", str(RUN04), "--params-file", str(params), "-o", str(out)]) == 0
    mounted = mounted_copy(RUN04, tmp_path / "mounted", x, y, math.radians(yaw_deg))
    axle, moved = tmp_path / "axle.json", tmp_path / "moved.json"
    for ref, offset, where in ((RUN04, "0,0,0", axle), (mounted, f"{x},{y},{yaw_deg}", moved)):
        assert cli(["eval", str(out), "--odom", "/odom", "--reference-bag", str(ref),
                    "--json", str(where), f"--reference-offset={offset}"]) == 0
    a, m = _figures(axle), _figures(moved)
    assert a.keys() == m.keys()
    for key in a:
        assert m[key] == pytest.approx(a[key], rel=1e-6, abs=1e-9), key


def test_without_an_offset_eval_finds_the_reference_s_yaw_from_its_travel(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A reference turned 104 deg (the phil_train Vicon marker's), no offset given: eval
    finds the yaw from the reference's own direction of travel and says it; its
    start-aligned figures then equal the axle's up to that estimate's error (here its
    yaw on the axle, -0.4 deg, is the motion capture's own: the same in both)."""
    params = write_params(tmp_path / "p.yaml", OPTIODOM_PARAMS)
    out = tmp_path / "out"
    assert cli(["replay", str(RUN04), "--params-file", str(params), "-o", str(out)]) == 0
    mounted = mounted_copy(RUN04, tmp_path / "mounted", 0.0, 0.0, math.radians(104.0))
    found = {}
    for ref, where in ((RUN04, tmp_path / "axle.json"), (mounted, tmp_path / "moved.json")):
        assert cli(["eval", str(out), "--odom", "/odom", "--reference-bag", str(ref),
                    "--json", str(where)]) == 0
        said = capsys.readouterr().err
        m = re.search(r"reference mount: yaw ([-+\d.]+) \+- ([\d.]+) deg from its direction "
                      r"of travel", said)
        assert m, said
        found[ref] = (float(m.group(1)), float(m.group(2)), _figures(where))
    (yaw_a, sig, fig_a), (yaw_m, _, fig_m) = found[RUN04], found[mounted]
    assert abs(yaw_a) < 3 * sig + 0.5 and sig < 0.5
    assert yaw_m == pytest.approx(yaw_a + 104.0, abs=0.02)
    for key in ("final_position_error_aligned_m", "ate_rmse_aligned_m", "final_error_per_m",
                "rpe_translation_per_m"):
        assert fig_m[key] == pytest.approx(fig_a[key], rel=1e-3), key


def _line(n: int = 201, speed: float = 0.5, hz: float = 20.0) -> Trajectory:
    t = np.arange(n) / hz
    return Trajectory.from_arrays((t * 1e9).astype(np.int64) + 10**9, speed * t,
                                  np.zeros(n), np.zeros(n))


def _square(n_side: int = 100) -> Trajectory:
    """1 m square driven counter-clockwise, with in-place turns at the corners."""
    pts: list[tuple[float, float, float]] = []
    x = y = yaw = 0.0
    for _ in range(4):
        for _ in range(n_side):
            x, y = x + 0.01 * math.cos(yaw), y + 0.01 * math.sin(yaw)
            pts.append((x, y, yaw))
        for _ in range(10):
            yaw += math.pi / 20
            pts.append((x, y, yaw))
    arr = np.array(pts)
    stamps = 10**9 + np.arange(len(arr), dtype=np.int64) * 50_000_000
    return Trajectory.from_arrays(stamps, arr[:, 0], arr[:, 1], arr[:, 2])


def test_identical_trajectories_have_zero_error() -> None:
    ref = _square()
    m = metrics.evaluate(ref, ref)
    assert m.samples == len(ref)
    for name in ("final_position_error_m", "final_heading_error_rad", "ate_rmse_m",
                 "ate_rmse_aligned_m", "ate_rmse_best_fit_m", "rpe_translation_per_m",
                 "rpe_heading_rad_per_m"):
        assert getattr(m, name) == pytest.approx(0.0, abs=1e-12), name
    assert m.distance_m == pytest.approx(4.0 - 0.01, abs=1e-9)  # first sample is 1 cm in


def test_a_rigidly_moved_trajectory_is_only_wrong_before_alignment() -> None:
    ref = _square()
    a, tx, ty = 0.3, 0.5, -0.2
    c, s = math.cos(a), math.sin(a)
    est = Trajectory.from_arrays(ref.stamp_ns, tx + c * ref.x - s * ref.y,
                                 ty + s * ref.x + c * ref.y, ref.yaw + a)
    m = metrics.evaluate(est, ref)
    # Raw: the end (back at ~origin) is off by where the origin went.
    end = np.array([ref.x[-1], ref.y[-1]])
    moved = np.array([tx + c * end[0] - s * end[1], ty + s * end[0] + c * end[1]])
    assert m.final_position_error_m == pytest.approx(float(np.hypot(*(moved - end))), abs=1e-12)
    assert m.final_heading_error_rad == pytest.approx(a, abs=1e-12)
    assert m.ate_rmse_m > 0.1
    for name in ("final_position_error_aligned_m", "final_heading_error_aligned_rad",
                 "ate_rmse_aligned_m", "ate_rmse_best_fit_m", "rpe_translation_per_m",
                 "rpe_heading_rad_per_m"):
        assert getattr(m, name) == pytest.approx(0.0, abs=1e-9), name


def test_scale_error_is_a_constant_error_per_metre() -> None:
    """Odometry reading 2 % long on a straight line: 2 % per metre, everywhere."""
    ref = _line()  # 10 s at 0.5 m/s = 5 m
    k = 0.02
    est = Trajectory.from_arrays(ref.stamp_ns, (1 + k) * ref.x, ref.y, ref.yaw)
    m = metrics.evaluate(est, ref, segment_length=1.0)
    assert m.distance_m == pytest.approx(5.0)
    assert m.final_position_error_m == pytest.approx(k * 5.0, abs=1e-12)
    assert m.final_error_per_m == pytest.approx(k, abs=1e-12)
    assert m.rpe_translation_per_m == pytest.approx(k, abs=1e-12)
    # ATE of a linearly growing error e(t) = k x(t): RMSE = k * sqrt(mean(x^2)).
    assert m.ate_rmse_m == pytest.approx(k * math.sqrt(np.mean(ref.x ** 2)), abs=1e-12)
    # 1 m stretches on a 5 m line: every pose at least 1 m before the end starts one.
    assert m.rpe_segments == int(np.sum(ref.x <= 4.0 + 1e-9))


def test_heading_drift_per_metre() -> None:
    """A constant yaw bias rate: the stretch's heading error is the bias over 1 m."""
    ref = _line()
    bias = 0.01  # rad per metre travelled
    est = Trajectory.from_arrays(ref.stamp_ns, ref.x, ref.y, bias * ref.x)
    m = metrics.evaluate(est, ref, segment_length=1.0)
    assert m.rpe_heading_rad_per_m == pytest.approx(bias, rel=1e-9)
    assert m.final_heading_error_rad == pytest.approx(bias * 5.0, abs=1e-12)


def test_stamps_are_matched_by_interpolation_never_extrapolated() -> None:
    ref = _line(n=101, hz=10.0)  # 0..10 s, 10 Hz, x = 0.5 t
    t = np.arange(-1.0, 12.0, 1 / 33.0)  # 33 Hz, starts before and ends after the reference
    est = Trajectory.from_arrays((t * 1e9).astype(np.int64) + 10**9, 0.5 * t, 0 * t, 0 * t)
    m = metrics.evaluate(est, ref)
    assert m.ate_rmse_m == pytest.approx(0.0, abs=1e-9)
    assert m.samples == int(np.sum((t >= -1e-9) & (t <= 10.0 + 1e-9)))
    assert m.duration_s <= 10.0
    # A gap in the reference longer than max_gap is not bridged.
    keep = (ref.stamp_ns < 2 * 10**9) | (ref.stamp_ns > 8 * 10**9)
    holey = Trajectory.from_arrays(ref.stamp_ns[keep], ref.x[keep], ref.y[keep], ref.yaw[keep])
    assert metrics.evaluate(est, holey).samples < m.samples * 0.5


def test_headings_are_compared_modulo_a_turn() -> None:
    ref = _square()
    est = Trajectory.from_arrays(ref.stamp_ns, ref.x, ref.y, ref.yaw + 4 * math.pi)
    m = metrics.evaluate(est, ref)
    assert m.final_heading_error_rad == pytest.approx(0.0, abs=1e-12)
    wrapped = np.remainder(ref.yaw + math.pi, 2 * math.pi) - math.pi
    est2 = Trajectory.from_arrays(ref.stamp_ns, ref.x, ref.y, wrapped)  # unwrapped on input
    assert metrics.evaluate(est2, ref).rpe_heading_rad_per_m == pytest.approx(0.0, abs=1e-12)


def _write_reference_bag(path: Path, traj: Trajectory) -> None:
    store = bagio.typestore()
    t = store.types
    odom = OdomMessages(store, "world", "robot")
    cov = [0.0] * 36
    with bagwriter.BagWriter(path) as w:
        w.add_topic("/pose", "geometry_msgs/msg/PoseStamped")
        w.add_topic("/odometry", bagio.ODOMETRY)
        w.add_topic("/tf", bagio.TF_MESSAGE)
        for ns, x, y, yaw in zip(traj.stamp_ns, traj.x, traj.y, traj.yaw, strict=True):
            o = odom.odometry(int(ns), float(x), float(y), float(yaw),
                              linear=0.0, angular=0.0, pose_covariance=cov, twist_covariance=cov)
            w.write("/odometry", int(ns), o)
            w.write("/pose", int(ns), t["geometry_msgs/msg/PoseStamped"](
                header=o.header, pose=o.pose.pose))
            robot = odom.tf(int(ns), float(x), float(y), float(yaw)).transforms[0]
            other = odom.tf(int(ns), 5.0, 5.0, 0.0).transforms[0]
            other.child_frame_id = "other"
            w.write("/tf", int(ns), t[bagio.TF_MESSAGE](transforms=[other, robot]))


def test_reference_types_and_the_cli(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    ref = _square(n_side=40)
    bag = tmp_path / "ref"
    _write_reference_bag(bag, ref)
    for topic, child in (("/pose", None), ("/odometry", None), ("/tf", "robot")):
        got = poses.read_trajectory(bag, topic, child)
        assert np.array_equal(got.stamp_ns, ref.stamp_ns)
        assert np.allclose(got.x, ref.x, atol=1e-15) and np.allclose(got.y, ref.y, atol=1e-15)
        assert np.allclose(got.yaw, ref.yaw, atol=1e-12), topic
    with pytest.raises(bagio.BagError, match="other"):  # /tf needs a child frame
        poses.read_trajectory(bag, "/tf")
    out = tmp_path / "m.json"
    assert cli(["eval", str(bag), "--odom", "/odometry", "--ground-truth", "/tf",
                "--child-frame", "robot", "--json", str(out)]) == 0
    assert json.loads(out.read_text())["ate_rmse_m"] == pytest.approx(0.0, abs=1e-12)
    assert "ATE RMSE" in capsys.readouterr().out
    assert cli(["eval", str(bag), "--odom", "/odometry", "--ground-truth", "/tf"]) == 2
    assert cli(["eval", str(bag), "--odom", "/nothing"]) == 2
    assert "not in the bag" in capsys.readouterr().err


def test_eval_on_a_bag_like_the_demo_s_needs_no_topic_flags(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The demo and sim_node write /ground_truth/odom; eval's defaults must find it."""
    from diffdrive_odom.demo.settings import BAG_TOPICS

    assert "/ground_truth/odom" in BAG_TOPICS and "/odom" in BAG_TOPICS
    ref = _square(n_side=40)
    bag = tmp_path / "bag"
    msgs = OdomMessages(bagio.typestore(), "odom", "base_link")
    cov = [0.0] * 36
    with bagwriter.BagWriter(bag) as w:
        for topic in ("/odom", "/ground_truth/odom"):
            w.add_topic(topic, bagio.ODOMETRY)
        w.add_topic("/tf", bagio.TF_MESSAGE)
        for ns, x, y, yaw in zip(ref.stamp_ns, ref.x, ref.y, ref.yaw, strict=True):
            args = (int(ns), float(x), float(y), float(yaw))
            w.write("/odom", int(ns), msgs.odometry(
                *args, linear=0.0, angular=0.0, pose_covariance=cov, twist_covariance=cov))
            w.write("/ground_truth/odom", int(ns), msgs.odometry(
                int(ns), float(x) + 0.1, float(y), float(yaw),
                linear=0.0, angular=0.0, pose_covariance=cov, twist_covariance=cov))
            w.write("/tf", int(ns), msgs.tf(*args))
    out = tmp_path / "m.json"
    assert cli(["eval", str(bag), "--json", str(out)]) == 0
    assert "using /ground_truth/odom" in capsys.readouterr().err
    assert json.loads(out.read_text())["ate_rmse_m"] == pytest.approx(0.1, abs=1e-12)
    # Odometry on /tf with one child frame: that frame, and eval says so.
    assert cli(["eval", str(bag), "--odom", "/tf", "--json", str(out)]) == 0
    assert "child frame 'base_link'" in capsys.readouterr().err
    assert json.loads(out.read_text())["ate_rmse_m"] == pytest.approx(0.1, abs=1e-12)


def test_eval_names_the_flag_that_picks_a_tf_frame(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bag = tmp_path / "ref"
    _write_reference_bag(bag, _square(n_side=40))  # /tf has frames 'other' and 'robot'
    assert cli(["eval", str(bag), "--odom", "/tf", "--ground-truth", "/pose"]) == 2
    err = capsys.readouterr().err
    assert "--odom-child-frame" in err and "'other', 'robot'" in err
    assert cli(["eval", str(bag), "--odom", "/tf", "--odom-child-frame", "robot",
                "--ground-truth", "/pose"]) == 0
    assert cli(["eval", str(bag), "--odom", "/pose", "--ground-truth", "/tf"]) == 2
    err = capsys.readouterr().err
    assert "--child-frame" in err and "--odom-child-frame" not in err


def test_eval_refuses_unusable_paths_in_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bag = tmp_path / "ref"
    _write_reference_bag(bag, _square(n_side=40))
    text = tmp_path / "notes.txt"
    text.write_text("not a bag\n")
    ok = ["eval", str(bag), "--odom", "/odometry", "--ground-truth", "/pose"]
    cases = {
        str(text): ["eval", str(text)],
        "--plot": [*ok, "--plot", str(tmp_path / "missing_dir" / "p.png")],
        "--json": [*ok, "--json", str(tmp_path)],
        "there is no ground-truth topic": ["eval", str(bag), "--odom", "/odometry"],
    }
    for name, argv in cases.items():
        assert cli(argv) == 2, name
        captured = capsys.readouterr()
        lines = captured.err.strip().splitlines()
        assert len(lines) == 1 and name in lines[0], lines
        assert captured.out == "", name
