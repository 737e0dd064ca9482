"""The gyro's bias, estimated while the wheels stand still (zero-velocity updates).

A scalar Kalman filter on the yaw-rate bias: its variance grows by the bias random
walk between updates; each wheel step over which both wheels stood still, and whose
interval the IMU's samples cover, measures the bias by the gyro's mean rate over it.
Standstill is judged from the wheels over the step's interval; the gyro must agree
(a robot turned by hand while its wheels stand is no bias). The decision waits for
the samples covering the interval (:mod:`~diffdrive_odom.core.estimation.gyro.gyrodometry` keeps
the step pending), so it works whatever the IMU's timing; an interval the samples
never cover (a dropout) is given up after ``imu_timeout``. Why none ran, when the
robot stood long enough for one, is counted and said once
(:meth:`Standstill.warning`), so a user whose bias is never estimated is told.
"""

from __future__ import annotations

import math
from collections import Counter, deque
from itertools import pairwise
from statistics import median

# s of standing still after which no zero-velocity update at all is warned of.
STAND_WARN_S = 1.0
# Standing steps' mean rates kept for the noise the gyro shows standing still (its
# median absolute deviation: robust to a robot turned by hand for a while), and how
# many are needed before it counts.
NOISE_WINDOW, NOISE_AFTER = 250, 25
# The measured noise density over gyro_noise_density beyond which it is said.
NOISE_RATIO = 2.0

# Why a standing interval gave no update: the counter's keys and what they mean.
WHY = {
    "unmeasured": "the IMU's samples never covered the wheels' standing intervals "
                  "(IMU stamps far from the wheels'? see imu_stamp_source, imu_timeout)",
    "gyro_disagreed": "the gyro turned while the wheels stood (a bias beyond "
                      "gyro_bias_stddev, gyro_noise_density too small, or the robot "
                      "turned by hand)",
    "silent": "the IMU was silent (no samples within imu_timeout)",
}


class Standstill:
    """The bias estimate and the zero-velocity updates' counters."""

    def __init__(self, bias: float, bias_stddev: float) -> None:
        self.bias = bias
        self.variance = bias_stddev ** 2
        self._grown_to: int | None = None  # stamp the variance was last grown to
        self.updates = 0
        self.standing_ns = 0  # wheel stamps' time standing still, judged or not
        self.missed: Counter[str] = Counter()
        self._warned = False
        self._rates: deque[tuple[float, float]] = deque(maxlen=NOISE_WINDOW)  # (z, dt)
        self._density: float | None = None  # measured_density of _rates (None: not yet)
        self._noise_said = False
        self.noise_warning = ""
        self._held: list[tuple[float, float]] = []  # rates offered before the noise is known

    def grow(self, stamp_ns: int, random_walk: float) -> None:
        """Let the variance grow by the random walk up to ``stamp_ns``."""
        last = self._grown_to
        if last is not None and stamp_ns > last:
            self.variance += random_walk * random_walk * (stamp_ns - last) * 1e-9
        self._grown_to = stamp_ns if last is None or stamp_ns > last else last

    def stood(self, dt_ns: int) -> None:
        """The wheels stood still for ``dt_ns`` (counted as the step is taken)."""
        self.standing_ns += dt_ns

    def measured_density(self) -> float:
        """The gyro's noise density [rad/s/sqrt(Hz)] seen standing still (0: too few steps).

        The median absolute difference of consecutive steps' mean rates, each scaled by
        the square root of its interval (times 1.4826 / sqrt(2): a normal sigma): a rate
        held for a while (a bias, a robot turned by hand) differs by nothing from step to
        step, so only the noise is measured.
        """
        if len(self._rates) < NOISE_AFTER:
            return 0.0
        if self._density is None:  # kept until the next rate: the online filters ask often
            scaled = [z * math.sqrt(dt) for z, dt in self._rates]
            self._density = 1.4826 / math.sqrt(2.0) * median(
                abs(b - a) for a, b in pairwise(scaled))
        return self._density

    def offer(self, z: float, dt: float, noise_density: float, sigmas: float) -> bool:
        """The wheels stood still over ``dt`` s, the gyro's mean rate was ``z``.

        The bias is updated unless the gyro turned (beyond ``sigmas`` of the noise, the
        declared or the measured, whichever is larger: a gyro noisier than declared must
        not have its updates cut to the ones that happen to agree, which would pin the
        bias). The first :data:`NOISE_AFTER` rates wait until the noise is measured.
        """
        self._rates.append((z, dt))
        self._density = None
        if len(self._rates) < NOISE_AFTER:  # the noise is not known yet: held
            self._held.append((z, dt))
            return True
        measured = self.measured_density()
        self._check_noise(measured, noise_density)
        density = max(noise_density, measured)
        held, self._held = self._held, []
        for zh, dth in held:
            self._gated(zh, dth, density, sigmas)
        return self._gated(z, dt, density, sigmas)

    def _gated(self, z: float, dt: float, density: float, sigmas: float) -> bool:
        r = density ** 2 / dt
        resid = z - self.bias
        if resid * resid > sigmas * sigmas * (r + self.variance):
            self.miss("gyro_disagreed")
            return False
        self.update(z, dt, density)
        return True

    def _check_noise(self, measured: float, declared: float) -> None:
        # 0: the rate never changed from step to step (a simulated gyro without noise, or
        # one quantized coarser than its noise): nothing to set gyro_noise_density to.
        if self._noise_said or len(self._rates) < 2 * NOISE_AFTER or measured == 0.0:
            return
        if 1.0 / NOISE_RATIO <= measured / declared <= NOISE_RATIO:
            return
        self._noise_said = True
        self.noise_warning = (
            f"standing still, the gyro's noise is {measured:.3g} rad/s/sqrt(Hz), "
            f"gyro_noise_density says {declared:.3g}: the slip test and the heading's "
            "weights use gyro_noise_density (slips flagged in noise, or missed); set it "
            "to what the gyro shows")

    def update(self, z: float, dt: float, noise_density: float) -> None:
        """The wheels stood still over ``dt`` s: the gyro's mean rate ``z`` measures the bias."""
        r = noise_density ** 2 / dt
        p = self.variance
        k = p / (p + r) if p + r > 0.0 else 0.0
        self.bias += k * (z - self.bias)
        self.variance = (1.0 - k) * p
        self.updates += 1

    def miss(self, why: str) -> None:
        """A standing interval gave no update (``why``: a key of :data:`WHY`)."""
        self.missed[why] += 1

    def warning(self) -> str:
        """Said once: the robot stood long enough and no update ran, and why ('' else).

        Rates held until the noise is known are updates to come, not missed ones: the
        TurtleBot3 bag said "no zero-velocity update ... the bias stays at 0" beside 75
        updates in its summary, its first standing steps held (and its IMU 0.3 s late).
        """
        if self._warned or self.updates or self._held or self.standing_ns < STAND_WARN_S * 1e9:
            return ""
        if not self.missed:
            return ""
        self._warned = True
        why, _ = self.missed.most_common(1)[0]
        return (f"the wheels stood still for {self.standing_ns * 1e-9:.1f} s but no "
                f"zero-velocity update of the gyro bias ran: {WHY[why]}; the bias stays "
                f"at {self.bias:.6g} rad/s until one runs")
