"""A fleet's bags at once: the same per-bag work on every core, or on a Dask cluster.

A fleet records one bag per robot per shift. ``replay`` given several bags runs its
one-bag work (the very function a single bag goes through) for each, in a
:class:`concurrent.futures.ProcessPoolExecutor` of ``--jobs`` processes (default: the
cores) or, with ``--dask ADDRESS``, as tasks on an existing ``dask.distributed``
cluster (the optional extra ``fleet``: ``pip install diffdrive_odom[fleet]``); no
scheduler of our own. Each bag's output (stdout, stderr, exit status) is captured in
its worker and printed here in the order the bags were given, followed by one
combined table, so what is printed does not depend on scheduling. A bag that fails
is named with its reason and does not stop the others; the exit status is the number
of bags that failed (0: all worked).
"""

from __future__ import annotations

import argparse
import io
import os
import sys
from collections.abc import Callable, Sequence
from concurrent.futures import Future, ProcessPoolExecutor
from contextlib import redirect_stderr, redirect_stdout
from dataclasses import dataclass
from pathlib import Path
from typing import Any

Work = Callable[[argparse.Namespace], int]


@dataclass(frozen=True)
class BagResult:
    """One bag's run: its exit status and everything it printed."""

    bag: str
    status: int
    stdout: str
    stderr: str

    def line(self) -> str:
        """What the combined table says of it: its summary, or why it failed."""
        if self.status == 0:
            lines = self.stdout.strip().splitlines()
            return lines[0] if lines else "ok"
        lines = self.stderr.strip().splitlines()
        return lines[-1] if lines else f"exit status {self.status}"


def run_one(work: Work, bag: str, args: argparse.Namespace) -> BagResult:
    """Run ``work(args)`` capturing its output; an exception is this bag's failure."""
    out, err = io.StringIO(), io.StringIO()
    with redirect_stdout(out), redirect_stderr(err):
        try:
            status = work(args)
        except Exception as exc:  # one bag's bug must not stop the fleet
            print(f"{type(exc).__name__}: {exc}", file=sys.stderr)
            status = 1
    return BagResult(bag, status, out.getvalue(), err.getvalue())


def add_fleet_arguments(ap: argparse.ArgumentParser) -> None:
    """``--jobs`` and ``--dask``: how several bags are worked on."""
    ap.add_argument("--jobs", type=int, default=None, metavar="N",
                    help="with several bags: processes working on them (default: the cores)")
    ap.add_argument("--dask", metavar="ADDRESS", default=None,
                    help="with several bags: submit each to this dask.distributed scheduler "
                    "(needs the extra 'fleet': pip install diffdrive_odom[fleet]; default: "
                    "local processes, see --jobs)")


def _failed(bag: str, exc: BaseException) -> BagResult:
    return BagResult(bag, 1, "", f"{type(exc).__name__}: {exc}\n")


def run_many(work: Work, jobs: Sequence[tuple[str, argparse.Namespace]], processes: int | None,
             dask: str | None) -> list[BagResult]:
    """Each ``(bag, args)`` through ``work``; results in the order given."""
    done = map_calls(run_one, [(work, bag, a) for bag, a in jobs], processes, dask)
    return [r if isinstance(r, BagResult) else _failed(bag, r)
            for (bag, _), r in zip(jobs, done, strict=True)]


def map_calls(fn: Callable[..., Any], calls: Sequence[tuple[Any, ...]], processes: int | None,
              dask: str | None) -> list[Any]:
    """``fn(*call)`` for each call, on processes or Dask; results (or the exception) in order.

    ``fn`` and its arguments must pickle (a module-level function, plain data).
    """
    if dask:
        return _on_dask(fn, calls, dask)
    workers = processes or os.cpu_count() or 1
    if workers == 1 or len(calls) <= 1:
        return [_call(fn, c) for c in calls]
    with ProcessPoolExecutor(max_workers=min(workers, len(calls))) as pool:
        futures: list[Future[Any]] = [pool.submit(fn, *c) for c in calls]
        return [_result(f) for f in futures]


def _call(fn: Callable[..., Any], call: tuple[Any, ...]) -> Any:
    try:
        return fn(*call)
    except Exception as exc:
        return exc


def _result(future: Any) -> Any:
    try:
        return future.result()
    except Exception as exc:  # the call's own, or a worker that died (killed, out of memory)
        return exc


def _on_dask(fn: Callable[..., Any], calls: Sequence[tuple[Any, ...]], address: str
             ) -> list[Any]:
    try:
        from distributed import Client
    except ImportError as exc:
        raise FleetError("--dask needs dask.distributed: pip install "
                         "'diffdrive_odom[fleet]' (or dask[distributed])") from exc
    connect: Any = Client  # untyped library
    with connect(address) as client:
        futures = [client.submit(fn, *c, pure=False) for c in calls]
        return [_result(f) for f in futures]


class FleetError(Exception):
    """The fleet cannot run at all (say why in one line)."""


def report(results: Sequence[BagResult], prefix: str) -> int:
    """Print every bag's output in order, then the combined table; the number failed."""
    for r in results:
        print(f"{prefix} {r.bag}:")
        sys.stdout.write(r.stdout)
        sys.stdout.flush()
        sys.stderr.write(r.stderr)
        sys.stderr.flush()
    width = max(len(r.bag) for r in results)
    print(f"\n{'bag':{width}s}  result")
    for r in results:
        print(f"{r.bag:{width}s}  {'ok    ' if r.status == 0 else 'FAILED'} {r.line()}")
    failed = sum(1 for r in results if r.status != 0)
    print(f"{len(results) - failed} of {len(results)} bags done, {failed} failed")
    return min(failed, 125)


def run_fleet(args: argparse.Namespace, work: Work, prefix: str,
              outputs: Sequence[tuple[str, str]]) -> int | str:
    """``args.bags`` each through ``work``; the number failed, or the one line why not at all.

    ``outputs``: ``(attribute, suffix)`` of the flags that name output files; with
    several bags each names a directory, and a bag's output in it is named after the
    bag (``run-04.csv``). ``args.jobs`` / ``args.dask``: see :func:`add_fleet_arguments`.
    """
    if args.jobs is not None and args.jobs < 1:
        return f"--jobs must be >= 1, got {args.jobs}"
    names = [Path(b).stem if Path(b).is_file() else Path(b).name for b in args.bags]
    if len(set(names)) != len(names):
        return "several bags have the same name: their outputs would collide"
    jobs = []
    for bag, name in zip(args.bags, names, strict=True):
        one = argparse.Namespace(**vars(args))
        one.bag = bag
        for attr, suffix in outputs:
            if getattr(args, attr):
                Path(getattr(args, attr)).mkdir(parents=True, exist_ok=True)
                setattr(one, attr, str(Path(getattr(args, attr)) / (name + suffix)))
        jobs.append((bag, one))
    try:
        results = run_many(work, jobs, args.jobs, args.dask)
    except FleetError as err:
        return str(err)
    return report(results, prefix)
