"""Is a calibration any good on runs it was not fitted to? Held-out checks and a bootstrap.

Pure Python + numpy. A fit always looks better on the runs it was fitted to; what a
user needs is the error on the next run. :func:`held_out` fits on all runs but one
group (a run: leave-one-run-out; an experiment: leave-one-experiment-out) and measures
the group left out, for every group; :func:`check` compares that with the nominal
geometry on the same runs, the test ``calibrate`` applies to itself before it
recommends anything. Both are measured by the one judge of a fit
(:func:`~diffdrive_odom.core.evaluation.judge.judgment`: the whole trajectory against the
reference moved onto base_link, and its end), each with the mount the fold's own fit
found (the reference's mount is not what is judged: nominal and calibrated share it).

The geometry's uncertainty is a bootstrap over runs (Efron): refit on runs drawn with
replacement, ``B`` times; the spread of the refits is what another set of runs of the
same robot would give, run-to-run differences included, which the Jacobian of one
fit does not see. Fewer than 3 runs give no sigma (with 2, every resample is one of the
two runs or both: the spread says nothing); a resample of fewer than 2 distinct runs is
skipped (one spin on the spot does not determine the separation alone).

A bootstrap over one session's runs cannot see what changes between sessions (tyres,
floor, the kind of motion), and the geometry a user fits is applied on other days.
The printed sigma therefore adds, in quadrature, a drift between sessions of
``SESSION_DRIFT_RATIO`` of each value (chosen on the OptiOdom robot's June 2020
experiments by :func:`drift_ratio`, checked on the December 2020 / January 2021 ones:
``bench/bench_calibration.py``) (:func:`with_drift`): sigma^2 = sigma_bootstrap^2
+ (ratio * value)^2. The ratio is a method-of-moments estimate over pairs of
experiments (:func:`drift_ratio`; DerSimonian and Laird, "Meta-analysis in clinical
trials", the between-study variance): what their fits differ by beyond both bootstraps.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Hashable, Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from diffdrive_odom.core.evaluation import calibration, determinacy
from diffdrive_odom.core.evaluation.judge import Judgment, judgment
from diffdrive_odom.core.evaluation.recorded_run import Run, values_of
from diffdrive_odom.core.geometry.kinematics import Geometry
from diffdrive_odom.core.geometry.mount import Mount
from diffdrive_odom.core.uncertainty.noise import SESSION_DRIFT_RATIO

FloatArray = npt.NDArray[np.float64]
Fitter = Callable[[Sequence[Run]], "calibration.Fit"]

BOOTSTRAP_RUNS = 20
MIN_RUNS_FOR_SIGMA = 3
SEED = 16  # fixed: the same runs print the same sigma


def default_fitter(nominal: Geometry) -> Fitter:
    """:func:`calibration.fit` with its defaults (the whole trajectory, the mount's yaw)."""
    return lambda runs: calibration.fit(runs, nominal, figures=False)


@dataclass(frozen=True)
class HeldOut:
    """One run judged with a geometry fitted without it (``geometry`` None: none possible).

    ``mount``: the one the fold's fit found (None: none), which judges nominal too.
    """

    run: str
    group: Hashable
    geometry: Geometry | None
    mount: Mount | None
    nominal: Judgment
    held_out: Judgment | None


def held_out(runs: Sequence[Run], nominal: Geometry, groups: Sequence[Hashable] | None = None,
             fitter: Fitter | None = None) -> list[HeldOut]:
    """For each group: fit on the other groups, measure this group's runs.

    ``groups`` labels each run (default: every run its own group, leave-one-run-out).
    With a single group nothing can be held out: ``geometry`` is None.
    """
    labels: Sequence[Hashable] = list(range(len(runs))) if groups is None else groups
    fit = fitter or default_fitter(nominal)
    out = []
    for g in dict.fromkeys(labels):
        rest = [r for r, lab in zip(runs, labels, strict=True) if lab != g]
        found = fit(rest) if rest else None
        for r, lab in zip(runs, labels, strict=True):
            if lab != g:
                continue
            if found is None:
                out.append(HeldOut(r.name, g, None, None, judgment(r, nominal), None))
            else:
                out.append(HeldOut(r.name, g, found.geometry, found.mount,
                                   judgment(r, nominal, found.mount),
                                   judgment(r, found.geometry, found.mount)))
    return out


@dataclass(frozen=True)
class Check:
    """Held-out mean of the judge's figure against nominal's on the same runs [m]."""

    runs: int
    nominal: float
    held_out: float

    @property
    def better(self) -> bool:
        """The held-out whole-trajectory error below nominal's."""
        return self.held_out < self.nominal


def check(results: Sequence[HeldOut]) -> Check | None:
    """Summarise :func:`held_out`; None when no run could be held out."""
    done = [(h.nominal, h.held_out) for h in results if h.held_out is not None]
    if not done:
        return None
    return Check(len(done), float(np.mean([n.error for n, _ in done])),
                 float(np.mean([h.error for _, h in done])))


@dataclass(frozen=True)
class Verdict:
    """The held-out check over the folds that count, what was left out and why, the margin.

    ``check`` is None when no fold counts. ``margin`` [m] is the noise of the held-out
    mean error: the RMS of the judge's figure the full fit leaves on its own runs (those
    whose end depends on the geometry; what no geometry explains: slip, the runs'
    scatter) over the square root of the folds counted. A change within it cannot tell
    better from worse. ``every_fold`` is the check over all folds, the rule before.
    """

    check: Check | None
    every_fold: Check
    left_out: tuple[tuple[str, str], ...]  # (held-out run, why its fold cannot judge)
    margin: float = 0.0

    @property
    def within_margin(self) -> bool:
        """The held-out change of the mean error is within the margin."""
        c = self.check
        return c is not None and abs(c.held_out - c.nominal) <= self.margin

    @property
    def cannot_tell(self) -> bool:
        """No fold can judge, or the change is within the margin: the block with a warning."""
        return self.check is None or self.within_margin

    @property
    def better(self) -> bool:
        """Better than nominal beyond the margin: the block without a warning."""
        return self.check is not None and not self.within_margin and self.check.better


def judge(runs: Sequence[Run], results: Sequence[HeldOut], nominal: Geometry,
          in_sample: Sequence[float] = (), groups: Sequence[Hashable] | None = None,
          shapes: Sequence[determinacy.Shape] | None = None,
          max_leverage: float = determinacy.MAX_LEVERAGE) -> Verdict | None:
    """:func:`check` over the folds that can judge the fit (:func:`fold_reasons`), with its margin.

    ``results`` from :func:`held_out` with the same ``groups``; ``in_sample``: the full
    fit's judge figure on each run, in order (the margin; empty: none);
    ``shapes`` (one per run, :func:`determinacy.shape`) when the caller has them. None
    when no run could be held out.
    """
    every = check(results)
    if every is None:
        return None
    labels: Sequence[Hashable] = list(range(len(runs))) if groups is None else groups
    shown = list(shapes) if shapes is not None else [determinacy.shape(r, nominal)
                                                     for r in runs]
    reasons = fold_reasons(shown, labels, max_leverage)
    # held_out's order: group by group, each group's runs in their order
    order = [i for g in dict.fromkeys(labels) for i, lab in enumerate(labels) if lab == g]
    kept, left = [], []
    for h, i in zip(results, order, strict=True):
        if h.held_out is None:
            continue
        if reasons[i]:
            left.append((h.run, reasons[i]))
        else:
            kept.append(h)
    judging = ([e for e, s in zip(in_sample, shown, strict=True) if not determinacy.judges(s)]
               if len(in_sample) else [])
    noise = math.sqrt(float(np.mean(np.square(judging)))) if judging else 0.0
    margin = noise / math.sqrt(len(kept)) if kept else 0.0
    return Verdict(check(kept), every, tuple(left), margin)


def fold_reasons(shapes: Sequence[determinacy.Shape], groups: Sequence[Hashable] | None = None,
                 max_leverage: float = determinacy.MAX_LEVERAGE) -> list[str]:
    """Per run (in order): why its held-out fold cannot judge a fit ("" when it can).

    A fold counts when its training runs (the other groups) determine the geometry
    (:func:`determinacy.coverage`), its held-out run's end depends on it
    (:func:`determinacy.judges`) and lies within what the training runs determine
    (:func:`determinacy.extrapolates`, ``max_leverage``; inf: not asked). It depends on
    the runs' shapes alone, not on the fit judged. ``groups`` as for :func:`held_out`.
    """
    labels: Sequence[Hashable] = list(range(len(shapes))) if groups is None else groups
    training: dict[Hashable, list[determinacy.Shape]] = {
        g: [s for s, lab in zip(shapes, labels, strict=True) if lab != g]
        for g in dict.fromkeys(labels)}
    lacks = {g: determinacy.coverage(t).reason for g, t in training.items()}
    return [f"its training runs do not determine the geometry: {lacks[lab]}" if lacks[lab]
            else determinacy.judges(s) or determinacy.extrapolates(training[lab], s, max_leverage)
            for s, lab in zip(shapes, labels, strict=True)]


def bootstrap(runs: Sequence[Run], nominal: Geometry, resamples: int = BOOTSTRAP_RUNS,
              seed: int = SEED, fitter: Callable[[Sequence[float]], FloatArray] | None = None
              ) -> FloatArray | None:
    """Covariance of the fitted values; None below 3 runs.

    ``fitter`` maps per-run weights to fitted values (default: :func:`calibration.fit`'s
    (left radius, right radius, separation) [m], 3x3; ``calibrate``'s: its objective's
    with the mount, :meth:`~.objective.Objective.weighted`).
    """
    if len(runs) < MIN_RUNS_FOR_SIGMA:
        return None

    def default(weights: Sequence[float]) -> FloatArray:
        return values_of(calibration.fit(runs, nominal, weights=weights,
                                         figures=False).geometry)

    refit = fitter or default
    rng = np.random.default_rng(seed)
    values: list[FloatArray] = []
    while len(values) < resamples:
        counts = np.bincount(rng.integers(0, len(runs), len(runs)), minlength=len(runs))
        if np.count_nonzero(counts) < 2:
            continue
        values.append(refit(counts.astype(np.float64).tolist()))
    return np.asarray(np.cov(np.array(values).T), dtype=np.float64)


def stddev_ratios(values: FloatArray, covariance: FloatArray) -> tuple[float, float]:
    """``(wheel_radius_stddev_ratio, wheel_separation_stddev_ratio)`` from a covariance.

    The node models each radius as independent with one ratio: the larger of the two
    wheels' relative sigmas (the conservative side).
    """
    rel = np.sqrt(np.diag(covariance)) / values
    return float(max(rel[0], rel[1])), float(rel[2])


def with_drift(values: FloatArray, covariance: FloatArray,
               ratio: float = SESSION_DRIFT_RATIO) -> FloatArray:
    """The printed covariance: the bootstrap's plus ``(ratio * value)^2`` on the diagonal.

    The drift of each value between sessions is taken independent (its cause differs:
    each tyre's wear, the contact patches' width on another floor).
    """
    return np.asarray(covariance + np.diag((ratio * np.asarray(values)) ** 2),
                      dtype=np.float64)


def drift_ratio(values: Sequence[FloatArray], covariances: Sequence[FloatArray]) -> float:
    """Relative drift between experiments beyond their own sigmas (method of moments).

    Over every pair (a, b) and parameter: ((v_a - v_b) / mean)^2 - (s_a / v_a)^2 -
    (s_b / v_b)^2 estimates ratio^2; the mean over all of them, floored at 0, is
    returned as a ratio. One ratio for all three values: three experiments give too few
    pairs for one each.
    """
    terms: list[float] = []
    for i in range(len(values)):
        for j in range(i + 1, len(values)):
            va, vb = np.asarray(values[i]), np.asarray(values[j])
            rel = (va - vb) / ((va + vb) / 2)
            own = (np.diag(covariances[i]) / va ** 2) + (np.diag(covariances[j]) / vb ** 2)
            terms += (rel ** 2 - own).tolist()
    if not terms:
        raise ValueError("drift_ratio needs two or more experiments")
    return float(np.sqrt(max(0.0, float(np.mean(terms)))))


def pair_z(values_a: FloatArray, printed_a: FloatArray, values_b: FloatArray,
           covariance_b: FloatArray) -> FloatArray:
    """``|v_a - v_b|`` in units of a's printed sigma with b's own (bootstrap) sigma added.

    How the printed sigma is checked: b is another experiment's fit, its geometry up to
    its own noise; if a's sigma covers b's geometry, ``|z| < 1`` about 68 % of the time.
    """
    diff = np.abs(np.asarray(values_a) - np.asarray(values_b))
    return np.asarray(diff / np.sqrt(np.diag(printed_a) + np.diag(covariance_b)),
                      dtype=np.float64)
