"""A campaign worker that dies takes its mission with it, and Dask stays on 127.0.0.1
(issue 26, item 7; issue 31, item 2).

A worker (a plain process, then a Dask worker process) runs a smoke mission through
``run_isolated``; it is SIGKILLed while the mission runs. The mission process must end within
seconds and its temporary folder must be gone. The Dask scheduler and workers started with the
flags docs/experiments.md gives listen on loopback only."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import psutil
import pytest
from loopback import family, off_machine_sockets

from fsw.settings import DEFAULT_CONFIG
from hil_sim.lab.campaign.child import ORPHAN_EXIT, TMP_PREFIX
from hil_sim.lab.campaign.execute import mission_dict, run_isolated
from hil_sim.lab.campaign.spec import expand, load_spec

pytestmark = [pytest.mark.slow, pytest.mark.req("26.7")]
SMOKE = DEFAULT_CONFIG.parent / "campaigns" / "smoke.toml"
DOCS = Path(__file__).resolve().parents[3] / "docs" / "experiments.md"


def mission() -> dict[str, Any]:
    return mission_dict(expand(load_spec(SMOKE))[0])  # ~12 s of CPU: long enough to be killed in flight


def mission_child(parent: int, timeout_s: float = 30.0) -> psutil.Process:
    """The mission process ``parent`` started."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        for p in psutil.Process(parent).children():
            try:
                if "hil_sim.lab.campaign.child" in p.cmdline():
                    return p
            except psutil.NoSuchProcess:
                continue
        time.sleep(0.05)
    raise AssertionError(f"no mission process under {parent}")


def kill_and_check(worker: int) -> None:
    child = mission_child(worker)
    folder = Path(child.cmdline()[-2]).parent
    assert folder.name.startswith(TMP_PREFIX) and folder.is_dir()
    time.sleep(0.5)  # the mission under way (either order is covered: a parent gone at start counts too)
    os.kill(worker, signal.SIGKILL)
    gone, alive = psutil.wait_procs([child], timeout=15)
    for p in alive:
        p.kill()
    assert not alive, "the mission outlived its worker"
    assert gone[0].returncode in (ORPHAN_EXIT, None)  # None: reaped by init before we looked
    assert not folder.exists()


def test_a_killed_local_worker_stops_its_mission_and_removes_its_folder() -> None:
    code = ("import json, sys; from hil_sim.lab.campaign.execute import run_isolated; "
            "run_isolated(json.loads(sys.argv[1]))")
    worker = subprocess.Popen([sys.executable, "-c", code, json.dumps(mission())])
    try:
        kill_and_check(worker.pid)
    finally:
        worker.kill()
        worker.wait()


def test_a_killed_dask_worker_stops_its_mission() -> None:
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=True, host="127.0.0.1",
                                  dashboard_address="127.0.0.1:0") as cluster, distributed.Client(cluster) as client:
        assert off_machine_sockets(family(os.getpid())) == []
        fut = client.submit(run_isolated, mission(), pure=False)
        (worker,) = client.run(os.getpid).values()
        try:
            kill_and_check(worker)
        finally:
            client.cancel(fut)


def _doc_commands() -> list[str]:
    block = DOCS.read_text().split("### Running it locally and on a cluster", 1)[1].split("```")[1]
    return [ln.split(" &", 1)[0].strip() for ln in block.splitlines() if ln.startswith("dask ")]


def test_the_documented_dask_cluster_listens_on_loopback_only(tmp_path: Path) -> None:
    """docs/experiments.md's `dask scheduler` and `dask worker` lines (their ports moved to free
    ones so a concurrent run cannot collide): every socket on 127.0.0.1, dashboards included."""
    cmds = _doc_commands()
    assert [c.split()[1] for c in cmds] == ["scheduler", "worker"]
    port = _free_port()
    dask = str(Path(sys.executable).parent / "dask")
    procs = []
    try:
        for c in cmds:
            argv = re.sub(r"127\.0\.0\.1:8787\b", "127.0.0.1:0", c.replace("8786", str(port))).split()
            procs.append(subprocess.Popen([dask, *argv[1:]], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                          cwd=tmp_path))
        distributed = pytest.importorskip("distributed")
        with distributed.Client(f"tcp://127.0.0.1:{port}", timeout="30s") as client:
            client.wait_for_workers(2, timeout=60)
            pids = [pid for p in procs for pid in family(p.pid)]
            listening = [c for pid in pids for c in psutil.Process(pid).net_connections("inet") if c.status == "LISTEN"]
            assert len(listening) >= 4  # scheduler + its HTTP server, each worker and its HTTP server
            assert off_machine_sockets(pids) == []
    finally:
        for p in procs:
            p.send_signal(signal.SIGINT)
        for p in procs:
            try:
                p.wait(timeout=20)
            except subprocess.TimeoutExpired:
                p.kill()


def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])
