"""Is the propagated covariance consistent with real runs? Final-pose NEES and a noise fit.

Pure Python + numpy/scipy (no rclpy, no bags). For a recorded run with a reference
(:class:`~diffdrive_odom.core.evaluation.recorded_run.Run`) and a geometry, the final
pose's error against the reference and the covariance the node would publish there come
from the fast lane's array form of the propagation
(:func:`diffdrive_odom.core.uncertainty.fastcov.bulk_covariance`, tested equal to the
node's per-step one). The covariance is linear in its noise parameters, so each run is
propagated once per term with a unit parameter (:class:`RunTerms`); any ``k``,
``k_rot`` and geometry ratios then cost a 3x3 sum.

The reference is moved onto base_link by its mount
(:mod:`~diffdrive_odom.core.geometry.mount`) before the final pose is compared, as the
fit does. It has an error of its own (a motion capture's noise):
:data:`REFERENCE_ERROR` (1 mm and 0.5 deg, 1 sigma) is added to the covariance before
the NEES is taken, and named where it is printed; its heading error moves a base_link
seen through a lever arm sideways (:func:`reference_error`).

:func:`fit_noise` chooses the random terms by maximum likelihood of the runs' final-pose
errors (each run one zero-mean Gaussian draw of its covariance), the others held fixed;
a parameter whose likelihood is highest at 0 is returned as 0, and the likelihood-ratio
statistic against 0 is returned with it, so a caller can say how much the data want it.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy import optimize

from diffdrive_odom.core.bulk.batch import integrate_steps
from diffdrive_odom.core.evaluation import calibration, leftout
from diffdrive_odom.core.evaluation.recorded_run import Run
from diffdrive_odom.core.geometry.integration import chord_array
from diffdrive_odom.core.geometry.kinematics import Geometry, body_increment
from diffdrive_odom.core.geometry.mount import AXLE, Mount
from diffdrive_odom.core.geometry.se2 import wrap_angles
from diffdrive_odom.core.uncertainty.fastcov import (
    BulkModel,
    BulkSteps,
    CovarianceState,
    bulk_covariance,
)
from diffdrive_odom.core.uncertainty.noise import NoiseModel
from diffdrive_odom.core.uncertainty.propagation import ZERO3, geometry_term

FloatArray = npt.NDArray[np.float64]

# The motion capture's own error (1 sigma): 1 mm in x and y, 0.5 deg in heading.
REFERENCE_POSITION_M, REFERENCE_HEADING_DEG = 0.001, 0.5
REFERENCE_ERROR: FloatArray = np.diag([REFERENCE_POSITION_M**2, REFERENCE_POSITION_M**2,
                                       math.radians(REFERENCE_HEADING_DEG) ** 2])
CHI2_3_95 = 7.815  # chi-square (3 dof) 95 % quantile
CHI2_3_999 = 16.266  # 99.9 %
# Likelihood-ratio statistic above which a parameter at a boundary (0) is wanted by the
# data at 5 %: half chi-square(1)'s mass sits at 0, so its 90 % quantile.
LR_5_PERCENT = 2.706


@dataclass(frozen=True)
class RunTerms:
    """A run's final-pose error and its covariance per unit of each noise parameter."""

    name: str
    error: FloatArray  # (3,): odometry minus reference (x, y [m], heading [rad])
    wheel: FloatArray  # 3x3 P for k_left = k_right = 1 m
    rotation: FloatArray  # 3x3 P for k_rot = 1 rad
    sensitivity: FloatArray  # 3x3 d pose / d(ln r_l, ln r_r, ln b)
    turned: float  # total |dtheta| [rad]
    distance: float  # total |ds| [m]


def run_terms(run: Run, geometry: Geometry, max_gap: float = 0.5,
              mount: Mount = AXLE) -> RunTerms:
    """Integrate ``run`` with ``geometry``; its final error and unit covariance terms.

    The reference moved onto base_link by ``mount``; the error with the run's slip
    events bridged (:mod:`~.leftout`, as the fit leaves them out); the covariance over
    every step (a slip's few steps change it little).
    """
    prepared = calibration.prepare(run, max_gap, ends_only=True)
    steps = run.steps
    x, y, th = integrate_steps(steps, geometry)
    ex, ey, eth = (leftout.integrate(steps, geometry, prepared.bridges, mount)
                   if prepared.bridges else (x, y, th))
    ref = mount.base_motions(prepared.reference[-1:])[0]
    i = int(prepared.index[-1])
    error = np.array([ex[i] - ref[0], ey[i] - ref[1],
                      float(wrap_angles(eth[i:i + 1] - ref[2])[0])])
    d_left, d_right = steps.d_left[:i + 1], steps.d_right[:i + 1]
    ds, dth = body_increment(geometry, d_left, d_right)
    sinc_half, chord = chord_array(ds, dth)
    after = th[:i + 1]
    bulk = BulkSteps(dt=steps.dt[:i + 1], ds=ds, dtheta=dth, d_left=d_left, d_right=d_right,
                     sinc_half=sinc_half, chord=chord,
                     before=np.concatenate(([0.0], after[:-1])), after=after)
    start = CovarianceState(covariance=ZERO3, sensitivity=ZERO3, rates=())

    def end(noise: NoiseModel) -> tuple[FloatArray, FloatArray]:
        out = bulk_covariance(BulkModel(noise=noise, geometry=geometry, ticks_per_revolution=0.0,
                                        wheels_per_side=1, window=1), start, bulk)
        assert out is not None  # finite steps, unit noise
        return np.array(out.end.covariance), np.array(out.end.sensitivity)

    wheel, sensitivity = end(NoiseModel(1.0, 1.0, 0.0, 0.0, 0.0))
    rotation, _ = end(NoiseModel(0.0, 0.0, 0.0, 0.0, 1.0))
    return RunTerms(run.name, error, wheel, rotation, sensitivity,
                    float(np.abs(dth).sum()), float(np.abs(ds).sum()))


@dataclass(frozen=True)
class Noise:
    """The parameters the final-pose covariance depends on (the node's, by meaning)."""

    k: float  # wheel_noise_k_left = _right [m]
    k_rotation: float  # rotation_noise_k [rad]
    radius_ratio: float  # wheel_radius_stddev_ratio
    separation_ratio: float  # wheel_separation_stddev_ratio


def covariance(t: RunTerms, noise: Noise, reference: FloatArray = REFERENCE_ERROR
               ) -> FloatArray:
    """The published final-pose covariance for ``noise``, plus the reference's error."""
    geo = np.array(geometry_term(tuple(map(tuple, t.sensitivity)), noise.radius_ratio,
                                 noise.separation_ratio))
    out: FloatArray = noise.k * t.wheel + noise.k_rotation * t.rotation + geo + reference
    return out


def nees(t: RunTerms, noise: Noise, reference: FloatArray = REFERENCE_ERROR) -> float:
    """Normalised estimation error squared of the final pose (chi-square, 3 dof if consistent)."""
    return float(t.error @ np.linalg.solve(covariance(t, noise, reference), t.error))


def log_likelihood(terms: Sequence[RunTerms], noise: Noise,
                   reference: FloatArray = REFERENCE_ERROR) -> float:
    """Sum over runs of the Gaussian log density of the final error (constants dropped)."""
    total = 0.0
    for t in terms:
        c = covariance(t, noise, reference)
        sign, logdet = np.linalg.slogdet(c)
        if sign <= 0:
            return -math.inf
        total -= 0.5 * (logdet + float(t.error @ np.linalg.solve(c, t.error)))
    return total


def joint_log_likelihood(groups: Sequence[Sequence[RunTerms]], noise: Noise,
                         reference: FloatArray = REFERENCE_ERROR) -> float:
    """:func:`log_likelihood` with the geometry error one draw per group, not per run.

    The runs of one session share the robot's true geometry: their geometry parts are
    correlated, ``cov(e_i, e_j) = J_i S J_j^T``, and only the random terms (and the
    reference's error) are independent between runs. So what repeated runs share is
    told apart from how they scatter, which is what the random terms must explain.
    """
    vr, vb = noise.radius_ratio**2, noise.separation_ratio**2
    s = np.diag([vr, vr, vb])
    total = 0.0
    for ts in groups:
        e = np.concatenate([t.error for t in ts])
        js = np.vstack([t.sensitivity for t in ts])
        c = js @ s @ js.T
        for i, t in enumerate(ts):
            c[3 * i:3 * i + 3, 3 * i:3 * i + 3] += (noise.k * t.wheel
                                                    + noise.k_rotation * t.rotation + reference)
        sign, logdet = np.linalg.slogdet(c)
        if sign <= 0:
            return -math.inf
        total -= 0.5 * (logdet + float(e @ np.linalg.solve(c, e)))
    return total


def upper_bound(log_likelihood_of: Callable[[float], float], best: float,
                drop: float = LR_5_PERCENT) -> float:
    """The largest value whose likelihood ratio against ``best`` stays under ``drop``.

    A one-sided 95 % upper confidence bound for a parameter whose likelihood falls
    monotonically above ``best`` (searched by decades in 1/16 steps, up to 1 rad).
    """
    top = log_likelihood_of(best)
    value = max(best, 1e-10)
    while value < 1.0:
        nxt = value * 10 ** (1 / 16)
        if 2.0 * (top - log_likelihood_of(nxt)) > drop:
            return value
        value = nxt
    return value


@dataclass(frozen=True)
class NoiseFit:
    """What :func:`fit_noise` found: the noise, and the likelihood-ratio against 0 per term."""

    noise: Noise
    lr_k: float | None  # 2 (logL(fit) - logL(k = 0)); None when k was held fixed
    lr_rotation: float


GRID = (0.0, *(10.0 ** (e / 4.0) for e in range(-40, -3)))  # 0 and 1e-10 .. ~0.6


def fit_noise(terms: Sequence[RunTerms], fixed: Noise, *, fit_k: bool = False,
              reference: FloatArray = REFERENCE_ERROR) -> NoiseFit:
    """Maximum-likelihood ``k_rot`` (and ``k`` with ``fit_k``), the rest as in ``fixed``.

    A grid over 0 and decades in quarter steps, then a bounded refinement in the log of
    each parameter found above 0; a parameter whose best value is 0 stays 0.
    """
    def ll(k: float, kr: float) -> float:
        return log_likelihood(terms, Noise(k, kr, fixed.radius_ratio, fixed.separation_ratio),
                              reference)

    ks = GRID if fit_k else (fixed.k,)
    best = max(((ll(k, kr), k, kr) for k in ks for kr in GRID), key=lambda v: v[0])
    _, k, kr = best
    free = [i for i, v in enumerate((k, kr)) if v > 0.0 and (i == 1 or fit_k)]
    if free:
        x0 = np.log10([(k, kr)[i] for i in free])

        def neg(x: FloatArray) -> float:
            v = [k, kr]
            for j, i in enumerate(free):
                v[i] = 10.0 ** float(x[j])
            return -ll(v[0], v[1])

        sol = optimize.minimize(neg, x0, method="Nelder-Mead",
                                options={"xatol": 1e-3, "fatol": 1e-6})
        if -float(sol.fun) > best[0]:
            v = [k, kr]
            for j, i in enumerate(free):
                v[i] = 10.0 ** float(sol.x[j])
            k, kr = v
    top = ll(k, kr)
    lr_rot = 2.0 * (top - max(ll(kk, 0.0) for kk in ((k,) if not fit_k else (k, *GRID))))
    lr_k = None if not fit_k else 2.0 * (top - max(ll(0.0, r) for r in (kr, *GRID)))
    return NoiseFit(Noise(k, kr, fixed.radius_ratio, fixed.separation_ratio), lr_k,
                    max(lr_rot, 0.0))


def chi2_band(n: int, dof: int = 3) -> tuple[float, float]:
    """Two-sided 95 % band of the mean of ``n`` chi-square(``dof``) values (Wilson-Hilferty)."""
    total = dof * n
    c = 2.0 / (9.0 * total)
    lo, hi = (total * (1 - c + z * math.sqrt(c)) ** 3 / n for z in (-1.96, 1.96))
    return lo, hi


def held_out_terms(runs: Sequence[Run], fitted: Sequence[tuple[Geometry, Mount] | None],
                   max_gap: float = 0.5) -> list[RunTerms]:
    """Each run's terms with the geometry (and mount) fitted without it (None: skipped).

    The random terms are judged on runs the geometry was not fitted to: in-sample, the
    fit absorbs part of each run's own random error and the errors read too small.
    """
    return [run_terms(r, f[0], max_gap, f[1]) for r, f in zip(runs, fitted, strict=True)
            if f is not None]


def reference_error(position_m: float, heading_rad: float, mount: Mount = AXLE) -> FloatArray:
    """The reference's own error as base_link's covariance (1 sigma of each pose).

    ``position_m`` in x and y, ``heading_rad`` in the heading; seen through the mount's
    lever arm, the heading error also moves base_link by ``heading_rad`` times the lever.
    """
    position = position_m**2 + (heading_rad * mount.lever) ** 2
    return np.diag([position, position, heading_rad**2])
