"""A fleet's bags through ``replay``: processes or a Dask cluster, one table, failures named.

Expected outputs are what ``replay`` writes for each bag alone (same bytes); the
order is the order the bags were given, whatever finished first.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
import time
from pathlib import Path

import pytest

from diffdrive_odom.tools.cli import main as cli

from bagutil import OPTIODOM_PARAMS, write_params
from rosutil import DATA, kill_left, running, still_running

pytestmark = [pytest.mark.process]

RUNS = [DATA / "optiodom" / r for r in
        ("square_231220200029_run-04", "square_231220200029_run-01")]


def _alone(tmp_path: Path, params: Path) -> dict[str, bytes]:
    out = {}
    for bag in RUNS:
        csv = tmp_path / f"alone_{bag.name}.csv"
        assert cli(["replay", str(bag), "--params-file", str(params), "--csv", str(csv)]) == 0
        out[bag.name] = csv.read_bytes()
    return out


def _check(tmp_path: Path, capsys: pytest.CaptureFixture[str], extra: list[str]) -> None:
    params = write_params(tmp_path / "p.yaml", OPTIODOM_PARAMS)
    alone = _alone(tmp_path, params)
    capsys.readouterr()
    missing = tmp_path / "no_such_bag"
    bags = [str(RUNS[0]), str(missing), str(RUNS[1])]
    status = cli(["replay", *bags, "--params-file", str(params),
                  "--csv", str(tmp_path / "fleet"), *extra])
    out, err = capsys.readouterr()
    assert status == 1  # one bag failed
    for bag in RUNS:
        assert (tmp_path / "fleet" / f"{bag.name}.csv").read_bytes() == alone[bag.name]
    assert not (tmp_path / "fleet" / "no_such_bag.csv").exists()
    # Each bag's block, then the table, in the order given.
    blocks = [out.index(f"[replay] {b}:") for b in bags]
    assert blocks == sorted(blocks)
    table = out[out.index("\nbag "):].splitlines()[2:5]
    assert [row.split()[0] for row in table] == bags
    assert [row.split()[1] for row in table] == ["ok", "FAILED", "ok"]
    assert str(missing) in err and "no_such_bag" in table[1]
    assert "2 of 3 bags done, 1 failed" in out


def test_fleet_on_processes(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    _check(tmp_path, capsys, ["--jobs", "2"])


def test_fleet_on_a_dask_cluster(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    distributed = pytest.importorskip(
        "distributed", reason="dask.distributed is not installed (the optional extra 'fleet')")
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as cluster:
        _check(tmp_path, capsys, ["--dask", cluster.scheduler_address])


def test_fleet_refuses_what_cannot_work(tmp_path: Path,
                                        capsys: pytest.CaptureFixture[str]) -> None:
    params = write_params(tmp_path / "p.yaml", OPTIODOM_PARAMS)
    bags = [str(b) for b in RUNS]
    assert cli(["replay", *bags, "--params-file", str(params), "--csv", str(tmp_path),
                "--jobs", "0"]) == 2
    assert "--jobs must be >= 1" in capsys.readouterr().err
    assert cli(["replay", bags[0], bags[0], "--params-file", str(params), "--csv",
                str(tmp_path)]) == 2
    assert "same name" in capsys.readouterr().err


def test_eval_fleet(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Replay's outputs (input kept, so each holds its ground truth) judged as a fleet."""
    params = write_params(tmp_path / "p.yaml", OPTIODOM_PARAMS)
    assert cli(["replay", *map(str, RUNS), "--params-file", str(params), "-o",
                str(tmp_path / "out"), "--keep-input", "--jobs", "2"]) == 0
    outs = [str(tmp_path / "out" / b.name) for b in RUNS]
    alone = []
    for k, bag in enumerate(outs):
        assert cli(["eval", bag, "--json", str(tmp_path / f"alone{k}.json")]) == 0
        alone.append((tmp_path / f"alone{k}.json").read_bytes())
    capsys.readouterr()
    status = cli(["eval", outs[0], str(tmp_path / "missing"), outs[1], "--json",
                  str(tmp_path / "figures"), "--jobs", "2"])
    out, _ = capsys.readouterr()
    assert status == 1
    for k, run in enumerate(RUNS):
        assert (tmp_path / "figures" / f"{run.name}.json").read_bytes() == alone[k]
    assert "2 of 3 bags done, 1 failed" in out


def test_calibrate_decodes_its_bags_in_parallel(tmp_path: Path,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    """The same fit whatever the processes; every bag that fails is named, no fit made."""
    nominal = ["-p", "wheel_radius:=0.042", "-p", "wheel_separation:=0.2", "--force"]
    bags = [str(b) for b in RUNS]
    outs = []
    for jobs in ("1", "2"):
        assert cli(["calibrate", *bags, *nominal, "--jobs", jobs]) == 0
        outs.append(re.sub(r"[\d.]+ s\b", "", capsys.readouterr().out))  # time taken
    assert outs[0] == outs[1] and "/**:" in outs[0]
    missing = [str(tmp_path / "gone1"), str(tmp_path / "gone2")]
    assert cli(["calibrate", bags[0], *missing, *nominal, "--jobs", "2"]) == 2
    err = capsys.readouterr().err
    assert "2 of 3 bags failed, so no fit" in err
    assert all(m in err for m in missing)


# A fleet whose two workers are each on a long call (a bag that takes ten minutes).
LONG_FLEET = r"""
import time
from diffdrive_odom.tools.fleet import map_calls
map_calls(time.sleep, [(600.0,), (600.0,)], 2, None)
"""


def children_of(pid: int) -> list[int]:
    """The running processes whose parent is ``pid`` (from /proc)."""
    out = []
    for entry in os.listdir("/proc"):
        try:
            with open(f"/proc/{entry}/stat", "rb") as f:
                ppid = int(f.read().rsplit(b")", 1)[1].split()[1])
        except (OSError, ValueError, IndexError):
            continue
        if ppid == pid and running(int(entry)):
            out.append(int(entry))
    return out


def _is_pool_worker(pid: int) -> bool:
    """A spawned pool worker (not multiprocessing's resource tracker, also a child)."""
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as f:
            return b"spawn_main" in f.read()
    except OSError:
        return False


def test_the_pool_workers_end_when_the_fleet_is_killed() -> None:
    """SIGKILL to the fleet's process runs none of the pool's shutdown: its workers used
    to go on with their bags, then wait for work under init forever."""
    fleet = subprocess.Popen([sys.executable, "-c", LONG_FLEET])
    workers: list[int] = []
    try:
        deadline = time.monotonic() + 30.0
        while len(workers) < 2 and time.monotonic() < deadline:
            assert fleet.poll() is None
            time.sleep(0.05)
            workers = [p for p in children_of(fleet.pid) if _is_pool_worker(p)]
        assert len(workers) == 2, workers
        time.sleep(0.5)  # each on its call by now
        fleet.kill()
        fleet.wait()
        assert not still_running(workers, 30.0), "pool workers outlived the fleet"
    finally:
        kill_left(fleet, workers)
