"""Running a campaign's missions: a local pool or a Dask cluster, resumable, with progress.

Each mission runs in a child process of its own (``hil_sim.lab.campaign.child``, which dies with
the worker that started it) under a wall-clock limit, so a mission that raises, hangs or dies
(segfault, out of memory) is a recorded outcome (``error`` / ``killed``), never a lost
campaign. The local executor is a
thread pool of ``jobs`` threads, each waiting on one child; with a scheduler address the same
function runs as Dask tasks (``dask.distributed``) on the cluster's workers, which need only
the project installed: the rows come back to this process, which stores each one atomically
as ``DIR/missions/<id>.json``. A rerun reuses every stored row whose mission inputs are
unchanged (:meth:`hil_sim.lab.campaign.spec.Mission.key`) and runs the rest. Ctrl-C stops the
campaign: missions it interrupted are not stored (a rerun runs them), finished ones are kept.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor, as_completed
from dataclasses import asdict
from pathlib import Path
from typing import Any

from hil_sim.lab.campaign.child import TMP_PREFIX
from hil_sim.lab.campaign.spec import Mission
from hil_sim.lab.campaign.table import failed_row

FAILED = ("error", "killed")


def mission_dict(m: Mission) -> dict[str, Any]:
    return {**asdict(m), "faults": list(m.faults), "key": m.key()}


def run_isolated(m: dict[str, Any]) -> dict[str, Any]:
    """Run one mission in a child process; its row, or an ``error``/``killed`` row. Never raises."""
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix=TMP_PREFIX, ignore_cleanup_errors=True) as tmp:
        result = Path(tmp) / "row.json"
        try:
            proc = subprocess.run(  # the child dies with this process (hil_sim.lab.campaign.child.die_with_parent)
                [sys.executable, "-m", "hil_sim.lab.campaign.child", str(result), str(os.getpid())],
                input=json.dumps(m), capture_output=True, text=True, timeout=m["timeout_s"], check=False,
            )
        except subprocess.TimeoutExpired:
            return failed_row(m, "killed", f"timeout: no result after {m['timeout_s']:g} s wall clock",
                              time.perf_counter() - t0)
        except OSError as exc:
            return failed_row(m, "error", f"could not start the mission process: {exc}", time.perf_counter() - t0)
        if proc.returncode == -signal.SIGINT:  # Ctrl-C reached the mission: not a result, run it again
            raise KeyboardInterrupt
        if proc.returncode != 0 or not result.is_file():
            last = (proc.stderr.strip().splitlines() or ["no output"])[-1]
            return failed_row(m, "killed", f"mission process exit code {proc.returncode}: {last}",
                              time.perf_counter() - t0)
        row: dict[str, Any] = json.loads(result.read_text())
        return row


class Store:
    """Rows stored one file a mission (``DIR/missions/<id>.json``), written atomically."""

    def __init__(self, out: Path) -> None:
        self.dir = out / "missions"
        self.dir.mkdir(parents=True, exist_ok=True)

    def get(self, m: dict[str, Any]) -> dict[str, Any] | None:
        p = self.dir / f"{m['id']}.json"
        try:
            row: dict[str, Any] = json.loads(p.read_text())
        except (OSError, ValueError):
            return None  # absent or half-written by a killed older run: run again
        return row if row.get("key") == m["key"] else None

    def put(self, row: dict[str, Any]) -> None:
        p = self.dir / f"{row['id']}.json"
        tmp = p.with_suffix(".json.tmp")
        tmp.write_text(json.dumps(row, indent=1))
        os.replace(tmp, p)


def _local(missions: list[dict[str, Any]], jobs: int, fn: Callable[[dict[str, Any]], dict[str, Any]]
           ) -> Iterator[tuple[dict[str, Any], dict[str, Any]]]:
    pool = ThreadPoolExecutor(max_workers=jobs)
    try:
        futs = {pool.submit(fn, m): m for m in missions}
        for fut in as_completed(futs):
            yield futs[fut], fut.result()
    finally:  # on Ctrl-C: start no more missions (running children got the SIGINT too)
        pool.shutdown(wait=False, cancel_futures=True)


def _dask(missions: list[dict[str, Any]], address: str, fn: Callable[[dict[str, Any]], dict[str, Any]]
          ) -> Iterator[tuple[dict[str, Any], dict[str, Any]]]:
    from dask.distributed import Client
    from dask.distributed import as_completed as dask_completed

    t0 = time.perf_counter()
    with Client(address, timeout="30s") as client:
        futs = [client.submit(fn, m, pure=False, key=f"mission-{m['id']}-{m['key']}") for m in missions]
        by_key = {f.key: m for f, m in zip(futs, missions, strict=True)}
        try:
            for fut in dask_completed(futs):
                m = by_key[fut.key]
                try:
                    row = fut.result()
                except Exception as exc:  # noqa: BLE001 - e.g. KilledWorker: the worker died under it
                    row = failed_row(m, "killed", f"dask: {type(exc).__name__}: {exc}", time.perf_counter() - t0)
                yield m, row
        finally:  # on Ctrl-C or an error here: the cluster drops what is left
            client.cancel(futs)


def execute(
    missions: list[Mission], out: Path, jobs: int = 2, scheduler: str | None = None, retry_failed: bool = False,
    fn: Callable[[dict[str, Any]], dict[str, Any]] = run_isolated, show_progress: bool = True,
    report_only: bool = False,
) -> tuple[list[dict[str, Any]], int]:
    """Run the missions not yet stored; return all rows (stored and new) and how many were reused.
    With ``report_only`` nothing runs: the rows stored so far (a campaign stopped part-way)."""
    from tqdm import tqdm

    store = Store(out)
    dicts = [mission_dict(m) for m in missions]
    rows: dict[str, dict[str, Any]] = {}
    todo = []
    for m in dicts:
        old = store.get(m)
        if old is not None and not (retry_failed and old["outcome"] in FAILED):
            rows[m["id"]] = old
        else:
            todo.append(m)
    reused = len(rows)
    if report_only:
        return [rows[m["id"]] for m in dicts if m["id"] in rows], reused
    failed = sum(r["outcome"] in FAILED for r in rows.values())
    where = scheduler or f"{jobs} local job{'s' * (jobs > 1)}"
    with tqdm(total=len(dicts), initial=reused, unit="mission", desc=f"campaign ({where})",
              disable=not show_progress) as bar:
        def status() -> None:
            bar.set_postfix_str(f"done {len(rows) - failed} failed {failed} remaining {len(dicts) - len(rows)}")

        status()
        if todo:
            it = _dask(todo, scheduler, fn) if scheduler else _local(todo, jobs, fn)
            for m, row in it:
                store.put(row)
                rows[m["id"]] = row
                failed += row["outcome"] in FAILED
                bar.update()
                status()
    return [rows[m["id"]] for m in dicts], reused
