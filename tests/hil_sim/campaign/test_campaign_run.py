"""Campaign execution (issue 16, item 2, "Done when"): the 4-mission smoke campaign runs on the
local pool, and its Method 5 missions give the same rows (wall-clock fields aside) on a Dask
LocalCluster of 2 worker processes on 127.0.0.1; a rerun skips the stored missions; a mission that raises is recorded
as ``error`` and one past its wall-clock limit as ``killed`` while the others finish.

The runs use the smoke spec with ``steps = 0`` (the panorama only, ~5 s of CPU a mission
instead of ~12 s): the same 4 missions (both methods, clean and with the camera dropout, which
still sends the mission to SAFE and back), so every column of the table is filled; the
table's per-step join is checked in test_campaign_report.py. Ctrl-C uses the smoke spec itself
(missions long enough to be interrupted in flight)."""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow.parquet as pq
import pytest

from fsw.settings import DEFAULT_CONFIG
from hil_sim.cli import main
from hil_sim.lab.campaign.execute import execute
from hil_sim.lab.campaign.spec import expand, load_spec
from hil_sim.lab.campaign.table import WALL_CLOCK_COLUMNS

pytestmark = [pytest.mark.slow, pytest.mark.timeout(1800)]
SMOKE = DEFAULT_CONFIG.parent / "campaigns" / "smoke.toml"


def panorama_only(text: str) -> str:
    """The smoke spec's text with ``steps = 0`` (the missions end after the panorama)."""
    out, n = re.subn(r"(?m)^steps = \d+", "steps = 0", text)
    assert n == 1, "smoke.toml has no 'steps = N' line"
    return out


@pytest.fixture(scope="module")
def spec(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("spec") / "smoke.toml"
    path.write_text(panorama_only(SMOKE.read_text()))
    return path


def table(out: Path) -> list[dict[str, Any]]:
    rows = pq.read_table(out / "results.parquet").to_pylist()
    return [{k: v for k, v in r.items() if k not in WALL_CLOCK_COLUMNS} for r in rows]


@pytest.fixture(scope="module")
def local_run(tmp_path_factory: pytest.TempPathFactory, spec: Path) -> Path:
    out = tmp_path_factory.mktemp("local")
    assert main(["campaign", str(spec), "--out", str(out), "--jobs", "2"]) == 0
    return out


def test_local_pool_runs_the_smoke_campaign(local_run: Path) -> None:
    rows = table(local_run)
    assert len(rows) == 4 and {r["method"] for r in rows} == {"5", "oracle"}
    assert {r["fault_set"] for r in rows} == {"none", "camera_dropout"}
    for r in rows:
        assert r["outcome"] in ("done", "safe", "time_limit", "edge_violation"), r
        assert r["mapped_cells"] > 0 and r["map_rmse_m"] is not None and 0.0 <= r["calib_2sigma"] <= 1.0
        assert r["mapped_cells_per_step"].split(";")[-1] == str(r["mapped_cells"])
    md = (local_run / "report.md").read_text()
    assert "Campaign smoke: 4 missions" in md and (local_run / "results.csv").is_file()


def test_rerun_skips_finished_missions(local_run: Path, spec: Path) -> None:
    missions = expand(load_spec(spec))
    before = {p.name: p.stat().st_mtime_ns for p in (local_run / "missions").glob("*.json")}

    def must_not_run(m: dict[str, Any]) -> dict[str, Any]:
        raise AssertionError(f"{m['id']} ran again")

    rows, reused = execute(missions, local_run, jobs=2, fn=must_not_run, show_progress=False)
    assert reused == 4 and len(rows) == 4
    assert before == {p.name: p.stat().st_mtime_ns for p in (local_run / "missions").glob("*.json")}
    # a report from the stored missions only (a campaign stopped part-way): nothing runs
    (local_run / "missions" / f"{missions[0].id}.json").rename(local_run / "held.json")
    assert main(["campaign", str(spec), "--out", str(local_run), "--report-only"]) == 0
    assert len(pq.read_table(local_run / "results.parquet")) == 3
    assert "a partial campaign: 3 of 4 missions" in (local_run / "report.md").read_text()
    (local_run / "held.json").rename(local_run / "missions" / f"{missions[0].id}.json")
    assert main(["campaign", str(spec), "--out", str(local_run), "--report-only"]) == 0  # the full table again
    assert len(pq.read_table(local_run / "results.parquet")) == 4
    assert main(["campaign", str(spec), "--out", str(local_run / "empty"), "--report-only"]) == 1
    # a changed mission (another step count) is not reused
    changed = [dataclasses.replace(missions[0], steps=missions[0].steps + 1)]
    ran: list[str] = []

    def record(m: dict[str, Any]) -> dict[str, Any]:
        ran.append(m["id"])
        from hil_sim.lab.campaign.table import failed_row

        return failed_row(m, "error", "not run in this test", 0.0)

    execute(changed, local_run / "other", jobs=1, fn=record, show_progress=False)
    _, reused = execute(changed, local_run, jobs=1, fn=record, show_progress=False)
    assert reused == 0 and ran == [changed[0].id] * 2


def test_dask_local_cluster_gives_the_same_table(local_run: Path, spec: Path, tmp_path: Path) -> None:
    """The Method 5 half of the campaign (clean and camera dropout: one mission per worker) on
    a 2-process Dask cluster: the same rows as the local pool's."""
    distributed = pytest.importorskip("distributed")
    half = tmp_path / "smoke.toml"
    text = spec.read_text()
    assert 'methods = ["5", "oracle"]' in text
    half.write_text(text.replace('methods = ["5", "oracle"]', 'methods = ["5"]'))
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                                  dashboard_address="127.0.0.1:0") as cluster:
        assert main(["campaign", str(half), "--out", str(tmp_path), "--scheduler", cluster.scheduler_address]) == 0
    local = [r for r in table(local_run) if r["method"] == "5"]
    assert len(local) == 2 and {r["fault_set"] for r in local} == {"none", "camera_dropout"}
    assert table(tmp_path) == local


def test_raising_and_hanging_missions_are_recorded_and_others_finish(tmp_path: Path) -> None:
    dem = tmp_path / "bad.npy"
    arr = np.zeros((64, 64), np.float32)
    arr[5, 5] = np.nan  # passes the spec check (a path), fails when the world is built
    np.save(dem, arr)
    spec = tmp_path / "spec.toml"
    spec.write_text(panorama_only(SMOKE.read_text()).replace('methods = ["5", "oracle"]', 'methods = ["oracle"]')
                    .replace('mode = "cross"', 'mode = "sample"\nfraction = 0.0')
                    + f'\n[[families]]\nname = "baddem"\nscenario = "file:{dem}"\n')
    assert main(["campaign", str(spec), "--out", str(tmp_path / "a")]) == 1  # 1: a mission raised
    rows = {r["family"]: r for r in pq.read_table(tmp_path / "a" / "results.parquet").to_pylist()}
    assert rows["baddem"]["outcome"] == "error" and "ScenarioError" in rows["baddem"]["error"]
    assert rows["lab"]["outcome"] != "error" and rows["lab"]["mapped_cells"] > 0
    assert "baddem" in (tmp_path / "a" / "report.md").read_text()

    spec.write_text(spec.read_text().replace("timeout_s = 900.0", "timeout_s = 2.0"))
    assert main(["campaign", str(spec), "--out", str(tmp_path / "b"), "--jobs", "1"]) == 1
    rows = {r["family"]: r for r in pq.read_table(tmp_path / "b" / "results.parquet").to_pylist()}
    assert rows["lab"]["outcome"] == "killed" and "timeout" in rows["lab"]["error"]


def _mission_processes(pgid: int) -> list[int]:
    """The campaign's mission children (``hil_sim.lab.campaign.child``) in process group ``pgid``."""
    import os

    found = []
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            if os.getpgid(int(d.name)) == pgid and b"hil_sim.lab.campaign.child" in (d / "cmdline").read_bytes():
                found.append(int(d.name))
        except OSError:  # gone meanwhile
            continue
    return found


def test_ctrl_c_stores_no_interrupted_mission(tmp_path: Path) -> None:
    import os
    import signal
    import subprocess
    import sys
    import time

    proc = subprocess.Popen([sys.executable, "-m", "hil_sim.cli", "campaign", str(SMOKE), "--out", str(tmp_path),
                             "--jobs", "2"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True,
                            # Ctrl-C as in a terminal, even when the suite runs as a background job
                            # (which starts its children with SIGINT ignored)
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    if Path("/proc/self/cmdline").is_file():
        t0 = time.monotonic()
        while len(_mission_processes(proc.pid)) < 2:  # both local jobs have started a mission
            assert proc.poll() is None and time.monotonic() - t0 < 120, "no mission processes"
            time.sleep(0.05)
        time.sleep(3.0)  # the missions are running (past their imports; a smoke mission takes ~12 s of CPU)
    else:  # no /proc to watch them start
        time.sleep(8.0)
    os.killpg(proc.pid, signal.SIGINT)  # as Ctrl-C in a terminal: the whole process group
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err.decode()[-500:]
    assert list((tmp_path / "missions").glob("*.json")) == []  # nothing half-run was recorded as a result
