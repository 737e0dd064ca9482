"""The held-out verdict of ``calibrate`` judged on runs it never saw: false refusals, acceptances.

    .venv/bin/python bench/bench_verdict.py [--rule old|folds|margin|new|all] [--jobs N] [--quick]

Data: ``../shared/data/optiodom_train`` (45 runs of one real robot, 8 experiments; Sousa
et al., "OptiOdom: a Generic Approach for Odometry Calibration of Wheeled Mobile
Robots"), converted once with its ``to_rosbag2.py`` into the cache folder that
``bench_calibration.py`` uses. Skips, saying so, where the data are missing.

For every experiment and every 3- and 4-run subset of its runs, as a user would give
them to ``calibrate``: fit the subset (``core.calibration.fit``, the CLI's fit: the mount's
yaw, its lever arm where the subset determines it), then judge that geometry on the
experiment's OTHER runs by the one judge's worst (``core.evaluation.judge``: the whole
trajectory and its end, the reference moved onto base_link by the fit's mount) against
the nominal geometry's worst on the same runs: better, worse, or a tie (within 1 mm).
The verdict on the subset itself is the CLI's:

- old: the rule at 13dd1c3, ``crossval.check`` over every leave-one-run-out fold
  (accepted when the held-out mean drops, else refused);
- folds: ``crossval.judge`` without its margin: the same check over the folds that can
  judge (training runs that determine the geometry, a held-out run whose end depends
  on it: ``core.determinacy``), "cannot tell" when none remains (the block is printed
  with a warning, exit 0);
- margin: the rule at 1bec3f3, ``crossval.judge`` with its margin and without the
  leverage test: "cannot tell" also when the held-out change of the mean final error is
  within the RMS final error the fit leaves on its own runs over the square root of the
  folds counted;
- new: ``crossval.judge`` as ``calibrate`` calls it: also leaves out a fold whose
  held-out run's end moves far more with the geometry than its training runs' residuals
  do (``determinacy.extrapolates``: a line judged by a fit to another line).

The leverage of every fold that passes the other tests is printed per experiment, and
the totals per half of the data: the June 2020 experiments (where ``MAX_LEVERAGE`` was
chosen) and the December 2020 ones (judged).

Counted per experiment and in total: false refusals (held out better, refused: no
block), false acceptances (held out worse, block without warning) and "cannot tell".
The experiments' free paths (1 and 2 runs) give no subset with a run left to judge.
Every fit goes through the decode-once batch path; fits are cached by their training
runs (a 4-run subset's folds are 3-run subsets), on at most 2 processes.
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import math
import multiprocessing
import sys
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

from diffdrive_odom.core.bulk import batch
from diffdrive_odom.core.evaluation import calibration, crossval, determinacy
from diffdrive_odom.core.evaluation.judge import judgment
from diffdrive_odom.core.evaluation.recorded_run import Run
from diffdrive_odom.settings.odometry import odometry_settings
from diffdrive_odom.tools.bags import bagreadings, poses

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "bench"))
import bench_calibration  # noqa: E402
from bench_calibration import NOMINAL, PARAMS, TRAIN  # noqa: E402

TIE_M = 0.001
SIZES = (3, 4)
OUTCOMES = ("accepted", "cannot tell", "refused")
RULES = ("old", "folds", "margin", "new")


def load(bag: Path) -> Run:
    """One bag decoded once into wheel steps, with its ground truth."""
    steps = batch.wheel_steps(bagreadings.read_joint_states(bag), odometry_settings(PARAMS))
    return Run(bag.name, steps, poses.read_trajectory(bag, "/ground_truth/pose"))


def experiments() -> dict[str, list[Path]]:
    """The training runs' bags by experiment (``kind/id``)."""
    out = bench_calibration.bags()
    groups: dict[str, list[Path]] = {}
    for bag in sorted(p for p in out.glob("*_run-*") if p.is_dir()):
        kind, exp, _ = bag.name.split("_")
        groups.setdefault(f"{kind}/{exp}", []).append(bag)
    return groups


@dataclass
class Tally:
    """Subsets by held-out truth and by each rule's outcome."""

    subsets: int = 0
    truth: dict[str, int] = field(default_factory=lambda: dict.fromkeys(
        ("better", "tie", "worse"), 0))
    outcome: dict[str, dict[str, int]] = field(default_factory=dict)
    false_refusal: dict[str, int] = field(default_factory=dict)
    false_acceptance: dict[str, int] = field(default_factory=dict)
    examples: list[str] = field(default_factory=list)
    leverage: list[float] = field(default_factory=list)  # folds that pass the other tests

    def add(self, other: Tally) -> None:
        self.subsets += other.subsets
        self.leverage += other.leverage
        for k, v in other.truth.items():
            self.truth[k] += v
        for rule, counts in other.outcome.items():
            mine = self.outcome.setdefault(rule, dict.fromkeys(OUTCOMES, 0))
            for k, v in counts.items():
                mine[k] += v
            self.false_refusal[rule] = (self.false_refusal.get(rule, 0)
                                        + other.false_refusal.get(rule, 0))
            self.false_acceptance[rule] = (self.false_acceptance.get(rule, 0)
                                           + other.false_acceptance.get(rule, 0))


def outcome(rule: str, runs: Sequence[Run], results: Sequence[crossval.HeldOut],
            shapes: Sequence[determinacy.Shape], in_sample: Sequence[float]) -> str:
    """What calibrate does with these runs under ``rule``."""
    if rule == "old":
        c = crossval.check(results)
        return "accepted" if c is not None and c.better else "refused"
    v = crossval.judge(runs, results, NOMINAL, in_sample if rule in ("margin", "new") else (),
                       shapes=shapes,
                       max_leverage=determinacy.MAX_LEVERAGE if rule == "new" else math.inf)
    assert v is not None
    if v.cannot_tell:
        return "cannot tell"
    return "accepted" if v.better else "refused"


def judge_experiment(job: tuple[str, list[Path], tuple[str, ...], tuple[int, ...]]
                     ) -> tuple[str, Tally]:
    """Every subset of one experiment: held-out truth and each rule's verdict."""
    name, bags, rules, sizes = job
    runs = [load(b) for b in bags]
    shapes = [determinacy.shape(r, NOMINAL, lever=True) for r in runs]
    fits: dict[tuple[str, ...], calibration.Fit] = {}

    def fit(training: Sequence[Run]) -> calibration.Fit:
        key = tuple(r.name for r in training)
        if key not in fits:
            fits[key] = bench_calibration.product(training)
        return fits[key]

    tally = Tally()
    for rule in rules:
        tally.outcome[rule] = dict.fromkeys(OUTCOMES, 0)
        tally.false_refusal[rule] = tally.false_acceptance[rule] = 0
    for size in sizes:
        for chosen in itertools.combinations(range(len(runs)), size):
            others = [i for i in range(len(runs)) if i not in chosen]
            if not others:
                continue
            sub = [runs[i] for i in chosen]
            found = fit(sub)
            worst_cal = max(judgment(runs[i], found.geometry, found.mount).error for i in others)
            in_sample = [judgment(r, found.geometry, found.mount).error for r in sub]
            worst_nom = max(judgment(runs[i], NOMINAL, found.mount).error for i in others)
            lever = bench_calibration.lever_rule(sub).lever
            chosen_shapes = [dataclasses.replace(shapes[i], lever=lever) for i in chosen]
            truth = ("tie" if abs(worst_cal - worst_nom) <= TIE_M
                     else "better" if worst_cal < worst_nom else "worse")
            tally.subsets += 1
            tally.truth[truth] += 1
            results = crossval.held_out(sub, NOMINAL, fitter=fit)
            for k, i in enumerate(chosen):
                training = [s for j, s in enumerate(chosen_shapes) if j != k]
                if not (determinacy.coverage(training).reason or determinacy.judges(shapes[i])):
                    tally.leverage.append(determinacy.leverage(training, chosen_shapes[k]))
            for rule in rules:
                got = outcome(rule, sub, results, chosen_shapes, in_sample)
                tally.outcome[rule][got] += 1
                false = ((truth == "better" and got == "refused")
                         or (truth == "worse" and got == "accepted"))
                if truth == "better" and got == "refused":
                    tally.false_refusal[rule] += 1
                if truth == "worse" and got == "accepted":
                    tally.false_acceptance[rule] += 1
                if false and rule == rules[-1]:
                    tally.examples.append(
                        f"  {rule} {name} runs {','.join(str(i + 1) for i in chosen)}: "
                        f"{got}, held out worst {worst_nom:.4f} nominal -> {worst_cal:.4f} m")
    return name, tally


def row(label: str, t: Tally, rules: Sequence[str]) -> str:
    lev = (f"{min(t.leverage):5.2f}-{max(t.leverage):5.2f}" if t.leverage else f"{'-':>11s}")
    line = (f"{label:24s} {t.subsets:4d} {t.truth['better']:4d} {t.truth['tie']:4d} "
            f"{t.truth['worse']:4d} {lev}")
    for rule in rules:
        o = t.outcome[rule]
        line += (f" | {o['accepted']:4d} {o['cannot tell']:4d} {o['refused']:4d} "
                 f"{t.false_refusal[rule]:4d} {t.false_acceptance[rule]:4d}")
    return line


def main(argv: Sequence[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rule", choices=(*RULES, "all"), default="all",
                    help="which verdict to count (old: every fold, the rule at 13dd1c3; "
                    "folds: the folds that can judge, no margin; margin: with the margin, "
                    "no leverage test, the rule at 1bec3f3; new: the product's)")
    ap.add_argument("--jobs", type=int, default=2, help="processes, 1 or 2 (default 2)")
    ap.add_argument("--quick", action="store_true",
                    help="the squares' 3-run subsets only (the test's run)")
    args = ap.parse_args(argv)
    if not (TRAIN / "to_rosbag2.py").exists():
        print(f"skipped: {TRAIN} is not here")
        return 0
    rules = RULES if args.rule == "all" else (args.rule,)
    sizes = (3,) if args.quick else SIZES
    groups = experiments()
    if args.quick:
        groups = {k: v for k, v in groups.items() if k.startswith("square/")}
    jobs = [(name, bags, rules, sizes) for name, bags in groups.items()
            if len(bags) > min(sizes)]
    for name, bags in groups.items():
        if len(bags) <= min(sizes):
            print(f"{name}: {len(bags)} run(s), no subset of {min(sizes)} with a run left to "
                  "judge it")
    with multiprocessing.get_context("fork").Pool(max(1, min(2, args.jobs))) as pool:
        done = dict(pool.imap_unordered(judge_experiment, jobs))
    print(f"\nEvery {'- and '.join(map(str, sizes))}-run subset of an experiment, judged on "
          f"its other runs (worst whole-trajectory error, the one judge; tie within "
          f"{1000 * TIE_M:g} mm)")
    head = (f"{'experiment':24s} {'sets':>4s} {'bet.':>4s} {'tie':>4s} {'wor.':>4s} "
            f"{'leverage':>11s}")
    for rule in rules:
        head += f" | {rule + ': acc':>9s} {'?':>4s} {'ref':>4s} {'FR':>4s} {'FA':>4s}"
    print(head)
    total, halves = Tally(), {"June 2020": Tally(), "December 2020": Tally()}
    for name in groups:
        if name in done:
            print(row(name, done[name], rules))
            total.add(done[name])
            halves["June 2020" if name.split("/")[1][2:4] == "06" else "December 2020"].add(
                done[name])
    for label, half in halves.items():
        if half.subsets:
            print(row(label, half, rules))
    print(row("ALL", total, rules))
    print("acc: block printed without warning; ?: cannot tell (block with a warning); ref: "
          "refused (no block); FR: false refusals (held out better, refused); FA: false "
          "acceptances (held out worse, accepted); leverage: range over the folds that pass "
          f"the other tests (new leaves out those above {determinacy.MAX_LEVERAGE:g})")
    for rule in rules:
        better = max(total.truth["better"], 1)
        print(f"{rule}: false refusals {total.false_refusal[rule]} of {total.subsets} subsets "
              f"({100 * total.false_refusal[rule] / max(total.subsets, 1):.1f} %; "
              f"{100 * total.false_refusal[rule] / better:.1f} % of the "
              f"{total.truth['better']} held out better), false acceptances "
              f"{total.false_acceptance[rule]}, cannot tell {total.outcome[rule]['cannot tell']}")
    examples = [e for t in done.values() for e in t.examples]
    if examples:
        print(f"false verdicts of the {rules[-1]} rule:")
        print("\n".join(examples[:40]))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
