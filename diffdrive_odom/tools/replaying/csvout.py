"""Odometry as CSV: one row per published pose, numbers written losslessly.

Why: a table anyone can load (pandas, a spreadsheet, evo) beside the output bag, with
stamps as exact integers and every float as the shortest text that reads back to the
same double, written fast enough not to cost more than the odometry itself.

CSV columns (one row per published odometry, see :data:`CSV_COLUMNS`):

==============  =============================================================
``stamp_ns``    measurement time: the JointState header stamp [ns], an integer
``time``        the same in seconds, written exactly: ``sec.nanosec`` with nine
                decimals (``1600000000.100000001``), never a rounded float
``x``, ``y``    position of the base frame in the odom frame [m]
``yaw``         heading in (-pi, pi] [rad]
``linear``      forward speed along base x [m/s] (rolling mean as the node)
``angular``     yaw rate [rad/s] (rolling mean as the node)
``status``      estimator verdict: reference / updated / time_reset
``var_x``,      diagonal of the published pose covariance: variance of x, y
``var_y``,      [m^2] and yaw [rad^2] (the full 6x6 matrix is in the output bag)
``var_yaw``
==============  =============================================================
"""

from __future__ import annotations

import csv
from collections.abc import Sequence
from pathlib import Path
from types import TracebackType
from typing import IO, Any

import numpy as np
import numpy.typing as npt

try:  # the CSV's numbers from C (float_texts); repr where it is not installed
    import orjson as _orjson
except ImportError:  # pragma: no cover - an install without the tools extra's orjson
    _orjson = None  # type: ignore[assignment]

from diffdrive_odom.wire.conversions import split_ns

CSV_COLUMNS = ("stamp_ns", "time", "x", "y", "yaw", "linear", "angular", "status",
               "var_x", "var_y", "var_yaw")


class CsvWriter:
    """Odometry rows with the documented :data:`CSV_COLUMNS` (full float precision)."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self._file: IO[str] | None = None
        self._csv: Any = None

    def __enter__(self) -> CsvWriter:
        self._file = open(self.path, "w", newline="", encoding="utf-8")
        self._csv = csv.writer(self._file)
        self._csv.writerow(CSV_COLUMNS)
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        if self._file is not None:
            self._file.close()

    def row(
        self, ns: int, x: float, y: float, yaw: float, *, linear: float, angular: float,
        status: str, pose_covariance: Sequence[float] = (),
    ) -> None:
        """One published pose; floats as :func:`float_texts` writes them (lossless).

        The stamp is an integer, so it is written as integers too: a float in seconds
        has only ~0.2 us resolution at today's epoch (``1600000000.1000001``).
        ``pose_covariance`` is the message's 6x6 row-major matrix; its x, y and yaw
        variances fill the last three columns (left empty without one).
        """
        (motion,) = float_texts(np.array([[x, y, yaw, linear, angular]], dtype=np.float64))
        variances = (float_texts(np.array([[pose_covariance[i] for i in (0, 7, 35)]],
                                          dtype=np.float64))[0].split(",")
                     if pose_covariance else ["", "", ""])
        self._csv.writerow((ns, seconds_text(ns), *motion.split(","), status, *variances))

    def rows(self, ns: Sequence[int], columns: npt.NDArray[np.float64], status: str) -> None:
        """Many rows at once, the text :meth:`row` writes.

        ``columns`` (n, 8) holds x, y, yaw, linear, angular and the x, y, yaw
        variances; ``status`` is a plain word (csv quotes nothing of such a row).
        """
        assert self._file is not None
        if not len(ns):
            return
        assert status.isidentifier(), status
        motion, variances = float_texts(columns[:, :5]), float_texts(columns[:, 5:])
        lines = (f"{n},{n // 1_000_000_000}.{n % 1_000_000_000:09d},{m},{status},{v}\r\n"
                 for n, m, v in zip(ns, motion, variances, strict=True))
        self._file.write("".join(lines))


def float_texts(values: npt.NDArray[np.float64]) -> list[str]:
    """Each row of a 2-D array as its numbers' shortest round-trip texts, comma-separated.

    Why: Python's ``repr`` costs about 0.5 us a number, more than the odometry of a
    reading; orjson (where installed) writes the same shortest digits from C, as
    ``0.00001`` and ``-2.5e-7`` where ``repr`` writes ``1e-05`` and ``-2.5e-07``.
    Either reads back to the very same double. A non-finite number (which publication
    never lets out) falls back to ``repr`` for the whole array.
    """
    if _orjson is not None and bool(np.isfinite(values).all()):
        text: str = _orjson.dumps(np.ascontiguousarray(values, dtype=np.float64),
                                  option=_orjson.OPT_SERIALIZE_NUMPY).decode()
        return text[2:-2].split("],[")
    return [",".join(map(repr, row)) for row in values.tolist()]


def seconds_text(ns: int) -> str:
    """Exact decimal seconds of an integer nanosecond stamp: ``sec.nanosec`` (9 places)."""
    sec, nanosec = split_ns(ns)
    return f"{sec}.{nanosec:09d}"
