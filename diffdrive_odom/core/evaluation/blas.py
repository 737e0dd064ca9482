"""The fits' linear algebra on one BLAS thread.

scipy's least squares factors the fit's Jacobian at every iteration: a few thousand rows
and a dozen or so columns. OpenBLAS's threads cannot share such work; they only
synchronise, and while they wait they spin. On two idle cores an SVD of 20000 x 12 took
the same wall time on two threads as on one, at twice the CPU; beside other work (the test
suite on four workers) calibrate's whole assessment of six runs took 9.6 s of CPU against
3.3 s on one thread. So each fit holds BLAS (numpy's and scipy's, whichever library they
were built with) to one thread while it runs, through threadpoolctl (the ``tools`` extra;
without it the fits give the same numbers on the process's own threads); outside the fits
the process keeps its own setting (``OPENBLAS_NUM_THREADS`` and the like).
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import ParamSpec, TypeVar

try:
    from threadpoolctl import ThreadpoolController
except ImportError:  # optional: the same fit, on the threads BLAS starts with
    ThreadpoolController = None

P = ParamSpec("P")
T = TypeVar("T")

@functools.cache
def _controller() -> ThreadpoolController:
    """Made at the first fit: numpy's and scipy's BLAS are loaded by then."""
    return ThreadpoolController()


def one_thread(fn: Callable[P, T]) -> Callable[P, T]:
    """``fn`` run with BLAS held to one thread (nested calls hold it as well)."""
    if ThreadpoolController is None:
        return fn

    @functools.wraps(fn)
    def held(*args: P.args, **kwargs: P.kwargs) -> T:
        with _controller().limit(limits=1, user_api="blas"):
            return fn(*args, **kwargs)

    return held
