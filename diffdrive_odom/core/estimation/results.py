"""What the reading pipeline reports: each reading's outcome, its counters, a hand-over.

Apart from :mod:`~diffdrive_odom.core.estimation.pipeline`, which produces them, because
the node, ``replay``, the fast lane and the diagnostics read them without running a
pipeline: :class:`Outcome` per reading, :class:`PipelineStats` (with :class:`GyroStats`)
the counters, :class:`Handover` the state the fast lane takes over and gives back.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType

from diffdrive_odom.core.estimation.gate import GateState
from diffdrive_odom.core.estimation.gyro.imulag import LagEstimate
from diffdrive_odom.core.estimation.gyro.slips import SlipStats
from diffdrive_odom.core.estimation.online.online_estimate import OnlineEstimate
from diffdrive_odom.core.estimation.wheels.encoders import WheelIncrement, WheelReading
from diffdrive_odom.core.estimation.wheels.timeline import Verdict
from diffdrive_odom.core.geometry.integration import Pose2D
from diffdrive_odom.core.geometry.mat3 import Matrix

__all__ = ["GyroStats", "Handover", "Outcome", "PipelineStats"]


@dataclass(frozen=True)
class PipelineStats:
    """Counters since the pipeline was built (a snapshot; never changes once taken).

    The names are stable: diagnostics publish them as they are.

    - ``readings``: readings offered, usable or not.
    - ``published``: poses that passed the publish gate.
    - ``dropped``: readings dropped, by reason code (``zero_stamp``, ``missing_joint``,
      ``bad_array``, ``non_finite``, ``no_data``, ``out_of_range``, ``stale_stamp``,
      ``future_stamp``, which counts every reading of a discarded burst); only codes
      seen. A reading stamped over ``max_reading_gap``
      ahead is held (not published, not counted) until the next reading shows whether
      it was a pause (then a ``gap`` re-anchor) or a lone outlier (``future_stamp``).
    - ``reanchors``: implausible steps (faster than ``max_wheel_speed``, a wheel rolling
      over ``plausibility.MAX_STEP_ARC``, or not finite), skipped (code ``too_fast``).
    - ``causes``: of those, the ones with a likely cause, by its text (which names the
      parameter that fixes it: a counter wrapping unseen, ``encoder_counter_bits``).
    - ``gap_reanchors``: readings more than ``max_reading_gap`` after the last usable
      one whose counts say the driver restarted, taken as the new reference (code
      ``gap``).
    - ``gaps_integrated``: such readings whose counts went on: the gap's motion
      integrated as one arc (code ``gap_integrated``).
    - ``time_resets``: restarts at the origin after a stamp jumped back (``time_reset``).
    - ``last_usable_stamp_ns``: stamp of the last reading the estimator accepted
      (None before the first).
    - ``velocity_fallback``: True while wheel motion comes from velocities because
      positions are empty or NaN.
    """

    readings: int = 0
    published: int = 0
    dropped: Mapping[str, int] = field(default_factory=lambda: MappingProxyType({}))
    reanchors: int = 0
    causes: Mapping[str, int] = field(default_factory=lambda: MappingProxyType({}))
    gap_reanchors: int = 0
    gaps_integrated: int = 0
    time_resets: int = 0
    last_usable_stamp_ns: int | None = None
    velocity_fallback: bool = False
    gyro: GyroStats | None = None  # use_imu true only
    online: OnlineEstimate | None = None  # online_calibration monitor|apply, use_imu only

    @property
    def dropped_total(self) -> int:
        """All dropped readings, whatever the reason."""
        return sum(self.dropped.values())


@dataclass(frozen=True)
class GyroStats:
    """The gyro's part of the counters (``use_imu`` true).

    ``samples``: IMU messages offered; ``dropped``: refused by code (``non_finite``,
    ``saturated``, ``zero_stamp``, ``stale_stamp``, ``future_stamp``); ``silent``: the
    last step was wheels only for want of samples; ``bias`` [rad/s] and its standard
    deviation; ``zero_velocity_updates``: bias updates while standing still;
    ``standing_s``: how long the wheels stood still; ``slips``; ``jitter`` [s]: the
    wheel stamps' timing error measured while turning; ``lag``: how much later the
    IMU's stamps are than the wheels' (None: not measured yet).
    """

    samples: int = 0
    dropped: Mapping[str, int] = field(default_factory=lambda: MappingProxyType({}))
    silent: bool = True
    bias: float = 0.0
    bias_stddev: float = 0.0
    zero_velocity_updates: int = 0
    slips: SlipStats = field(default_factory=SlipStats)
    standing_s: float = 0.0
    jitter: float = 0.0
    lag: LagEstimate | None = None


@dataclass(frozen=True, slots=True)
class Outcome:
    """What happened to one reading: the verdict, whether to publish, and a one-off note.

    ``note`` is set only when the input mode changes (velocity fallback on or off), so
    a caller that logs it says so once, not per reading; ``warning`` only the first
    time header stamps are found far from the receiver's clock. ``stamp_ns``: the
    reading's stamp as used (``stamp_source``), which a published pose carries.
    """

    verdict: Verdict
    publish: bool
    note: str = ""
    warning: str = ""
    stamp_ns: int = 0


@dataclass(frozen=True)
class Handover:
    """The pipeline's state where a bulk integrator takes over or hands back.

    :mod:`diffdrive_odom.core.bulk.fastlane` integrates stretches where no rule can fire
    from here and hands the state it reached back (:meth:`ReadingPipeline.take_back`),
    so the next reading meets the pipeline exactly as if every reading had been fed.
    ``reference`` is None while a rule has something pending (a held reading, stale
    stamps, a timeline on trial): then no stretch may start. ``counts``: where the
    reference's counts were first seen [ns] and the last step that moved them
    (:class:`~.wheels.counts.CountTrack`). ``covariance``, ``sensitivity`` and ``rates``
    are the propagated model's (empty when static).
    """

    reference: WheelReading | None
    counts: tuple[int, WheelIncrement | None]
    pose: Pose2D
    windows: tuple[tuple[float, ...], tuple[float, ...]]
    covariance: Matrix
    sensitivity: Matrix
    rates: tuple[Matrix, ...]
    gate: GateState
    clock_named: bool
