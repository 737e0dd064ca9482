"""calibrate against the anchor (issue 38 item 5): every real set, experiment and held-out pair.

    .venv/bin/python bench/bench_anchor.py [--quick]

The anchor (``bench/anchor.py``, written without the package): a plain least squares
over the three multipliers, the reference's lever arm and every run's start pose, on the
reference's positions only, leaving out the steps ``calibrate`` leaves out (the slips
its gyro finds, given to the anchor as stamp spans). ``calibrate`` is the product's own
decision (``core.evaluation.assessment.assess``: the objective chosen held out, the
mount's yaw, its lever arm where the runs determine it, the printed sigma).

Real sets of ``../shared/data`` (read in place; skipped, saying so, where missing):
``optiodom_train`` (8 experiments, bench_calibration's cache of its bags), ``optiodom``
(the two squares, one experiment) and ``phil_train`` (runs 0, 2, 6: the Vicon's; their
IMU finds the slips; they all turn counter-clockwise). ``turtlebot3_sim`` is simulated,
not judged here.

1. Per experiment: calibrate's multipliers (left, right, separation) and printed
   1-sigma, its mount, beside the anchor's multipliers, 1-sigma and lever arm; "agrees"
   when every multiplier is within 1 % of the anchor's or within 2 combined sigma
   (calibrate's printed sigma and the anchor's in quadrature). A multiplier the anchor
   does not determine (its 1-sigma above 1 %: positions alone do not see a turn on the
   spot when the reference sits on the axle) is named, not compared.
2. Held out: every leave-one-experiment-out pair of a kind (fitted on the kind's other
   experiments, judged on this one; the optiodom squares judged by the December
   squares), the same comparison on the training experiments, then each judged run's
   error by the anchor's figure (its RMS position error, its own start pose fitted, the
   lever arm fitted with the geometry) for nominal, calibrate and the anchor; phil_train
   leave-one-run-out.
3. phil_train (counter-clockwise only): the combination of the three values these
   runs see least (calibrate's information, the mount eliminated) and how weakly (the
   mirror ratio: 1 both ways, above 100 "turning one way only"), and calibrate against
   the anchor along it and across it, in calibrate's printed sigma.
4. phil_train's gyro as the judge of the turning, on all seven runs (4, 5, 7, 9 have no
   Vicon and neither fit saw them): over the half-second windows the gyro turns each
   way, the turn nominal's, calibrate's and the anchor's geometry give the wheels,
   against the gyro's (its bias at standstill removed; the navX agrees with the Vicon
   within 0.3 %); the steps calibrate leaves out (the slips) counted in neither. Beside
   them, why calibrate and the anchor part: the anchor's positions-only fit on the runs
   whole (not cut at the slips: their turn the Vicon's, as calibrate bridges them), each
   run's start pinned at the reference's first pose (calibrate's objective; its heading
   the Vicon's yaw less one mount yaw, fitted) or fitted (the anchor's).

5. phil_train: where calibrate and the anchor part and what moves it: their difference
   along each combination calibrate's information sees (strongest first); the anchor's
   fit of the runs whole, each start pinned or fitted, with the runs' first 0 to 10 s
   dropped; and the gyro's judge again, over every step of each turn one way between
   the slips (``anchor.stretches``: section 4's windows, picked by the gyro's own sign,
   favour the wheels where the body lags them), pooled per way on the runs seen and
   unseen.

``--quick``: the squares of optiodom_train only.
"""

from __future__ import annotations

import argparse
import sys
from argparse import Namespace
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "bench"))
import anchor  # noqa: E402
import bench_calibration as bc  # noqa: E402

from diffdrive_odom.core.evaluation import assessment, determinacy, leftout  # noqa: E402
from diffdrive_odom.core.evaluation.recorded_run import Run, values_of  # noqa: E402
from diffdrive_odom.core.geometry.kinematics import Geometry  # noqa: E402
from diffdrive_odom.settings.odometry import odometry_settings  # noqa: E402
from diffdrive_odom.tools.calibrating.runs import decode  # noqa: E402

PHIL = bc.SHARED / "phil_train"
PHIL_RUNS = (0, 2, 6)
PHIL_ALL = (0, 2, 6, 4, 5, 7, 9)  # 4, 5, 7, 9: wheels and gyro, no Vicon
PHIL_STEP_S = 0.025  # phil_train's wheels are read at 40 Hz
PHIL_PARAMS = {"wheel_radius": 0.035, "wheel_separation": 0.23,
               "left_wheel_names": ["wheel_left_joint"],
               "right_wheel_names": ["wheel_right_joint"], "ticks_per_revolution": 2578.33,
               "encoder_counter_bits": 16}
AGREE_RATIO, AGREE_SIGMAS = 0.01, 2.0
UNDETERMINED = 0.01  # the anchor's relative 1-sigma above which it does not determine a value
NAMES = ("left", "right", "separation")


@dataclass
class Exp:
    """One experiment: its runs for the package and for the anchor, its robot."""

    name: str
    kind: str
    runs: list[Run]
    anchored: list[anchor.AnchorRun]
    nominal: Geometry
    whole: list[anchor.WholeRun] = field(default_factory=list)  # phil_train's, uncut


def _spans(run: Run) -> list[tuple[int, int]]:
    """The steps calibrate leaves out (its slips' bridges; no reference: the slips) as
    stamp spans."""
    gone = (leftout.slipped(run.steps) if run.reference is None
            else leftout.replaced(leftout.bridges(run), len(run.steps)))
    edges = np.diff(np.concatenate(([0], gone.astype(np.int8), [0])))
    stamps = run.steps.stamp_ns
    return [(int(stamps[a]), int(stamps[b - 1]))
            for a, b in zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1),
                            strict=True)]


def optiodom(quick: bool) -> list[Exp]:
    out: dict[str, Exp] = {}
    data = bc.load_all(quick)
    for d in data:
        bag = (bc.TEST if d.exp == bc.TRAIN_ONLY else bc.bags()) / d.run.name
        t, left, right, ref = anchor.read_bag(bag, "left_wheel_joint", "right_wheel_joint")
        e = out.setdefault(d.group, Exp(d.group, d.kind, [], [], bc.NOMINAL))
        e.runs.append(d.run)
        e.anchored.append(anchor.anchor_run(d.run.name, t, left, right, ref))
    return list(out.values())


PhilTurns = dict[str, tuple[float, np.ndarray]]  # anchor.turns of one run


@dataclass
class PhilRun:
    """A phil_train run for the package, for the anchor (cut and whole; with its Vicon) and
    its gyro's turns."""

    run: Run
    anchored: anchor.AnchorRun | None
    whole: anchor.WholeRun | None
    turns: PhilTurns
    stretches: list[tuple[int, int, float, np.ndarray]]  # anchor.stretches


def _phil_run(n: int, vicon: bool) -> PhilRun:
    """phil_trial_``n`` (``vicon``: with its reference)."""
    plain = odometry_settings(PHIL_PARAMS)
    gyro = odometry_settings({**PHIL_PARAMS, "use_imu": True, "online_calibration": "disabled"})
    args = Namespace(ground_truth=None, topic="/joint_states", child_frame=None,
                     imu_topic=None)
    bag = PHIL / f"phil_trial_{n}"
    run = decode(str(bag), (plain, gyro), args, vicon)
    t, left, right, ref = anchor.read_bag(bag, "wheel_left_joint", "wheel_right_joint",
                                          ticks=2578.33, counter_bits=16, yaw=vicon)
    spans = _spans(run)
    rates = anchor.read_gyro(bag)
    turns = anchor.turns(t, left, right, rates, spans)
    stretches = anchor.stretches(t, left, right, rates, spans)
    if not vicon:
        return PhilRun(run, None, None, turns, stretches)
    return PhilRun(run, anchor.anchor_run(run.name, t, left, right, ref[:, :3], spans),
                   anchor.whole_run(run.name, t, left, right, ref, spans), turns, stretches)


def phil() -> list[Exp]:
    e = Exp("phil_train/0,2,6", "phil", [], [], odometry_settings(PHIL_PARAMS).geometry)
    for n in PHIL_RUNS:
        p = _phil_run(n, True)
        assert p.anchored is not None and p.whole is not None  # a Vicon run
        e.runs.append(p.run)
        e.anchored.append(p.anchored)
        e.whole.append(p.whole)
    return [e]


def _mult(g: Geometry, nominal: Geometry) -> np.ndarray:
    return values_of(g) / values_of(nominal)


@dataclass
class Compared:
    assessed: assessment.Assessment
    cal: np.ndarray  # multipliers
    cal_sigma: np.ndarray | None
    mount: str
    fit: anchor.AnchorFit
    agrees: bool
    lever: tuple[float, float]
    undetermined: tuple[str, ...]  # what the anchor does not determine


def compare(runs: Sequence[Run], anchored: Sequence[anchor.AnchorRun], nominal: Geometry
            ) -> Compared:
    a = assessment.assess(runs, nominal)
    cal = _mult(a.fit.geometry, nominal)
    sig = None if a.printed is None else np.sqrt(np.diag(a.printed)) / values_of(nominal)
    f = anchor.fit(anchored, nominal.wheel_radius, nominal.wheel_separation)
    comb = f.sigma[:3] if sig is None else np.hypot(sig, f.sigma[:3])
    diff = np.abs(cal - f.multipliers)
    free = f.sigma[:3] > UNDETERMINED * f.multipliers
    agrees = bool(np.all((diff <= AGREE_RATIO * f.multipliers) | (diff <= AGREE_SIGMAS * comb)
                         | free))
    m = a.mount
    text = m.mount.text(m.sigma) + (" (lever held at 0)" if m.lever_held else "")
    return Compared(a, cal, sig, text, f, agrees, (m.mount.x, m.mount.y),
                    tuple(n for n, u in zip(NAMES, free, strict=True) if u))


def _cells(v: np.ndarray, s: np.ndarray | None) -> str:
    return " ".join(f"{x:.5f}" + (f"+-{e:.5f}" if s is not None else "") for x, e in
                    zip(v, s if s is not None else v, strict=True))


def per_experiment(exps: Sequence[Exp]) -> int:
    print("== 1. Per experiment: calibrate (multipliers +- printed sigma) beside the anchor "
          "(multipliers +- its sigma, lever arm [m]) ==")
    bad = 0
    for e in exps:
        c = compare(e.runs, e.anchored, e.nominal)
        bad += not c.agrees
        f = c.fit
        print(f"{e.name:28s} calibrate {_cells(c.cal, c.cal_sigma)}\n"
              f"{'':28s} anchor    {_cells(f.multipliers, f.sigma[:3])} lever "
              f"({f.lever[0]:+.4f}, {f.lever[1]:+.4f}) +- ({f.sigma[3]:.4f}, {f.sigma[4]:.4f})"
              f"\n{'':28s} mount found: {c.mount}; "
              f"{'agrees' if c.agrees else 'DOES NOT AGREE'}"
              + (f" (the anchor does not determine: {', '.join(c.undetermined)})"
                 if c.undetermined else ""), flush=True)
    return bad


def held_out(exps: Sequence[Exp]) -> int:
    print("\n== 2. Held out: fitted on the kind's other experiments (LOEO; phil_train: the "
          "other runs), judged per run by the anchor's figure [m] ==")
    print(f"{'judged run':34s} {'nominal':>8s} {'calibrate':>9s} {'anchor':>8s}  training "
          "multipliers agree")
    bad = 0
    pairs: list[tuple[str, list[Run], list[anchor.AnchorRun], list[int], Exp]] = []
    for e in exps:
        if e.kind == "phil":
            for i in range(len(e.runs)):
                rest = [j for j in range(len(e.runs)) if j != i]
                pairs.append((f"{e.name} w/o {i}", [e.runs[j] for j in rest],
                              [e.anchored[j] for j in rest], [i], e))
            continue
        kind = e.kind
        others = [o for o in exps if o.kind == kind and o is not e
                  and bc.TRAIN_ONLY not in o.name]
        if not others:
            continue
        pairs.append((e.name, [r for o in others for r in o.runs],
                      [r for o in others for r in o.anchored], list(range(len(e.runs))), e))
    worse = total = 0
    for label, runs, anchored, judged, e in pairs:
        c = compare(runs, anchored, e.nominal)
        bad += not c.agrees
        r0, b0 = e.nominal.wheel_radius, e.nominal.wheel_separation
        levers = [anchor.fit(anchored, r0, b0, multipliers=m).lever
                  for m in ((1.0, 1.0, 1.0), c.cal)]
        for i in judged:
            run = e.anchored[i]
            n = anchor.judge(run, (1.0, 1.0, 1.0), levers[0], r0, b0)
            cal = anchor.judge(run, c.cal, levers[1], r0, b0)
            anc = anchor.judge(run, c.fit.multipliers, c.fit.lever, r0, b0)
            total += 1
            worse += cal > n
            print(f"{run.name:34s} {n:8.4f} {cal:9.4f} {anc:8.4f}  {label}: "
                  f"{'yes' if c.agrees else 'NO'}"
                  + (f" (anchor: {', '.join(c.undetermined)} undetermined)"
                     if c.undetermined else ""), flush=True)
    print(f"calibrate's geometry worse than nominal on {worse} of {total} judged runs")
    return bad


def phil_combination(e: Exp, c: Compared) -> None:
    print("\n== 3. phil_train, all counter-clockwise: what the runs determine ==")
    a, f = c.assessed, c.fit
    w = a.weakest
    print(f"the combination these runs see least: {w[0]:+.3f} left {w[1]:+.3f} right "
          f"{w[2]:+.3f} separation (relative); mirror ratio {a.coverage.mirror_ratio:.0f} "
          f"({a.coverage.reason or 'determined by calibrate rule: under 100'})")
    if c.cal_sigma is not None:
        d = (c.cal - f.multipliers) / c.cal_sigma  # in calibrate's printed sigma, per value
        rel = (c.cal - f.multipliers) / f.multipliers
        along = float(w @ rel)
        across = float(np.linalg.norm(rel - along * w))
        print("calibrate - anchor per value [printed sigma]: "
              + " ".join(f"{n} {v:+.2f}" for n, v in zip(NAMES, d, strict=True))
              + f"; along the weakest combination {100 * along:+.2f} %, across it "
              f"{100 * across:.2f} %")
    print(f"calibrate {_cells(c.cal, c.cal_sigma)}; mount {c.mount}\n"
          f"anchor    {_cells(f.multipliers, f.sigma[:3])}; lever ({f.lever[0]:+.3f}, "
          f"{f.lever[1]:+.3f}) m")


def _against_gyro(gyro_turn: float, wheels: np.ndarray, geometries: dict[str, np.ndarray],
                  nominal: Geometry) -> dict[str, float]:
    """Each geometry's turn of the ``wheels`` [rad] less the gyro's ``gyro_turn``."""
    return {k: anchor.predicted_turn(wheels, m, nominal.wheel_radius, nominal.wheel_separation)
            - gyro_turn for k, m in geometries.items()}


GyroRuns = list[tuple[int, PhilRun]]  # phil_train's runs read without their Vicon


def phil_gyro(e: Exp, c: Compared, gyro_runs: GyroRuns) -> None:
    """The turning of nominal's, calibrate's and the anchor's geometry judged by the gyro."""
    print("\n== 4. phil_train: the turn each geometry gives the wheels against the gyro's "
          "(navX, bias at standstill removed; within 0.3 % of the Vicon), on the turns each "
          "way, slips left out; runs 4, 5, 7, 9 unseen by either fit ==")
    r0, b0 = e.nominal.wheel_radius, e.nominal.wheel_separation
    geometries = {"nominal": np.ones(3), "calibrate": c.cal, "anchor": c.fit.multipliers}
    for pinned, name in ((True, "pinned"), (False, "free")):
        m, lever, yaw, rms = anchor.start_fit(e.whole, r0, b0, pinned)
        geometries[name] = m
        print(f"the runs whole (slips' turn the Vicon's), positions, each start {name:6s}: "
              f"{_cells(m, None)}, k_L/k_b {m[0] / m[2]:.4f}, k_R/k_b {m[1] / m[2]:.4f}, "
              f"lever ({lever[0]:+.4f}, {lever[1]:+.4f}) m"
              + (f", mount yaw {np.degrees(yaw):+.2f} deg" if pinned else "")
              + f", RMS {1000 * rms:.1f} mm")
    print(f"{'run':14s} {'way':4s} {'gyro [deg]':>10s}  " + "  ".join(
        f"{k:>9s}" for k in geometries) + "   (predicted / gyro - 1, %)")
    pooled: dict[tuple[str, str], list[float]] = {}
    for n, run in gyro_runs:
        for way, (gyro_turn, wheels) in run.turns.items():
            if abs(gyro_turn) < 0.5:  # under 30 deg that way: none to judge
                continue
            cells = []
            seen = "seen" if n in PHIL_RUNS else "unseen"
            for k, err in _against_gyro(gyro_turn, wheels, geometries, e.nominal).items():
                cells.append(f"{100 * err / gyro_turn:+9.2f}")
                acc = pooled.setdefault((seen, k), [0.0, 0.0])
                acc[0] += err * np.sign(gyro_turn)  # > 0: turns too much
                acc[1] += abs(gyro_turn)
            print(f"phil_trial_{n:<3d} {way:4s} {np.degrees(gyro_turn):+10.1f}  "
                  + "  ".join(cells), flush=True)
    for seen in ("seen", "unseen"):
        print(f"pooled, runs {seen:6s}: " + "  ".join(
            f"{k} {100 * pooled[(seen, k)][0] / pooled[(seen, k)][1]:+.2f} %"
            for k in geometries) + "  (turned too much (+) or too little, over all the "
              "turns either way)")


def phil_parting(e: Exp, c: Compared, gyro_runs: GyroRuns) -> None:
    """Where calibrate and the anchor part on phil_train, and what moves it."""
    print("\n== 5. phil_train: where calibrate and the anchor part, and what moves it ==")
    shapes = assessment.mount_spec(e.runs, e.nominal, None)[2]
    info = determinacy.geometry_part(sum((s.information for s in shapes), np.zeros((6, 6))),
                                     lever=shapes[0].lever)
    w, u = np.linalg.eigh(info)
    gap = (c.cal - c.fit.multipliers) / c.fit.multipliers
    for e_k in (2, 1, 0):
        d = u[:, e_k] if u[np.argmax(np.abs(u[:, e_k])), e_k] > 0 else -u[:, e_k]
        print(f"calibrate's information along {d[0]:+.2f} left {d[1]:+.2f} right {d[2]:+.2f} "
              f"separation: {w[e_k] / w[-1]:.2g} of the strongest; calibrate - anchor along it "
              f"{100 * float(gap @ d):+.3f} %")
    r0, b0 = e.nominal.wheel_radius, e.nominal.wheel_separation
    for seconds in (0, 2, 4, 6, 10):
        cells = []
        for pinned in (True, False):
            steps = int(seconds / PHIL_STEP_S)
            m, _, _, rms = anchor.start_fit([anchor.later(r, steps) for r in e.whole], r0, b0,
                                            pinned)
            cells.append(f"start {'pinned' if pinned else 'fitted'} k_L/k_b {m[0] / m[2]:.4f} "
                         f"k_R/k_b {m[1] / m[2]:.4f} (RMS {1000 * rms:.1f} mm)")
        print(f"the runs whole from {seconds:2d} s on: " + "; ".join(cells), flush=True)
    geometries = {"nominal": np.ones(3), "calibrate": c.cal, "anchor": c.fit.multipliers}
    print("the gyro's turn over the stretches between slips (every step counted, from "
          f"{anchor.AFTER_SLIP_NS / 1e9:g} s after a slip), predicted / gyro - 1 in %: "
          + ", ".join(geometries))
    pooled: dict[tuple[str, str, str], list[float]] = {}
    for n, run in gyro_runs:
        for i, j, gyro_turn, wheels in run.stretches:
            seen = "seen" if n in PHIL_RUNS else "unseen"
            way = "ccw" if gyro_turn > 0 else "cw"
            cells = []
            for k, err in _against_gyro(gyro_turn, wheels, geometries, e.nominal).items():
                cells.append(f"{100 * err / gyro_turn:+7.2f}")
                acc = pooled.setdefault((seen, way, k), [0.0, 0.0])
                acc[0] += err
                acc[1] += gyro_turn
            print(f"phil_trial_{n} steps {i:5d}-{j:5d} {way:3s} {np.degrees(gyro_turn):+8.1f} "
                  "deg: " + " ".join(cells), flush=True)
    for seen in ("seen", "unseen"):
        for way in ("ccw", "cw"):
            if (seen, way, "nominal") in pooled:
                print(f"pooled, runs {seen:6s} {way:3s}: " + "  ".join(
                    f"{k} {100 * pooled[(seen, way, k)][0] / pooled[(seen, way, k)][1]:+.2f} %"
                    for k in geometries))


def main(argv: Sequence[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="optiodom_train's squares only")
    args = ap.parse_args(list(argv))
    exps: list[Exp] = []
    if (bc.TRAIN / "to_rosbag2.py").exists():
        exps += optiodom(args.quick)
    else:
        print(f"skipped: {bc.TRAIN} not found (the project's shared data)")
    phils = phil() if PHIL.is_dir() and not args.quick else []
    if not PHIL.is_dir():
        print(f"skipped: {PHIL} not found")
    if not exps and not phils:
        return 0
    bad = per_experiment([*exps, *phils])
    bad += held_out([*exps, *phils])
    for e in phils:  # calibrate on the runs and the gyro runs read once, for sections 3-5
        c = compare(e.runs, e.anchored, e.nominal)
        gyro_runs = [(n, _phil_run(n, False)) for n in PHIL_ALL]
        phil_combination(e, c)
        phil_gyro(e, c, gyro_runs)
        phil_parting(e, c, gyro_runs)
    print(f"\nexperiments and held-out pairs where calibrate does not agree with the anchor: "
          f"{bad}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
