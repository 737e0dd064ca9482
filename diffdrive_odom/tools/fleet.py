"""A fleet's bags at once: the same per-bag work on every core, or on a Dask cluster.

A fleet records one bag per robot per shift. ``replay`` given several bags runs its
one-bag work (the very function a single bag goes through) for each, in a
:class:`concurrent.futures.ProcessPoolExecutor` of ``--jobs`` processes (default: the
cores) or, with ``--dask ADDRESS``, as tasks on an existing ``dask.distributed``
cluster (the optional extra ``fleet``: ``pip install diffdrive_odom[fleet]``); no
scheduler of our own. Each bag's output (stdout, stderr, exit status) is captured in
its worker and printed here in the order the bags were given, followed by one
combined table of each bag's figures side by side (:data:`COLUMNS`; the work records
them with :func:`record`), also written as CSV or JSON with ``--summary``, so what is
printed does not depend on scheduling. A bag that fails
is named with its reason and does not stop the others; the exit status is the number
of bags that failed (0: all worked). The pool's workers end with this process however
it ends (SIGKILL included: they used to wait for work under init forever), a bag they
are on interrupted as by Ctrl-C, so its staged outputs go (:func:`_end_with_parent`).
"""

from __future__ import annotations

import _thread
import argparse
import csv
import io
import json
import math
import multiprocessing
import os
import sys
from collections.abc import Callable, Sequence
from concurrent.futures import Future, ProcessPoolExecutor
from contextlib import redirect_stderr, redirect_stdout
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from diffdrive_odom.ros import lifetime
from diffdrive_odom.settings.dependencies import missing_text
from diffdrive_odom.tools.cmdline.args import fail
from diffdrive_odom.tools.cmdline.outputs import output_problem

Work = Callable[[argparse.Namespace], int]
Figure = float | int | None

# The summary's figures: (key, table heading, format). The evaluation's are start aligned
# (the odometry's start put on the reference's), as its error per metre is.
COLUMNS: tuple[tuple[str, str, str], ...] = (
    ("readings", "readings", "{:d}"),
    ("poses", "poses", "{:d}"),
    ("distance_m", "distance [m]", "{:.3f}"),
    ("final_error_m", "final error [m]", "{:.4f}"),
    ("ate_m", "ATE [m]", "{:.4f}"),
    ("error_per_m", "error/m [%]", "{:.3f}"),
    ("slips", "slips", "{:d}"),
)
# Shown even when no bag has them: what a fleet's evaluation is read for.
ALWAYS = ("final_error_m", "ate_m", "error_per_m", "slips")
PERCENT = ("error_per_m",)
FIGURES = "fleet_figures"  # the attribute of a bag's arguments its work records into


@dataclass(frozen=True)
class BagResult:
    """One bag's run: its exit status and everything it printed."""

    bag: str
    status: int
    stdout: str
    stderr: str
    figures: dict[str, Figure] = field(default_factory=dict)

    def reason(self) -> str:
        """Why it failed ('' when it did not)."""
        if self.status == 0:
            return ""
        lines = self.stderr.strip().splitlines()
        return lines[-1] if lines else f"exit status {self.status}"


def record(args: argparse.Namespace, **figures: Figure) -> None:
    """Note a bag's figures for the fleet's summary (nothing when run alone)."""
    into = getattr(args, FIGURES, None)
    if into is not None:
        into.update({k: (None if isinstance(v, float) and not math.isfinite(v) else v)
                     for k, v in figures.items()})


def run_one(work: Work, bag: str, args: argparse.Namespace) -> BagResult:
    """Run ``work(args)`` capturing its output; an exception is this bag's failure."""
    out, err = io.StringIO(), io.StringIO()
    figures: dict[str, Figure] = {}
    setattr(args, FIGURES, figures)
    with redirect_stdout(out), redirect_stderr(err):
        try:
            status = work(args)
        except Exception as exc:  # one bag's bug must not stop the fleet
            print(f"{type(exc).__name__}: {exc}", file=sys.stderr)
            status = 1
    return BagResult(bag, status, out.getvalue(), err.getvalue(),
                     figures if status == 0 else {})


def add_fleet_arguments(ap: argparse.ArgumentParser) -> None:
    """``--jobs`` and ``--dask``: how several bags are worked on."""
    ap.add_argument("--jobs", type=int, default=None, metavar="N",
                    help="with several bags: processes working on them (default: the cores)")
    ap.add_argument("--dask", metavar="ADDRESS", default=None,
                    help="with several bags: submit each to this dask.distributed scheduler "
                    "(needs the extra 'fleet': pip install diffdrive_odom[fleet]; default: "
                    "local processes, see --jobs)")


def add_summary_argument(ap: argparse.ArgumentParser) -> None:
    """``--summary FILE.csv|FILE.json``: the fleet's table as a file."""
    ap.add_argument("--summary", metavar="FILE", default=None,
                    help="with several bags: also write the summary table, one row a bag, "
                    "as CSV (FILE.csv) or JSON (FILE.json) (default: not written)")


def summary_problem(path: str | None) -> str | None:
    """Why ``--summary`` cannot be used (checked before any work), or None."""
    if path is None:
        return None
    if Path(path).suffix.lower() not in (".csv", ".json"):
        return f"--summary {path}: name a .csv or .json file"
    return output_problem(path, "--summary")


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
    # spawn, not fork: a fork copies the caller's threads' state without the threads (a
    # test process's DDS, rclpy's executors), and the child's garbage collector then
    # finalised their objects: a segfault in a calibrate worker, twice in a full test run.
    with ProcessPoolExecutor(max_workers=min(workers, len(calls)),
                             mp_context=multiprocessing.get_context("spawn"),
                             initializer=_end_with_parent, initargs=(os.getpid(),)) as pool:
        futures: list[Future[Any]] = [pool.submit(fn, *c) for c in calls]
        return [_result(f) for f in futures]


# Seconds a pool worker has, once the fleet's process has ended, to unwind the bag it is on.
WORKER_GRACE_S = 2.0


def _end_with_parent(parent: int) -> None:
    """A pool worker's start: end once ``parent`` has ended.

    The work is interrupted first (Ctrl-C's KeyboardInterrupt in the main thread: the
    staged outputs are removed on the way out), then the worker exits; an idle one,
    blocked on the pool's queue, exits after the grace.
    """
    lifetime.watch(parent, _thread.interrupt_main, WORKER_GRACE_S)


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
        raise FleetError(missing_text("distributed", "--dask") or str(exc)) from exc
    connect: Any = Client  # untyped library
    with connect(address) as client:
        futures = [client.submit(fn, *c, pure=False) for c in calls]
        return [_result(f) for f in futures]


class FleetError(Exception):
    """The fleet cannot run at all (say why in one line)."""


def _columns(results: Sequence[BagResult]) -> list[tuple[str, str, str]]:
    return [c for c in COLUMNS
            if c[0] in ALWAYS or any(r.figures.get(c[0]) is not None for r in results)]


def _cell(value: Figure, key: str, fmt: str) -> str:
    if value is None:
        return "-"
    return fmt.format(100.0 * value if key in PERCENT else value)


def table(results: Sequence[BagResult]) -> list[str]:
    """The summary: a bag a row, its figures side by side (``-``: none), or why it failed."""
    columns = _columns(results)
    width = max(len("bag"), *(len(r.bag) for r in results))
    cells = [[_cell(r.figures.get(k), k, f) for k, _, f in columns] for r in results]
    widths = [max(len(h), *(len(row[i]) for row in cells)) for i, (_, h, _) in enumerate(columns)]
    lines = [f"{'bag':{width}s}  result  " + "  ".join(
        f"{h:>{w}s}" for (_, h, _), w in zip(columns, widths, strict=True))]
    for r, row in zip(results, cells, strict=True):
        if r.status != 0:
            lines.append(f"{r.bag:{width}s}  FAILED  {r.reason()}")
            continue
        lines.append(f"{r.bag:{width}s}  ok      " + "  ".join(
            f"{c:>{w}s}" for c, w in zip(row, widths, strict=True)))
    return lines


def write_summary(results: Sequence[BagResult], path: str) -> None:
    """The table as CSV or JSON (by the suffix): every figure, null/empty where none."""
    rows = [{"bag": r.bag, "status": "ok" if r.status == 0 else "failed",
             **{k: r.figures.get(k) for k, _, _ in COLUMNS}, "reason": r.reason()}
            for r in results]
    if Path(path).suffix.lower() == ".json":
        Path(path).write_text(json.dumps(rows, indent=2) + "\n", encoding="utf-8")
        return
    with open(path, "w", newline="", encoding="utf-8") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows({k: ("" if v is None else v) for k, v in row.items()} for row in rows)


def report(results: Sequence[BagResult], prefix: str, summary: str | None = None) -> int:
    """Print every bag's output in order, then the summary table; the number failed."""
    for r in results:
        print(f"{prefix} {r.bag}:")
        sys.stdout.write(r.stdout)
        sys.stdout.flush()
        sys.stderr.write(r.stderr)
        sys.stderr.flush()
    if summary:
        write_summary(results, summary)
    print()
    for line in table(results):
        print(line)
    failed = sum(1 for r in results if r.status != 0)
    print(f"{len(results) - failed} of {len(results)} bags done, {failed} failed")
    return min(failed, 125)


def dispatch(args: argparse.Namespace, work: Work, prefix: str,
             outputs: Sequence[tuple[str, str]], one_bag: str, refused: str | None) -> int:
    """``args.bags``: one through ``work`` itself, several as a fleet (:func:`run_fleet`).

    ``one_bag``: what a single bag writes instead of ``--summary``'s table; ``refused``:
    why these flags cannot run as a fleet, or None. Exit 2 (with that line) when not.
    """
    if len(args.bags) == 1:
        if args.summary:
            return fail(prefix, "--summary is a fleet's table: give several bags (one bag: "
                        f"{one_bag})")
        args.bag = args.bags[0]
        return work(args)
    if refused:
        return fail(prefix, refused)
    done = run_fleet(args, work, prefix, outputs)
    return fail(prefix, done) if isinstance(done, str) else done


def run_fleet(args: argparse.Namespace, work: Work, prefix: str,
              outputs: Sequence[tuple[str, str]]) -> int | str:
    """``args.bags`` each through ``work``; the number failed, or the one line why not at all.

    ``outputs``: ``(attribute, suffix)`` of the flags that name output files; with
    several bags each names a directory, and a bag's output in it is named after the
    bag (``run-04.csv``). ``args.jobs`` / ``args.dask``: see :func:`add_fleet_arguments`.
    """
    if args.jobs is not None and args.jobs < 1:
        return f"--jobs must be >= 1, got {args.jobs}"
    summary = getattr(args, "summary", None)
    problem = summary_problem(summary)
    if problem:
        return problem
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
    try:
        return report(results, prefix, summary)
    except OSError as err:  # the summary's place vanished or filled up after the check
        return f"--summary: cannot write: {err}"
