"""How fast a demo's processes are all gone after a signal to the demo, idle and loaded.

    .venv/bin/python bench/bench_endings.py [--count 20] [--signals INT,TERM,HUP,KILL]
                                            [--busy 2] [--deadline 60] [--quick]

Each trial starts ``diffdrive-odom demo --short`` (four node processes under it) in a
session of its own, waits for its ``nodes up`` line (the loop runs: the nodes publish),
sends one signal to the demo's pid only (as ``kill`` or a closed ssh session does) and
polls /proc until no process of that session is left (zombies aside: the demo's own is
reaped here), which is what a user needs: nothing of the run left running. Idle and
loaded trials alternate, trial by trial: ``--busy`` ``python -c 'while True: pass'``
processes, started once, are SIGSTOPped for the idle trials and SIGCONTed for the loaded
ones, so the machine's own noise falls on both alike. A trial still running at
``--deadline`` seconds counts as left behind (printed as ``>deadline``) and its session
is killed, so the bench itself leaves nothing running (also when SIGTERM or SIGHUP stops
it: as Ctrl-C). 20 trials per signal and load take about 16 minutes on two cores (each
demo start is 4-6 s); ``--count`` shortens it.
"""

from __future__ import annotations

import argparse
import os
import random
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager, suppress
from dataclasses import dataclass
from pathlib import Path

BIN = Path(sys.executable).parent
SIGNALS = ("INT", "TERM", "HUP", "KILL")
LOADS = ("idle", "loaded")
STARTUP_S = 90.0  # longest wait for "nodes up"
POLL_S = 0.005


@dataclass(frozen=True)
class Ending:
    """One trial: seconds until nothing of the run was left (None: past the deadline)."""

    seconds: float | None
    code: int | None  # the demo's exit status (negative: the signal that ended it)


def session_processes(sid: int) -> list[int]:
    """The live (not zombie) processes of session ``sid``, from /proc/<pid>/stat."""
    out = []
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/stat", "rb") as f:
                fields = f.read().rsplit(b")", 1)[1].split()
        except OSError:
            continue  # gone meanwhile
        if int(fields[3]) == sid and fields[0] != b"Z":  # fields[0]: state, [3]: session
            out.append(int(entry))
    return out


@contextmanager
def busy_loops(n: int) -> Iterator[list[subprocess.Popen[bytes]]]:
    """``n`` busy Python processes, stopped (SIGSTOP) until a loaded trial continues them."""
    procs = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(n)]
    try:
        for p in procs:
            p.send_signal(signal.SIGSTOP)
        yield procs
    finally:
        for p in procs:
            p.kill()
            p.wait()


def trial(signum: int, domain: int, work: Path, deadline: float) -> Ending:
    """Start the demo, signal it once its nodes are up, time until its session is empty."""
    out_dir = work / "out"
    proc = subprocess.Popen(
        [str(BIN / "diffdrive-odom"), "demo", "--short", "--no-plot", "--no-bag",
         "--output", str(out_dir), "--domain-id", str(domain)],
        stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, start_new_session=True)
    try:
        assert proc.stdout is not None
        started = time.monotonic()
        for line in proc.stdout:
            if "nodes up" in line:
                break
            if time.monotonic() - started > STARTUP_S:
                raise RuntimeError("the demo did not start its nodes")
        else:
            raise RuntimeError(f"the demo ended before its nodes were up ({proc.wait()})")
        t0 = time.monotonic()
        os.kill(proc.pid, signum)
        while time.monotonic() - t0 < deadline:
            proc.poll()  # reaps the demo once it has exited
            if proc.returncode is not None and not session_processes(proc.pid):
                return Ending(time.monotonic() - t0, proc.returncode)
            time.sleep(POLL_S)
        return Ending(None, proc.poll())
    finally:
        for pid in session_processes(proc.pid):
            with suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
        proc.wait()
        if proc.stdout is not None:
            proc.stdout.close()


def cell(values: Sequence[Ending], deadline: float) -> str:
    """``median / slowest`` seconds; ``>deadline`` where something was left."""
    done = [e.seconds for e in values if e.seconds is not None]
    left = len(values) - len(done)
    if left:
        return f">{deadline:g} s ({left} of {len(values)} left)"
    return f"{statistics.median(done):5.2f} / {max(done):5.2f}"


def codes(values: Sequence[Ending]) -> str:
    found = sorted({e.code for e in values}, key=lambda c: (c is None, c or 0))
    return ",".join("-" if c is None else str(c) for c in found)


def _interrupt(signum: int, frame: object) -> None:
    raise KeyboardInterrupt  # SIGTERM/SIGHUP as Ctrl-C: the busy loops and demos go too


def main(argv: Sequence[str] | None = None) -> int:
    for s in (signal.SIGTERM, signal.SIGHUP):
        signal.signal(s, _interrupt)
    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument("--count", type=int, default=20, help="trials per signal and load")
    ap.add_argument("--signals", default=",".join(SIGNALS),
                    help="signals sent to the demo, comma separated")
    ap.add_argument("--busy", type=int, default=2, help="busy processes of a loaded trial")
    ap.add_argument("--deadline", type=float, default=60.0,
                    help="seconds after which a trial counts as leaving processes behind")
    ap.add_argument("--domain-id", type=int, default=None,
                    help="ROS_DOMAIN_ID of the demos (default: a random one)")
    ap.add_argument("--quick", action="store_true", help="1 trial per signal and load")
    args = ap.parse_args(argv)
    count = 1 if args.quick else args.count
    names = [s.strip().upper().removeprefix("SIG") for s in args.signals.split(",")]
    signums = {n: signal.Signals[f"SIG{n}"].value for n in names}
    domain = args.domain_id if args.domain_id is not None else random.randint(150, 230)
    results: dict[tuple[str, str], list[Ending]] = {(n, ld): [] for n in names for ld in LOADS}
    t_start = time.monotonic()
    with busy_loops(args.busy) as loops, tempfile.TemporaryDirectory() as tmp:
        for i in range(count):
            for name in names:
                for load in LOADS if i % 2 == 0 else LOADS[::-1]:
                    for p in loops:
                        p.send_signal(signal.SIGCONT if load == "loaded" else signal.SIGSTOP)
                    work = Path(tmp) / f"{name}-{load}-{i}"
                    work.mkdir()
                    results[(name, load)].append(
                        trial(signums[name], domain, work, args.deadline))
                    for p in loops:
                        p.send_signal(signal.SIGSTOP)
            print(f"  round {i + 1}/{count} done ({time.monotonic() - t_start:.0f} s)",
                  file=sys.stderr, flush=True)
    print(f"diffdrive-odom demo --short, one signal to the demo once its nodes are up: "
          f"seconds until no process of the run is left, median / slowest of {count} "
          f"(loaded: {args.busy} busy loops on {os.cpu_count()} cores)")
    head = f"{'signal':8s}  {'idle':>22s}  {'loaded':>22s}  demo exit codes"
    print(head)
    for name in names:
        idle, loaded = results[(name, "idle")], results[(name, "loaded")]
        print(f"SIG{name:5s}  {cell(idle, args.deadline):>22s}  "
              f"{cell(loaded, args.deadline):>22s}  {codes(idle + loaded)}")
    print(f"({time.monotonic() - t_start:.0f} s in all)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
