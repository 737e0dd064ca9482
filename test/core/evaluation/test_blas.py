"""The fits hold BLAS to one thread while they run, and give the process its own back.

Why: their Jacobians are too narrow for BLAS's threads to share, which then only spin
(core/evaluation/blas.py has the figures). The oracle is threadpoolctl's own report of
each loaded BLAS library's thread count.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy import optimize
from test_calibration import NOMINAL, simulate

from diffdrive_odom.core.evaluation import blas, calibration
from diffdrive_odom.core.motion import routes

threadpoolctl = pytest.importorskip("threadpoolctl")


def _blas_threads() -> list[int]:
    return [int(i["num_threads"]) for i in threadpoolctl.threadpool_info()
            if i["user_api"] == "blas"]


def test_a_held_function_runs_on_one_thread_and_the_setting_comes_back() -> None:
    np.linalg.svd(np.ones((40, 3)))  # numpy's BLAS is loaded
    before = _blas_threads()
    assert before, "no BLAS library loaded to hold"
    with threadpoolctl.threadpool_limits(limits=2, user_api="blas"):
        outside = _blas_threads()
        inside = blas.one_thread(_blas_threads)()
        nested = blas.one_thread(lambda: blas.one_thread(_blas_threads)() + _blas_threads())()
        assert inside == [1] * len(outside)
        assert nested == [1] * (2 * len(outside))
        assert _blas_threads() == outside  # given back as it was
    assert _blas_threads() == before


def test_the_calibration_fit_runs_its_least_squares_on_one_thread(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """The one least-squares fit every calibration goes through (calibrate, the demo, the
    benches) runs scipy's solver with BLAS held, the process's setting around it kept."""
    seen: list[list[int]] = []
    solver = optimize.least_squares

    def spy(*args: object, **kwargs: object) -> object:
        seen.append(_blas_threads())
        return solver(*args, **kwargs)

    monkeypatch.setattr(optimize, "least_squares", spy)  # the module calibration calls
    runs = [simulate(routes.umbmark(1.0, clockwise=True))]
    with threadpoolctl.threadpool_limits(limits=2, user_api="blas"):
        outside = _blas_threads()
        calibration.fit(runs, NOMINAL, figures=False)
        assert _blas_threads() == outside
    assert seen and all(threads == [1] * len(outside) for threads in seen), seen
