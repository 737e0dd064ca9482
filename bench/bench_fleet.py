"""A fleet's bags: ``replay`` on 16 bags with 1 process, 2 processes and a 2-worker Dask cluster.

    .venv/bin/python bench/bench_fleet.py [--bags 16] [--readings 20000]

Wall time of ``diffdrive-odom replay BAG... --csv DIR`` (in this process, its output
swallowed) and the speed-up against one process. The Dask row starts a
``distributed.LocalCluster`` of 2 single-threaded worker processes first (not timed)
and is skipped, saying why, when dask.distributed is not installed.
"""

from __future__ import annotations

import argparse
import io
import shutil
import sys
import tempfile
import time
from contextlib import redirect_stderr, redirect_stdout
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

from bench_replay import _synthetic  # noqa: E402

from diffdrive_odom.tools.cli import main as cli  # noqa: E402


def _replay(bags: list[Path], params: Path, out: Path, extra: list[str]) -> float:
    shutil.rmtree(out, ignore_errors=True)
    t0 = time.perf_counter()
    with redirect_stdout(io.StringIO()), redirect_stderr(io.StringIO()):
        status = cli(["replay", *map(str, bags), "--params-file", str(params),
                      "--csv", str(out), *extra])
    seconds = time.perf_counter() - t0
    assert status == 0, status
    return seconds


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    ap.add_argument("--bags", type=int, default=16)
    ap.add_argument("--readings", type=int, default=20_000, help="readings per bag")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        params = tmp / "p.yaml"
        params.write_text("odometry_node:\n  ros__parameters:\n    wheel_radius: 0.05\n"
                          "    wheel_separation: 0.3\n", encoding="utf-8")
        bags = []
        for k in range(args.bags):
            bag = tmp / f"robot{k:02d}"
            _synthetic(bag, args.readings)
            bags.append(bag)
        rows = [("1 process", _replay(bags, params, tmp / "out1", ["--jobs", "1"])),
                ("2 processes", _replay(bags, params, tmp / "out2", ["--jobs", "2"]))]
        try:
            from distributed import LocalCluster
        except ImportError:
            print("dask.distributed not installed (pip install diffdrive_odom[fleet]): "
                  "no Dask row")
        else:
            cluster_cls: Any = LocalCluster  # untyped library
            with cluster_cls(n_workers=2, threads_per_worker=1, processes=True,
                              dashboard_address=None) as cluster:
                rows.append(("Dask LocalCluster, 2 workers",
                             _replay(bags, params, tmp / "outd",
                                     ["--dask", cluster.scheduler_address])))
    one = rows[0][1]
    total = args.bags * args.readings
    print(f"replay --csv on {args.bags} bags x {args.readings} readings")
    print(f"  {'how':30s} {'wall s':>8s} {'readings/s':>12s} {'speed-up':>9s}")
    for label, seconds in rows:
        print(f"  {label:30s} {seconds:8.2f} {total / seconds:12,.0f} {one / seconds:8.2f}x")
    return 0


if __name__ == "__main__":
    sys.exit(main())
