"""The online geometry estimate over a run, drawn: ``replay --online-calibration --plot``.

One panel: the three multipliers of ddc's YAML (mean radius held) over the distance
the estimate counted, each with its 1-sigma band, and where it became determined
(turned ``online_calibration_min_turn`` each way); the demo draws the same panel under
its trajectory (:mod:`diffdrive_odom.demo.plot`). matplotlib is imported inside the
functions, so ``--help`` and the rest of replay work without it.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

from diffdrive_odom.core.estimation.online.online_estimate import OnlineEstimate

Trace = Sequence[tuple[int, OnlineEstimate]]
NAMES = ("left wheel radius", "right wheel radius", "wheel separation")
COLORS = ("tab:blue", "tab:orange", "tab:green")


def draw(ax: Any, trace: Trace, true: Sequence[float] | None = None, columns: int = 4) -> None:
    """The estimate's multipliers with their 1-sigma bands on ``ax`` (a matplotlib Axes).

    ``true``: the true multipliers in the same convention (a simulation's), dashed;
    ``columns``: of the legend under the axes (the demo's panel is the figure's width).
    """
    import numpy as np

    d = np.array([e.distance for _, e in trace])
    for i, (name, color) in enumerate(zip(NAMES, COLORS, strict=True)):
        m = np.array([e.multipliers[i] for _, e in trace])
        s = np.array([e.stddevs[i] for _, e in trace])
        ax.plot(d, m, "-", color=color, lw=1.4, label=f"{name} multiplier +- 1 sigma")
        ax.fill_between(d, m - s, m + s, color=color, alpha=0.2, lw=0)
        if true is not None:
            ax.axhline(true[i], color=color, ls="--", lw=1.0, label=f"true {name}")
    first = next((e.distance for _, e in trace if e.determined), None)
    if first is not None:
        ax.axvline(first, color="0.4", ls=":", lw=1.0,
                   label="determined (turned min_turn each way)")
    if len(d):
        # The first windows' sigma is the prior's (5 %): keep the converged part readable.
        late = [e for _, e in trace if e.determined] or [e for _, e in trace]
        values = [m + k * s for e in late for m, s in zip(e.multipliers, e.stddevs, strict=True)
                  for k in (-3.0, 3.0)]
        values += list(true or ())
        lo, hi = min(values), max(values)
        pad = 0.15 * (hi - lo) or 1e-3
        ax.set_ylim(lo - pad, hi + pad)
    ax.set_xlabel("distance the estimate counted [m]")
    ax.set_ylabel("multiplier (mean radius held)")
    ax.grid(True, alpha=0.3)
    # Under the x label, whatever the panel's height: a fraction of the axes put it on
    # the label in the demo's short panel.
    from matplotlib.transforms import offset_copy

    ax.legend(loc="upper center", bbox_to_anchor=(0.5, 0.0), fontsize=8, ncol=columns,
              bbox_transform=offset_copy(ax.transAxes, fig=ax.figure, y=-LABEL_ROOM_PT,
                                         units="points"))


LABEL_ROOM_PT = 34.0  # below the axes: the tick labels and the x label


def write(path: str | Path, trace: Trace, title: str) -> None:
    """A PNG of :func:`draw` alone, titled ``title`` (also the PNG's Title).

    The legend sits under the axes in two columns and the image is cut to what is drawn
    (``bbox_inches="tight"``): in four columns on a 9-inch figure it ran past both edges.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(9, 5.5))
    draw(ax, trace, columns=2)
    ax.set_title(title, fontsize=10)
    fig.savefig(path, dpi=100, bbox_inches="tight", pad_inches=0.15,
                metadata={"Title": title})
    plt.close(fig)
