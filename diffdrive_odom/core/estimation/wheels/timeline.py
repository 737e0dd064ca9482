"""What the estimator says about a reading, and the verdicts of its stamp rules.

Pure Python. :class:`Status` and :class:`Verdict` are the outcome of
:meth:`~diffdrive_odom.core.estimation.wheels.estimator.OdometryEstimator.update` (the rules'
settings: :mod:`~diffdrive_odom.core.estimation.config`). The rest is the vocabulary
of the rules on header stamps: a stamp far back (a bag loop), a reading held after a
gap, a lone outlier, a pause taken as a new reference, and the :class:`Trial` of a
timeline taken after a gap, which keeps a burst of far-ahead stamps from replacing the
timeline or the pose. Kept beside the estimator so its module holds the rules
themselves, and every text a log shows for them is written once.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

from diffdrive_odom.core.estimation.wheels.encoders import Reason, WheelReading
from diffdrive_odom.core.geometry.integration import Pose2D
from diffdrive_odom.core.geometry.mat3 import Matrix

# s of its own stamps a timeline taken after a gap must last to be taken for good. Longer
# than a burst of outlier stamps (a driver's clock glitching for a second or two), short
# enough that a driver whose clock really changed is published again soon.
ADOPT_CLOCK_AFTER_S = 5.0


class Status(enum.Enum):
    """What the estimator did with one reading."""

    REFERENCE = "reference"  # first reading / re-anchored: no motion integrated
    UPDATED = "updated"
    DROPPED = "dropped"  # unusable: state untouched
    REANCHORED = "reanchored"  # implausible step skipped; this reading is the new reference
    TIME_RESET = "time_reset"  # stamp jumped back: estimator restarted from this reading
    # Not published: a stamp far ahead kept aside until the next reading decides, or a
    # reading on a clock that jumped, integrated while that clock is on trial.
    HELD = "held"


@dataclass(frozen=True)
class Verdict:
    """The outcome of :meth:`OdometryEstimator.update`.

    ``code`` is the stable key to count by; ``reason`` the human text for logs.
    """

    status: Status
    code: Reason = Reason.UPDATED
    reason: str = ""
    count: int = 1  # readings ``dropped_code`` stands for (a discarded burst: all of them)
    cause: str = ""  # a skipped step's likely cause and the parameter that fixes it

    @property
    def has_new_pose(self) -> bool:
        """True when the pose may have changed and is worth publishing."""
        return self.status in (Status.UPDATED, Status.REFERENCE, Status.TIME_RESET)

    @property
    def dropped_code(self) -> Reason | None:
        """The code of the reading(s) this verdict drops, if any; counters key on it.

        That is this reading, or (for ``future_stamp``) earlier ones found to be
        outliers (``count`` of them).
        """
        if self.status is Status.DROPPED or self.code is Reason.FUTURE_STAMP:
            return self.code
        return None

    @property
    def warning(self) -> str:
        """What a log says about this verdict ('' when nothing is worth a warning)."""
        if self.dropped_code is not None:
            return "dropped"
        if self.status is Status.REANCHORED or self.code is Reason.GAP:
            return "re-anchored"
        if self.code is Reason.GAP_INTEGRATED:
            return "after a gap"
        if self.code is Reason.CLOCK_JUMP:
            return "held"
        return ""


# The verdict of every plain step (frozen, so one instance serves them all).
UPDATED = Verdict(Status.UPDATED)
ON_TRIAL = Verdict(Status.HELD, Reason.HELD,
                   "on a clock that jumped: integrated, not published while on trial")


@dataclass
class Trial:
    """A timeline taken after a gap, on trial until it has lasted ADOPT_CLOCK_AFTER_S.

    ``before``: the old timeline's last usable reading, with the pose and the
    covariance state (pose covariance, geometry sensitivity) it left; ``first``: the
    reading that started the new one; ``readings``: how many the new one has had;
    ``suspect``: the jump is the driver's clock jumping into the future, not a pause
    (:func:`suspect_jump`), so its poses are not published while on trial.
    """

    before: WheelReading
    first: WheelReading
    pose: Pose2D
    covariance: tuple[Matrix, Matrix] | None
    suspect: bool
    readings: int = 2  # the held reading and the one that continued it

    @property
    def jump_s(self) -> float:
        """How far ahead of the old timeline the new one started [s]."""
        return (self.first.stamp_ns - self.before.stamp_ns) * 1e-9

    def returned_to(self, reading: WheelReading, latest_ns: int, gap_ns: float) -> bool:
        """True when ``reading`` continues the old timeline.

        It is after the old timeline's last reading, before the new one's start, and no
        further on than the new one has run since it started (plus one gap).
        """
        since = reading.stamp_ns - self.before.stamp_ns
        return (reading.stamp_ns < self.first.stamp_ns
                and 0 < since <= latest_ns - self.first.stamp_ns + gap_ns)

    def lasted(self, reading: WheelReading) -> bool:
        """True once the new timeline has run ADOPT_CLOCK_AFTER_S up to ``reading``."""
        return reading.stamp_ns - self.first.stamp_ns >= ADOPT_CLOCK_AFTER_S * 1e9


def suspect_jump(before: WheelReading, first: WheelReading, gap_s: float) -> bool:
    """True when a jump ahead is the driver's clock jumping, not a pause.

    Both must hold, by over a gap: the stamps jumped further than the receiver saw time
    pass (a pause, a driver restart, moves both clocks alike), and the new stamp is
    ahead of its own receive time (impossible for a measurement: the stamp is in the
    future). Unknown receive times say nothing (False). A driver whose clock is behind
    ours (never synced) is named by the clock offset check instead.
    """
    if before.receive_ns is None or first.receive_ns is None:
        return False
    gap_ns = gap_s * 1e9
    jumped = (first.stamp_ns - before.stamp_ns) - (first.receive_ns - before.receive_ns)
    return jumped > gap_ns and first.stamp_ns - first.receive_ns > gap_ns


def too_fast(why: str, wrap: tuple[int, float]) -> Verdict:
    """An implausible step, skipped: ``why`` (plausibility's text), and a wrap it matches.

    ``wrap``: :func:`~.wheels.plausibility.counter_wrap`'s width and span, named as the
    likely cause with the parameter that fixes it.
    """
    bits, span = wrap
    cause = "" if not bits else (
        f"likely a {bits}-bit counter wrapping ({2**bits} counts = {span:.4g} rad): set "
        f"encoder_counter_bits: {bits}")
    return Verdict(Status.REANCHORED, Reason.TOO_FAST,
                   f"{why}; step skipped" + (f" ({cause})" if cause else ""), cause=cause)


def time_reset(age_ns: int) -> Verdict:
    """A stamp far back (a bag loop): restart at the origin."""
    return Verdict(Status.TIME_RESET, Reason.TIME_RESET,
                   f"stamp jumped back {age_ns * 1e-9:.3f} s: odometry restarted at the origin")


def stale(age_ns: int) -> Verdict:
    """A repeated or slightly older stamp: dropped."""
    what = "repeats" if age_ns == 0 else "is older than"
    return Verdict(Status.DROPPED, Reason.STALE_STAMP, f"stamp {what} the previous reading's")


def held(ahead_ns: int, replaced: int | None) -> Verdict:
    """A reading ``ahead_ns`` after the last usable one, held.

    ``replaced``: how far after it an earlier held one was, now found a lone outlier.
    """
    if replaced is not None:
        return Verdict(
            Status.HELD, Reason.FUTURE_STAMP,
            f"the reading stamped {replaced * 1e-9:.3f} s after the last usable one was "
            "not continued: dropped as an outlier; this one is held in its place",
        )
    return Verdict(
        Status.HELD, Reason.HELD,
        f"stamp {ahead_ns * 1e-9:.3f} s after the last usable reading: held until the next "
        "reading shows a pause or an outlier",
    )


def lone_outlier(ahead_ns: int) -> Verdict:
    """A held reading the next one did not continue: it was dropped (this one integrated)."""
    return Verdict(
        Status.UPDATED, Reason.FUTURE_STAMP,
        f"a lone reading stamped {ahead_ns * 1e-9:.3f} s after the last usable one was "
        "dropped as an outlier (the readings after it continue the old timeline)",
    )


def gap_taken(trial: Trial, max_reading_gap: float, why: str) -> Verdict:
    """A held reading continued: the pause was real (or, if suspect, the clock jumped).

    ``why``: what in the counts makes it a restart ('': its motion was integrated).
    """
    if trial.suspect:
        elapsed = (trial.first.receive_ns or 0) - (trial.before.receive_ns or 0)
        return Verdict(
            Status.HELD, Reason.CLOCK_JUMP,
            f"stamps jumped {trial.jump_s:.3f} s ahead while {elapsed * 1e-9:.3f} s passed "
            "(receive time): integrated but not published until the old clock returns "
            f"(then they are outliers) or this one lasts {ADOPT_CLOCK_AFTER_S:g} s",
        )
    if not why:
        return Verdict(
            Status.UPDATED, Reason.GAP_INTEGRATED,
            f"{trial.jump_s:.3f} s without a reading (max_reading_gap {max_reading_gap:g} "
            "s): the counts went on, so the gap's motion is integrated as one arc (heading "
            "from the counts, position covariance grown for the unknown path)",
        )
    return Verdict(
        Status.UPDATED, Reason.GAP,
        f"{trial.jump_s:.3f} s since the last usable reading (max_reading_gap "
        f"{max_reading_gap:g} s): taken as the new reference, no motion integrated over "
        f"the gap (a driver restart: {why})",
    )


def clock_adopted(trial: Trial) -> Verdict:
    """A suspect timeline lasted: it is the driver's new clock."""
    return Verdict(
        Status.UPDATED, Reason.GAP,
        f"the stamps that jumped {trial.jump_s:.3f} s ahead kept that clock for "
        f"{ADOPT_CLOCK_AFTER_S:g} s: taken as the driver's new clock (sync the driver's "
        "clock, or set stamp_source: receive_time)",
    )


def burst_discarded(trial: Trial) -> Verdict:
    """The old timeline returned: the trial's readings were outliers, all counted."""
    return Verdict(
        Status.UPDATED, Reason.FUTURE_STAMP,
        f"{trial.readings} readings stamped from {trial.jump_s:.3f} s after the last usable "
        "one on were dropped as outliers: the readings after them continue the old "
        "timeline, integrated from its last reading (no motion lost)",
        count=trial.readings,
    )
