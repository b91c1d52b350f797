"""Full disks and failing devices in the bench's writers (issue 26, item 4): the Cliff-bot's
received map, the run's pictures and summary, the console copy of storage events, and
``safer-hil run --resume`` on a disk that is still full. The slow test runs a whole mission on a
1 MiB tmpfs (root only) and checks the run ends with one line, never a traceback."""

from __future__ import annotations

import errno
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from fsw.comm.link import LinkConfig
from fsw.core.codec.mapcodec import encode_map
from fsw.core.geometry import MapGrid
from fsw.framework.storage import StorageError
from fsw.framework.telemetry import Event, Severity
from hil_sim import cliffbot_receiver as cr
from hil_sim.cli import main
from hil_sim.mission import mission_report as mr
from hil_sim.mission import run_dir, run_spec

FAULTS = [errno.ENOSPC, errno.EIO]
NAMES = {errno.ENOSPC: "ENOSPC", errno.EIO: "EIO"}


def _raise(code: int) -> Any:
    def fail(*args: Any, **kwargs: Any) -> None:
        raise OSError(code, os.strerror(code))
    return fail


class _NoPort:
    def recv(self, timeout_s: float = 0.0, now_s: float = 0.0) -> None:
        return None

    def send(self, data: bytes, now_s: float = 0.0) -> None:
        pass


@pytest.mark.parametrize("code", FAULTS, ids=NAMES.get)
def test_cliffbot_keeps_a_map_it_cannot_save(tmp_path: Path, code: int, monkeypatch: pytest.MonkeyPatch,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    """req(26.4): the map stays decoded in memory, the report says why it was not saved, one
    MAP_NOT_SAVED line on stderr, no file left under a final name."""
    z = np.linspace(0.0, 0.5, 40 * 30, dtype=np.float32).reshape(40, 30)
    data = encode_map(z, cell_m=0.03, wheel_diameter_m=0.2).data
    bot = cr.Cliffbot(LinkConfig(), _NoPort(), tmp_path)  # type: ignore[arg-type]
    monkeypatch.setattr(cr, "write_figure13", _raise(code))
    rep = bot._report(1, data)
    assert rep.decoded and rep.png == "" and NAMES[code] in rep.save_error and 1 in bot.maps
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "MAP_NOT_SAVED map 1" in err and NAMES[code] in err
    assert list(tmp_path.iterdir()) == []
    monkeypatch.undo()
    rep = bot._report(2, data)  # room again: saved as usual
    assert rep.save_error == "" and Path(rep.png).is_file() and (tmp_path / "cliffbot_map_2.npy").is_file()


def _outputs(tmp_path: Path) -> tuple[dict[str, Any], Any, Any, MapGrid]:
    grid = MapGrid(x0=0.0, y0=0.0, cell=0.1, nx=8, ny=6)
    emap = type("M", (), {"z": np.zeros((6, 8)), "var": np.full((6, 8), 1e-4), "mapped": np.ones((6, 8), bool)})()
    summary = {"scenario": "lab", "method": "5", "seed": 0, "mapped_cells": 48,
               "steps": [{"step": 0, "mapped_cells": 48, "obtained_new_cells": 48, "expected_new_cells": 40,
                          "pose": {"x": 0.1, "y": 0.1}}]}
    return summary, emap, np.zeros((6, 8)), grid


@pytest.mark.parametrize("code", FAULTS, ids=NAMES.get)
def test_report_pictures_that_fail_are_listed_and_the_summary_still_written(
        tmp_path: Path, code: int, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    summary, emap, truth, grid = _outputs(tmp_path)
    monkeypatch.setattr(mr.np, "save", _raise(code))
    mr.write_outputs(tmp_path, summary, emap, truth, grid)
    monkeypatch.undo()
    written = json.loads((tmp_path / "summary.json").read_text())
    assert written["write_errors"] == [f"map_error.npy: {os.strerror(code)} ({NAMES[code]})"]
    assert "REPORT_FILE_NOT_SAVED" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["coverage.png", "map.png", "summary.json"]


@pytest.mark.parametrize("code", FAULTS, ids=NAMES.get)
def test_a_summary_that_cannot_be_written_is_one_line(tmp_path: Path, code: int,
                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    summary, emap, truth, grid = _outputs(tmp_path)
    (tmp_path / "summary.json").write_text("{}")  # an older summary stays whole
    monkeypatch.setattr(Path, "write_text", _raise(code))
    with pytest.raises(StorageError) as err:
        mr.write_outputs(tmp_path, summary, emap, truth, grid)
    monkeypatch.undo()
    assert "summary.json not written" in str(err.value) and NAMES[code] in str(err.value)
    assert "\n" not in str(err.value) and (tmp_path / "summary.json").read_text() == "{}"


def test_storage_events_reach_the_console(capsys: pytest.CaptureFixture[str]) -> None:
    """The quiet bench still prints CHECKPOINT_FAILED and TLOG_ERROR (one line each), and only those."""
    run_dir.echo_storage_events(Event(12.5, 7, "mission.CHECKPOINT_FAILED", Severity.WARNING_HI,
                                          "mission checkpoint failed: No space left on device (ENOSPC)"))
    run_dir.echo_storage_events(Event(13.0, 8, "mission.STEP", Severity.ACTIVITY_HI, "step 3"))
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and "mission.CHECKPOINT_FAILED" in err[0] and "ENOSPC" in err[0]


def test_resume_on_a_full_disk_says_so_in_one_line(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    """req(26.4): ``--resume`` on a disk that is still full: exit 1, one line, no traceback."""
    out = tmp_path / "run"
    out.mkdir()
    run_spec.write_manifest(run_spec.RunSpec(steps=1, out=out))

    def full(directory: Any, need: int) -> None:
        raise StorageError(errno.ENOSPC, f"{directory}: no room for {need} bytes (No space left on device (ENOSPC))")

    monkeypatch.setattr(run_dir, "probe", full)
    assert main(["run", "--resume", str(out)]) == 1
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert len(err) == 1 and "disk is full" in err[0] and "ENOSPC" in err[0] and "Traceback" not in err[0]


def _tmpfs(path: Path, size: str) -> bool:
    if os.geteuid() != 0 or shutil.which("mount") is None:
        return False
    path.mkdir(parents=True, exist_ok=True)
    return subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(path)],
                          capture_output=True).returncode == 0


@pytest.mark.slow
@pytest.mark.timeout(1800)
def test_mission_on_a_1mib_disk_ends_in_one_line_and_resume_refuses(tmp_path: Path) -> None:
    """req(26.4): the reviewer's case: ``--out`` on a small tmpfs. The panorama only (``--steps
    0``, the shortest mission that maps and transmits) on 1 MiB: the panorama's map checkpoints,
    the .tlog and the Cliff-bot's received map fill it mid-mission. Which flight writer meets the
    full disk first (a checkpoint or a batch of the .tlog) depends on the .tlog's length, which
    the run's timing telemetry varies; what holds either way:

    * every flight writer the disk refused said so: one console line each, ENOSPC named;
    * nothing written is lost or corrupt: the newest good checkpoint loads, no temporary is
      left; a .tlog never stopped holds every CHECKPOINT_FAILED the console printed, whole; a
      stopped one reads back up to where it stopped;
    * the mission goes on to its end: the run reaches its report, which lists what it could not
      write, or says in one last line that the summary did not fit (exit 1), never a traceback;
    * ``--resume`` on the still-full disk is one line, exit 1."""
    mnt = tmp_path / "disk"
    if not _tmpfs(mnt, "1m"):
        pytest.skip("needs root and tmpfs to make a small disk")
    try:
        run = mnt / "run"
        cmd = [sys.executable, "-m", "hil_sim.cli", "run", "--steps", "0", "--out", str(run)]
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=900)
        assert "Traceback" not in r.stderr and r.returncode in (0, 1), r.stderr[-2000:]
        lines = [ln for ln in r.stderr.replace("\r", "\n").splitlines() if ln.strip()]
        failed_checkpoints = [ln for ln in lines if "mission.CHECKPOINT_FAILED" in ln]
        tlog_errors = [ln for ln in lines if "mavlink.TLOG_ERROR" in ln]
        assert failed_checkpoints or tlog_errors, r.stderr[-2000:]  # the disk filled under a flight writer
        assert all("ENOSPC" in ln for ln in failed_checkpoints + tlog_errors), r.stderr[-2000:]

        from fsw.comm.mavlink_tlog import read_tlog
        from fsw.core.map.checkpoint import CheckpointConfig
        from fsw.drivers.map_store import MapStore

        latest = MapStore(CheckpointConfig(directory=str(run / "checkpoints"))).load_latest()
        assert latest.meta is not None and not latest.skipped, latest.skipped
        assert not list((run / "checkpoints").glob(".map_*.tmp"))
        records, tail = read_tlog(run / "fsw.tlog")
        assert records
        if not tlog_errors:  # the .tlog was never refused: all of it, whole
            assert tail is None
            assert bool(failed_checkpoints) == any(b"CHECKPOINT_FAILED" in f for _, f in records)

        summary = run / "summary.json"
        if r.returncode == 1:  # no room left for the summary: said in one last line
            assert lines[-1].startswith("safer-hil run: ") and "summary.json not written" in lines[-1]
        else:  # the summary fitted: the mission's end, and what did not fit
            s = json.loads(summary.read_text())
            assert s["final_state"] == "DONE"
            assert s["write_errors"] or s["cliffbot"]["save_error"] or failed_checkpoints
        summary.unlink(missing_ok=True)  # not finished: --resume must try
        with (mnt / "filler").open("wb") as fh:  # the disk stays full
            try:
                while True:
                    fh.write(bytes(65536))
                    fh.flush()
            except OSError:
                pass
        r2 = subprocess.run([sys.executable, "-m", "hil_sim.cli", "run", "--resume", str(run)],
                            capture_output=True, text=True, timeout=300)
        err = [ln for ln in r2.stderr.splitlines() if ln.strip()]
        assert r2.returncode == 1 and len(err) == 1 and "disk is full" in err[0], r2.stderr
    finally:
        subprocess.run(["umount", str(mnt)], capture_output=True)
