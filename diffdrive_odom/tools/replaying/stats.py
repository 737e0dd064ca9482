"""What a replay did: its counters, the summary line it prints, and what the tests read.

Apart from :mod:`~diffdrive_odom.tools.replay` (the command and its readings engine)
because the open-loop engine (:mod:`~diffdrive_odom.tools.replaying.openloop`) fills the
same record and the fleet's table reads it.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

from diffdrive_odom.core.estimation.online import online_estimate
from diffdrive_odom.core.estimation.results import PipelineStats
from diffdrive_odom.core.geometry.integration import Pose2D

__all__ = ["ReplayStats"]


@dataclass
class ReplayStats:
    """What a replay did, for the summary line and the tests.

    ``reasons`` counts by reason code (see ``encoders.Reason``), ``examples`` keeps
    the first human text of each code; ``refused`` counts the poses the publication
    rule kept back (by reason text, as the node warns); ``published`` is what went out;
    ``pipeline`` is the shared counters' snapshot; ``warnings`` what the node would
    have warned of once (a driver's clock far from the log time).
    """

    readings: int = 0
    published: int = 0
    statuses: Counter[str] = field(default_factory=Counter)
    reasons: Counter[str] = field(default_factory=Counter)
    examples: dict[str, str] = field(default_factory=dict)
    refused: Counter[str] = field(default_factory=Counter)
    warnings: list[str] = field(default_factory=list)  # the pipeline's one-off warnings
    notes: Counter[str] = field(default_factory=Counter)  # input mode / IMU switches
    final_pose: Pose2D = field(default_factory=Pose2D)
    final_stamp_ns: int | None = None
    seconds: float = 0.0
    pipeline: PipelineStats = field(default_factory=PipelineStats)
    unit: str = "readings"  # what was fed: wheel readings, or (open loop) commands
    online_trace: list[tuple[int, online_estimate.OnlineEstimate]] = field(default_factory=list)

    @property
    def usable(self) -> bool:
        """True when at least one reading got past the drop rules."""
        return self.pipeline.last_usable_stamp_ns is not None

    def summary(self) -> str:
        """One human line."""
        p = self.final_pose
        rate = self.readings / self.seconds if self.seconds > 0 else float("inf")
        counts = ", ".join(f"{k} {v}" for k, v in sorted(self.statuses.items()))
        return (
            f"{self.readings} {self.unit} ({counts}) -> {self.published} poses in "
            f"{self.seconds:.2f} s ({rate:,.0f} {self.unit}/s); final pose x={p.x:.6f} m "
            f"y={p.y:.6f} m yaw={p.theta:.6f} rad"
        ) + self._gyro_summary()

    def reason_lines(self, top: int = 5) -> list[str]:
        """The summary's lines on what the rules did, one a reason.

        The ``top`` codes by count, each with its first text, then the likely causes of
        skipped steps with the parameter that fixes them.
        """
        lines = [f"  {count} x {code}: {self.examples[code]}"
                 for code, count in self.reasons.most_common(top)]
        lines += [f"  {count} of the too_fast steps: {cause}"
                  for cause, count in self.pipeline.causes.items()]
        return lines

    def _gyro_summary(self) -> str:
        """The gyro's part of the summary line (``use_imu``), '' otherwise."""
        g = self.pipeline.gyro
        if g is None:
            return ""
        s = g.slips
        dropped = sum(g.dropped.values())
        last = "" if s.last_stamp_ns is None else (
            f", last at {s.last_stamp_ns * 1e-9:.3f} s ({s.last_size:.4f} rad)")
        return (f"; gyro: {g.samples} IMU samples ({dropped} dropped), {s.events} slip "
                f"events over {s.steps} steps ({s.total_size:.4f} rad){last}, bias "
                f"{g.bias:.6f} +- {g.bias_stddev:.6f} rad/s from {g.zero_velocity_updates} "
                f"zero-velocity updates over {g.standing_s:.1f} s standing still"
                + (", IMU silent at the end" if g.silent else "")
                + f"; wheel stamps' jitter {g.jitter * 1e3:.1f} ms; "
                + ("IMU lag not measured (turn more than a radian)" if g.lag is None
                   else g.lag.measured()))
