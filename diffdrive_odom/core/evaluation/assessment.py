"""``calibrate``'s whole judgment of its fit in one place: mount, objective, fit, verdict, sigma.

Pure Python + numpy/scipy. :func:`assess` is what ``diffdrive-odom calibrate`` does with
its runs (the command only reads bags and prints), and what the benches measure it by:

1. the reference's mount (:mod:`~diffdrive_odom.core.geometry.mount`): given, or fitted
   beside the geometry, its yaw always and its lever arm where the runs determine it
   (:func:`~diffdrive_odom.core.evaluation.determinacy.lever_reason`; otherwise held at 0
   and said why);
2. the objective, chosen held out (:mod:`~diffdrive_odom.core.evaluation.objective`);
3. the fit, its held-out check and verdict (:mod:`~diffdrive_odom.core.evaluation.crossval`),
   all by the one judge (:mod:`~diffdrive_odom.core.evaluation.judge`);
4. the bootstrap's sigma, of the geometry and the mount, and the printed sigma (with the
   drift between sessions);
5. whether the params block may be printed: not when the nominal geometry does better
   held out (:attr:`Assessment.refused`), nor when a value moved more than
   :data:`IMPLAUSIBLE_RATIO` from nominal and more than :data:`IMPLAUSIBLE_SIGMAS` of
   its printed sigma (:attr:`Assessment.implausible`: a wheel does not change by that
   much; a wrong nominal ``wheel_radius`` or ``ticks_per_revolution``, or a mount the
   runs do not determine, does), unless forced.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from diffdrive_odom.core.evaluation import calibration, crossval, determinacy, objective
from diffdrive_odom.core.evaluation.calibration import MountRule, MountSpec, always
from diffdrive_odom.core.evaluation.recorded_run import Run, values_of
from diffdrive_odom.core.geometry.kinematics import Geometry
from diffdrive_odom.core.geometry.mount import Mount
from diffdrive_odom.core.uncertainty.noise import SESSION_DRIFT_RATIO

FloatArray = npt.NDArray[np.float64]

IMPLAUSIBLE_RATIO = 0.10  # a value this far from nominal (relative) ...
IMPLAUSIBLE_SIGMAS = 5.0  # ... and this many printed sigmas away is named, held back
VALUE_NAMES = ("left wheel radius", "right wheel radius", "wheel separation")


@dataclass(frozen=True)
class MountFound:
    """The reference's mount as the fit used it, and how it is known.

    ``sigma``: 1-sigma of x, y [m] and yaw [rad] (NaN where held), from the bootstrap
    over runs (``source``) or, below 3 runs, from the fit's Jacobian; ``lever_held``:
    why the lever arm was held at 0 ("" when fitted, or given).
    """

    mount: Mount
    given: bool
    sigma: tuple[float, float, float]
    source: str
    lever_held: str = ""


@dataclass(frozen=True)
class Implausible:
    """A fitted value that moved too far to be the wheels (:data:`IMPLAUSIBLE_RATIO`)."""

    name: str
    nominal: float
    fitted: float
    sigma: float | None  # the printed 1-sigma (None: too few runs for one)

    @property
    def ratio(self) -> float:
        """The fitted value over the nominal one."""
        return self.fitted / self.nominal


@dataclass(frozen=True)
class Assessment:
    """What :func:`assess` found (see the module)."""

    choice: objective.Choice
    fit: calibration.Fit
    verdict: crossval.Verdict | None
    covariance: FloatArray | None  # the bootstrap's, of the three values and the mount
    printed: FloatArray | None  # 3x3: the geometry's, with the drift between sessions
    mount: MountFound
    implausible: tuple[Implausible, ...]
    spread_folds: tuple[crossval.HeldOut, ...]  # whose geometries fit rotation_noise_k
    coverage: determinacy.Coverage  # whether all the runs determine the geometry
    weakest: FloatArray  # the combination of the three values they see least (unit)

    @property
    def refused(self) -> bool:
        """The nominal geometry did better on held-out runs, beyond the margin."""
        v = self.verdict
        return v is not None and not v.cannot_tell and not v.better

    @property
    def withheld(self) -> bool:
        """The params block is printed only when forced."""
        return self.refused or bool(self.implausible)

    @property
    def geometry_covariance(self) -> FloatArray | None:
        """The bootstrap's 3x3 covariance of the three values [m^2]."""
        return None if self.covariance is None else self.covariance[:3, :3]

    @property
    def ratios(self) -> tuple[float, float] | None:
        """The block's ``wheel_radius_stddev_ratio``, ``wheel_separation_stddev_ratio``."""
        if self.printed is None:
            return None
        return crossval.stddev_ratios(self.fit.values, self.printed)


def mount_spec(runs: Sequence[Run], nominal: Geometry, given: Mount | None
               ) -> tuple[MountSpec, str, list[determinacy.Shape], MountRule]:
    """How the fit treats the mount: its spec, why the lever arm is held, shapes, a rule.

    The rule says how a subset of the runs is fitted (a held-out fold's, a bootstrap
    resample's); the reason is "" when the lever arm is fitted. The shapes are taken at
    the mount a first fit finds (the lever arm's information is taken in base_link, so
    where the reference is mounted does not change them). A subset that does not
    determine the lever arm all the runs determine fits the yaw with the lever arm held
    where that first fit put it.
    """
    if given is not None:
        spec = MountSpec(given)
        return spec, "", [determinacy.shape(r, nominal, given) for r in runs], always(spec)
    free = MountSpec(lever=True)
    first = calibration.fit(runs, nominal, mount=free, figures=False).mount
    shapes = [determinacy.shape(r, nominal, first, lever=True) for r in runs]
    held = determinacy.lever_reason(shapes)
    if held:
        yaw_only = calibration.fit(runs, nominal, figures=False).mount
        shapes = [determinacy.shape(r, nominal, yaw_only) for r in runs]
        return calibration.YAW_ONLY, held, shapes, always(calibration.YAW_ONLY)
    by_run = {id(r): s for r, s in zip(runs, shapes, strict=True)}
    kept = MountSpec(held_lever=(first.x, first.y))

    def rule(subset: Sequence[Run]) -> MountSpec:
        return kept if determinacy.lever_reason([by_run[id(r)] for r in subset]) else free

    return free, "", shapes, rule


def assess(runs: Sequence[Run], nominal: Geometry, *, given: Mount | None = None,
           objective_name: str | None = None, end_weight: float | None = None,
           drift: float = SESSION_DRIFT_RATIO) -> Assessment:
    """``calibrate``'s steps on ``runs`` (see the module).

    ``objective_name`` / ``end_weight`` as ``--objective`` / ``--end-weight`` (None:
    chosen held out); ``given``: ``--reference-offset``; ``drift``: ``--session-drift``.
    """
    spec, lever_held, shapes, rule = mount_spec(runs, nominal, given)
    judged = shapes if len(runs) >= 2 else None
    chosen = objective.chosen_by(objective_name, end_weight, runs, nominal, judged, rule)
    goal = chosen.objective
    result = goal.fit(runs, nominal, mount=spec)
    in_sample = [r.after.error for r in result.runs]
    folds = chosen.folds() or tuple(crossval.held_out(runs, nominal,
                                                      fitter=goal.fitter(nominal, rule)))
    verdict = (crossval.judge(runs, folds, nominal, in_sample, shapes=judged)
               if judged else None)
    spread = goal.spread  # whose refits give the sigma and rotation_noise_k
    spread_folds = (folds if spread == goal else chosen.folds(spread)
                    or tuple(crossval.held_out(runs, nominal,
                                               fitter=spread.fitter(nominal, rule))))
    covariance = crossval.bootstrap(runs, nominal, fitter=spread.weighted(
        runs, nominal, rule, result.mount.yaw))
    printed = (None if covariance is None
               else crossval.with_drift(result.values, covariance[:3, :3], drift))
    return Assessment(chosen, result, verdict, covariance, printed,
                      _mount_found(result, spec, covariance, lever_held),
                      implausible(nominal, result.values, printed), tuple(spread_folds),
                      determinacy.coverage(shapes), determinacy.weakest(shapes))


def reference_mount(runs: Sequence[Run], nominal: Geometry, given: Mount | None) -> MountFound:
    """The mount alone, as :func:`assess` finds it (UMBmark's reference ends need it)."""
    spec, lever_held, _, _ = mount_spec(runs, nominal, given)
    return _mount_found(calibration.fit(runs, nominal, mount=spec, figures=False), spec, None,
                        lever_held)


def _mount_found(result: calibration.Fit, spec: MountSpec, covariance: FloatArray | None,
                 lever_held: str) -> MountFound:
    if spec.given is not None:
        return MountFound(spec.given, True, (math.nan,) * 3, "given")
    if result.ends_only:  # the end poses hold the whole trajectory's mount
        return MountFound(result.mount, False, (math.nan,) * 3,
                          "held where the whole trajectory's fit puts it (the end poses "
                          "alone do not fit it)", lever_held)
    fitted = (result.lever_fitted, result.lever_fitted, result.yaw_fitted)
    if covariance is not None:
        boot = np.sqrt(np.diag(covariance)[3:6])
        sigma = tuple(float(s) if f else math.nan for s, f in zip(boot, fitted, strict=True))
        source = f"bootstrap over runs ({crossval.BOOTSTRAP_RUNS} resamples)"
    else:
        sigma = result.mount_sigma
        source = (f"the fit's residuals (a bootstrap needs {crossval.MIN_RUNS_FOR_SIGMA} "
                  "or more runs)")
    return MountFound(result.mount, False, (sigma[0], sigma[1], sigma[2]), source, lever_held)


def implausible(nominal: Geometry, values: FloatArray, printed: FloatArray | None
                ) -> tuple[Implausible, ...]:
    """The values more than 10 % from nominal and 5 printed sigmas (no sigma: 10 % alone)."""
    base = values_of(nominal)
    sigma = None if printed is None else np.sqrt(np.diag(printed))
    out = []
    for i, name in enumerate(VALUE_NAMES):
        moved = abs(float(values[i]) - float(base[i]))
        s = None if sigma is None else float(sigma[i])
        if moved > IMPLAUSIBLE_RATIO * float(base[i]) and (s is None
                                                           or moved > IMPLAUSIBLE_SIGMAS * s):
            out.append(Implausible(name, float(base[i]), float(values[i]), s))
    return tuple(out)
