"""Do a set of runs determine the geometry? The held-out verdict counts only folds that do.

Pure Python + numpy. A fold of the held-out check (:mod:`diffdrive_odom.core.evaluation.crossval`)
judges a geometry fitted on its training runs; when those runs cannot determine the
geometry, the fold's error says what the runs lack, not whether the fit is any good.
Per step the wheels give an arc length and a turn, two numbers for three values: a
motion with one wheel ratio (a line, a spin on the spot, a circle) leaves one
combination free, and only runs with different ratios pin down all three. Three ways a
set of runs fails, each named:

- too little travel: turns on the spot alone do not see the common scale of the radii
  and the separation (a spin's angle is ``(r_left + r_right) / b``);
- too little turning: straight lines alone do not see the separation;
- turning one way only: the fit's Jacobian sees the combination that a turn the other
  way brings out (Borenstein and Feng, "Measurement and correction of systematic
  odometry errors in mobile robots": a square's type A and type B errors are told apart
  only by squares driven both ways). Measured on the fit's own normal equations: the
  runs mirrored (left and right wheels swapped, the path reflected) give information
  ``M``, the runs themselves ``A`` (both with the reference's mount, the fit's
  nuisance, eliminated); the largest generalised eigenvalue of ``(M, A)`` is how much
  more strongly, at worst, the mirrored runs would see a combination of the three
  values. Balanced runs give about 1; on the OptiOdom runs (at the nominal geometry)
  circles or squares of one direction gave 770 to 2300, a single free path 15.

The reference's lever arm (its offset from the axle, :mod:`~diffdrive_odom.core.geometry.mount`)
is fitted only where the runs determine it (:func:`lever_reason`): a turn moves a
reference off the axle sideways, but a turn at one curvature, one way, moves it as a
slightly different geometry would. Measured as the worst factor by which freeing the
lever arm widens the geometry's variance (the largest generalised eigenvalue of the
geometry's information with the lever arm held and with it eliminated): circles and
squares both ways, free paths, lines with spins on the spot 1.0 to 2.9 on the OptiOdom
runs; squares one way (turned on the spot at the corners) 6.4 to 7.6; circles one way 96
to 135. :data:`MAX_LEVER_INFLATION` lies between (25, near their geometric mean). And
the lever arm must be seen at all: its 1-sigma, were the residuals 1 cm RMS
(:data:`LEVER_NOISE_M`), is 3 to 10 mm on those runs and 0.22 to 1.4 m on two straight
lines alone (a line does not turn the reference about the axle); :data:`MAX_LEVER_SIGMA_M`
lies between (0.05 m, near their geometric mean).

A fold also judges nothing when its held-out run ends in the same place whatever the
geometry (a turn on the spot): :func:`judges` asks that a 1 % change of the values move
the run's end by :data:`MIN_END_SHIFT_M` or more (turns on the spot: 1.4 mm; the
OptiOdom lines, circles and squares: 80 mm or more).

A fold also judges nothing when its held-out run's end is far more sensitive to the
geometry than its training runs are (:func:`extrapolates`): a fit matches the training
runs' residuals only up to what no geometry explains there (slip, the floor, the runs'
own scatter), and the held-out end moves by up to :func:`leverage` times that misfit
(``||G A^-1/2||``, ``G`` the held-out end's Jacobian, ``A`` the training runs' information,
both per relative change of the values, the start yaw eliminated). A straight
line judged by a fit to another line and spins on the spot: 4.9 to 7.4 on the OptiOdom
runs (its end drifts sideways with the square of the distance, a fit sees the mean of
it, the start yaw takes the linear part), so one line's own curvature, amplified, is
what the fold measures (it grows with the line's length, as the heading residuals weigh
less: simulated, 1 m 3.9, 2 m 6.1, 4 m 7.5; circles and squares: 1.0 to 2.1, a square
of 1, 2, 4 m: 1.7, 1.8, 2.0). :data:`MAX_LEVERAGE` was set
between the two on the June 2020 experiments (1.96 and 4.90: their geometric mean, 3.1,
rounded) and holds on the December ones (2.13 and 5.19).

The thresholds: :data:`MIN_TRAVEL_M` and :data:`MIN_TURN_RAD` are where a 1 % error of
the scale or of the separation moves a run by 10 mm or 0.9 deg, well above a motion
capture's own error (1 mm, 0.5 deg); :data:`MAX_MIRROR_RATIO` lies between the balanced
runs (1.0 to 1.3 on the OptiOdom experiments that turn both ways, 11 on its single
20 m free path, with the mount's yaw and lever arm eliminated) and those turning one way:
phil_train's three Vicon runs, all counter-clockwise, 56, where two fits of their
geometry (calibrate's and bench/anchor.py's) part by 3.7 % in the separation; the
OptiOdom circles or squares of one direction 770 to 2300. It was 100 before phil_train
was measured.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from diffdrive_odom.core.bulk.batch import integrate_steps
from diffdrive_odom.core.evaluation import calibration
from diffdrive_odom.core.evaluation.recorded_run import Run, values_of, with_values
from diffdrive_odom.core.geometry.kinematics import Geometry, body_increment
from diffdrive_odom.core.geometry.mount import AXLE, Mount

FloatArray = npt.NDArray[np.float64]

MIN_TRAVEL_M = 1.0  # arc length driven, all runs together
MIN_TURN_RAD = math.pi / 2  # heading span of the run that turns most
MAX_MIRROR_RATIO = 30.0
MIN_END_SHIFT_M = 0.01  # end moved by a 1 % change of the values, at worst
MAX_LEVERAGE = 3.0  # held-out end shift per unit of training residual, at worst
MAX_LEVER_INFLATION = 25.0  # the geometry's variance widened by a free lever arm, at worst
MAX_LEVER_SIGMA_M = 0.05  # the lever arm's 1-sigma at LEVER_NOISE_M of residual, at worst
LEVER_NOISE_M = 0.01
GEOMETRY, LEVER, YAW = (0, 1, 2), (3, 4), (5,)  # the information's columns
_STEP = 1e-5  # relative step of the central differences


@dataclass(frozen=True)
class Shape:
    """What one run shows of the geometry (nominal geometry, computed once per run)."""

    travel: float  # sum of |arc length| [m]
    turn_span: float  # max - min heading [rad]
    net_turn: float  # end heading [rad], + counter-clockwise
    end_jacobian: FloatArray  # 2x3: end position per relative change of the values [m]
    information: FloatArray  # 6x6 J^T J: log radii, log separation, the mount (x, y, yaw)
    mirrored: FloatArray  # the same for the run mirrored
    lever: bool = False  # whether the fit frees the lever arm (eliminated with the yaw)

    @property
    def end_shift(self) -> float:
        """How far a 1 % change of the three values moves the run's end, at most [m]."""
        return 0.01 * float(np.linalg.norm(self.end_jacobian, 2))


@dataclass(frozen=True)
class Coverage:
    """Whether a set of runs determines the geometry; ``reason`` names what it lacks."""

    travel: float
    turn_span: float
    mirror_ratio: float
    reason: str  # "" when it does

    @property
    def determined(self) -> bool:
        """Nothing lacking: the runs determine all three values."""
        return not self.reason


def mirrored(run: Run) -> Run:
    """The run driven the other way: wheels swapped, its reference reflected about x.

    Its mount is reflected too (:func:`mirrored_mount`).
    """
    ref = run.reference
    steps = dataclasses.replace(run.steps, d_left=run.steps.d_right,
                                d_right=run.steps.d_left)
    return Run(run.name, steps, None if ref is None
               else dataclasses.replace(ref, y=-ref.y, yaw=-ref.yaw))


def mirrored_mount(mount: Mount) -> Mount:
    """A mount reflected about base_link's x axis, as :func:`mirrored` reflects a run."""
    return Mount(mount.x, -mount.y, -mount.yaw)


def nudged(mount: Mount, d: FloatArray) -> Mount:
    """``mount`` moved by ``d`` = (x, y, yaw) in base_link (``D M``).

    The mount's columns of the information are taken in base_link, so they do not
    depend on where the reference is mounted: the same runs with their reference moved
    give the same information.
    """
    c, s = math.cos(float(d[2])), math.sin(float(d[2]))
    return Mount(float(d[0]) + c * mount.x - s * mount.y, float(d[1]) + s * mount.x + c * mount.y,
                 float(d[2]) + mount.yaw)


def information(run: Run, nominal: Geometry, mount: Mount = AXLE,
                max_gap: float = 0.5) -> FloatArray:
    """``J^T J`` of the fit's residuals of ``run`` at ``nominal`` (its weighting, 6x6).

    Columns: the logs of the left and right radius and the separation (relative
    changes), then the mount's x, y and yaw, moved in base_link (:func:`nudged`).
    """
    p = calibration.prepare(run, max_gap)
    base = values_of(nominal)
    heading_length = 0.5 * nominal.separation
    weight = 1.0 / math.sqrt(len(p.index))

    def res(x: FloatArray) -> FloatArray:
        v = base * np.exp(x[:3])
        g = with_values(nominal, float(v[0]), float(v[1]), float(v[2]))
        return weight * calibration.residuals(p, g, nudged(mount, x[3:]),
                                              heading_length).ravel()

    cols = [(res(_STEP * e) - res(-_STEP * e)) / (2 * _STEP) for e in np.eye(6)]
    jac = np.column_stack(cols)
    return np.asarray(jac.T @ jac, dtype=np.float64)


def end_jacobian(run: Run, nominal: Geometry) -> FloatArray:
    """2x3: the run's end position per relative change of the three values [m]."""
    base = values_of(nominal)

    def end(x: FloatArray) -> FloatArray:
        v = base * np.exp(x)
        x_, y_, _ = integrate_steps(run.steps, with_values(nominal, float(v[0]),
                                                           float(v[1]), float(v[2])))
        return np.array([x_[-1], y_[-1]])

    return np.column_stack([(end(_STEP * e) - end(-_STEP * e)) / (2 * _STEP)
                            for e in np.eye(3)])


def shape(run: Run, nominal: Geometry, mount: Mount = AXLE, lever: bool = False,
          max_gap: float = 0.5) -> Shape:
    """One run's travel, turning and information (the fit's Jacobian), and its mirror's.

    ``mount``: where the reference sits (given, or as fitted); ``lever``: whether the
    fit frees its lever arm (:func:`lever_reason` decides it on all the runs).
    """
    ds, _ = body_increment(nominal, run.steps.d_left, run.steps.d_right)
    _, _, th = integrate_steps(run.steps, nominal)
    heading = np.concatenate(([0.0], th))
    return Shape(float(np.sum(np.abs(ds))), float(np.ptp(heading)), float(heading[-1]),
                 end_jacobian(run, nominal), information(run, nominal, mount, max_gap),
                 information(mirrored(run), nominal, mirrored_mount(mount), max_gap), lever)


def judges(held_out: Shape) -> str:
    """Why a held-out run cannot judge a geometry ("" when it can)."""
    if held_out.end_shift >= MIN_END_SHIFT_M:
        return ""
    return (f"the held-out run ends in place whatever the geometry (a 1 % change moves its "
            f"end {1000 * held_out.end_shift:.1f} mm; {1000 * MIN_END_SHIFT_M:g} mm or more "
            "needed)")


def leverage(training: Sequence[Shape], held_out: Shape) -> float:
    """How far the held-out end can move per unit of the training runs' residual.

    ``||G A^-1/2||`` (spectral norm); inf when the training runs leave a combination of
    the values free.
    """
    info = geometry_part(sum((s.information for s in training), np.zeros((6, 6))),
                         _lever(training))
    w, u = np.linalg.eigh(info)
    if w[0] <= 1e-12 * max(float(w[-1]), 1e-300):
        return math.inf
    return float(np.linalg.norm(held_out.end_jacobian @ (u / np.sqrt(w)), 2))


def extrapolates(training: Sequence[Shape], held_out: Shape,
                 max_leverage: float = MAX_LEVERAGE) -> str:
    """Why a fold's held-out run lies beyond what its training runs determine ("" if not)."""
    lev = leverage(training, held_out)
    if lev <= max_leverage:
        return ""
    return (f"the held-out run's end moves {lev:.1f}x more with the geometry than its training "
            f"runs' residuals do (an extrapolation: what those runs leave unexplained decides "
            f"it; {max_leverage:g}x or less needed)")


def _lever(shapes: Sequence[Shape]) -> bool:
    return bool(shapes) and shapes[0].lever


def geometry_part(info: FloatArray, lever: bool = False) -> FloatArray:
    """The 3x3 information on the geometry, the mount's fitted part eliminated (Schur).

    The yaw always, the lever arm with ``lever`` (held, its columns are dropped).
    """
    nuisance = [*LEVER, *YAW] if lever else list(YAW)
    g = list(GEOMETRY)
    a, b, d = info[np.ix_(g, g)], info[np.ix_(g, nuisance)], info[np.ix_(nuisance, nuisance)]
    return np.asarray(a - b @ np.linalg.pinv(d) @ b.T, dtype=np.float64)


def generalised_max(own: FloatArray, other: FloatArray) -> float:
    """Largest generalised eigenvalue of ``(other, own)``; inf when ``own`` is singular."""
    w, u = np.linalg.eigh(own)
    if w[0] <= 1e-12 * max(float(w[-1]), 1e-300):
        return math.inf
    white = u / np.sqrt(w)
    return float(np.linalg.eigvalsh(white.T @ other @ white)[-1])


def mirror_ratio(shapes: Sequence[Shape]) -> float:
    """Largest generalised eigenvalue of (mirrored, own) information; inf when singular."""
    lever = _lever(shapes)
    own = geometry_part(sum((s.information for s in shapes), np.zeros((6, 6))), lever)
    mir = geometry_part(sum((s.mirrored for s in shapes), np.zeros((6, 6))), lever)
    return generalised_max(own, mir)


def lever_inflation(shapes: Sequence[Shape]) -> float:
    """How much freeing the lever arm widens the geometry's variance, at worst."""
    info = sum((s.information for s in shapes), np.zeros((6, 6)))
    return generalised_max(geometry_part(info, True), geometry_part(info, False))


def lever_sigma(shapes: Sequence[Shape], noise: float = LEVER_NOISE_M) -> float:
    """The lever arm's largest 1-sigma [m] were the residuals ``noise`` RMS (inf: not seen)."""
    info = sum((s.information for s in shapes), np.zeros((6, 6)))
    keep, rest = list(LEVER), [*GEOMETRY, *YAW]
    a, b, d = info[np.ix_(keep, keep)], info[np.ix_(keep, rest)], info[np.ix_(rest, rest)]
    w = np.linalg.eigvalsh(a - b @ np.linalg.pinv(d) @ b.T)
    return math.inf if w[0] <= 0.0 else noise / math.sqrt(float(w[0]))


def lever_reason(shapes: Sequence[Shape]) -> str:
    """Why ``shapes`` (all the runs) do not determine the reference's lever arm ("" if they do)."""
    if not shapes:
        return "no run"
    sigma = lever_sigma(shapes)
    if sigma > MAX_LEVER_SIGMA_M:
        return (f"these runs barely turn it about the axle (its 1-sigma would be "
                f"{sigma:.2g} m at {1000 * LEVER_NOISE_M:g} mm of residual; "
                f"{MAX_LEVER_SIGMA_M:g} m or less needed: turns both ways or spins on the "
                "spot determine it)")
    inflation = lever_inflation(shapes)
    if inflation > MAX_LEVER_INFLATION:
        return (f"turning at one curvature, one way, it trades with the geometry: freeing it "
                f"would widen the geometry's variance {inflation:.0f}x "
                f"({MAX_LEVER_INFLATION:g}x or less needed; turns both ways or spins on the "
                "spot determine it)")
    return ""


def weakest(shapes: Sequence[Shape]) -> FloatArray:
    """The combination of the three values ``shapes`` see least (unit, relative changes).

    The geometry's information (the mount's fitted part eliminated) has its smallest
    eigenvalue along it: what runs turning one way only leave free.
    """
    info = geometry_part(sum((s.information for s in shapes), np.zeros((6, 6))), _lever(shapes))
    _, u = np.linalg.eigh(info)
    v = u[:, 0]
    return np.asarray(v if v[np.argmax(np.abs(v))] > 0 else -v, dtype=np.float64)


def coverage(shapes: Sequence[Shape]) -> Coverage:
    """Whether ``shapes`` (a fold's training runs) determine the geometry, and if not why."""
    travel = sum(s.travel for s in shapes)
    span = max((s.turn_span for s in shapes), default=0.0)
    ratio = mirror_ratio(shapes) if shapes else math.inf
    if travel < MIN_TRAVEL_M:
        reason = (f"too little travel ({travel:.2f} m, turns on the spot only; "
                  f"{MIN_TRAVEL_M:g} m or more needed)")
    elif span < MIN_TURN_RAD:
        reason = (f"too little turning (heading spans {math.degrees(span):.0f} deg, "
                  f"straight lines only; {math.degrees(MIN_TURN_RAD):.0f} deg or more needed)")
    elif ratio > MAX_MIRROR_RATIO:
        net = sum(s.net_turn for s in shapes)
        way = "counter-clockwise" if net > 0 else "clockwise"
        seen = ("a combination these runs do not see at all" if math.isinf(ratio)
                else f"the geometry {ratio:.0f}x more strongly in one combination")
        reason = (f"turning one way only ({way}: the same runs driven the other way would "
                  f"see {seen})")
    else:
        reason = ""
    return Coverage(travel, span, ratio, reason)
