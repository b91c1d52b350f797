"""Full disks and failing devices in the flight writers (issue 26, item 4): the map store's
checkpoints, the mission's checkpoint step and the .tlog. ENOSPC and EIO are injected into the
write or fsync; each gives a one-line reason with the errno name, keeps the last good state and
raises no traceback out of the task."""

from __future__ import annotations

import errno
import io
import os
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from fsw.comm.mavlink_tlog import TlogWriter, read_tlog
from fsw.core.geometry import MapGrid
from fsw.core.map.checkpoint import CheckpointConfig
from fsw.core.map.elevation_map import ElevationMap
from fsw.drivers import map_store as ms
from fsw.framework.storage import StorageError, describe, is_disk_fault, probe
from fsw.tasks import mission_checkpoint as mc
from fsw.tasks.mission import MissionTask

FAULTS = [errno.ENOSPC, errno.EIO]
NAMES = {errno.ENOSPC: "ENOSPC", errno.EIO: "EIO"}
REAL_FSYNC = os.fsync


def _map(z: float = 0.1) -> ElevationMap:
    m = ElevationMap(MapGrid(x0=0.0, y0=0.0, cell=0.1, nx=8, ny=6))
    m.merge(np.array([[0.35, 0.25, z], [0.55, 0.45, z]]), cov=np.tile(np.eye(3) * 1e-4, (2, 1, 1)))
    return m


def _failing_fsync(code: int) -> Any:
    def fsync(fd: int) -> None:
        raise OSError(code, os.strerror(code))
    return fsync


@pytest.mark.parametrize("code", FAULTS, ids=NAMES.get)
def test_checkpoint_write_fault_keeps_the_newest_good_checkpoint(tmp_path: Path, code: int,
                                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    """req(26.4): a failed save leaves no temporary, prunes nothing, and the newest good
    checkpoint still loads; the error names the errno."""
    store = ms.MapStore(CheckpointConfig(directory=str(tmp_path), keep=2))
    store.save_next(_map(0.1), 1.0)
    store.save_next(_map(0.2), 2.0)
    before = [p.name for p in store.paths()]
    monkeypatch.setattr(ms.os, "fsync", _failing_fsync(code))
    with pytest.raises(OSError) as err:
        store.save_next(_map(0.3), 3.0)
    assert NAMES[code] in describe(err.value) and is_disk_fault(err.value)
    monkeypatch.undo()
    assert [p.name for p in store.paths()] == before
    assert not list(tmp_path.glob(".map_*.tmp"))
    latest = ms.MapStore(CheckpointConfig(directory=str(tmp_path))).load_latest()
    assert latest.meta is not None and latest.meta.time_s == 2.0 and not latest.skipped


@pytest.mark.parametrize("code", FAULTS, ids=NAMES.get)
def test_background_write_fault_is_reported_in_one_line(tmp_path: Path, code: int,
                                                         monkeypatch: pytest.MonkeyPatch) -> None:
    store = ms.MapStore(CheckpointConfig(directory=str(tmp_path)), background=True)
    try:
        monkeypatch.setattr(ms.os, "fsync", _failing_fsync(code))
        store.save_next(_map(), 1.0)
        store.flush()
        err = store.take_error()
        assert err is not None and NAMES[code] in err and "\n" not in err
    finally:
        monkeypatch.undo()
        store.close()


class _Mission:
    """The parts of the mission task that ``MissionTask.checkpoint`` touches."""

    def __init__(self, store: Any) -> None:
        self.ctx = SimpleNamespace(res=SimpleNamespace(map_store=store), clock=SimpleNamespace(now=lambda: 5.0))
        self.latest = SimpleNamespace(snapshot=_map())
        self.name = "mission"
        self.step = 3
        self.events: list[tuple[str, dict[str, Any]]] = []

    def section(self, phase: str) -> dict[str, Any]:
        return {"step": self.step, "phase": phase}

    def event(self, name: str, **args: Any) -> None:
        self.events.append((name, args))


@pytest.mark.parametrize("code", FAULTS, ids=NAMES.get)
def test_mission_checkpoint_fault_is_an_event_and_the_mission_goes_on(tmp_path: Path, code: int,
                                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    """req(26.4): the mission's checkpoint step turns the fault into CHECKPOINT_FAILED (the
    console and the .tlog carry events) and returns normally; a later save succeeds."""
    store = ms.MapStore(CheckpointConfig(directory=str(tmp_path)))
    m = _Mission(store)
    monkeypatch.setattr(mc, "full_state", lambda ctx, own, section: dict(section))
    monkeypatch.setattr(ms.os, "fsync", _failing_fsync(code))
    MissionTask.checkpoint(m, "SELECT")  # type: ignore[arg-type]
    assert m.events == [("CHECKPOINT_FAILED", {"error": f"{os.strerror(code)} ({NAMES[code]})"})]
    monkeypatch.setattr(ms.os, "fsync", REAL_FSYNC)  # the disk has room again
    MissionTask.checkpoint(m, "SELECT")  # type: ignore[arg-type]
    assert m.events[-1][0] == "CHECKPOINT_SAVED" and len(store.paths()) == 1


class _FullStream(io.BytesIO):
    """A stream that takes ``room`` bytes, then fails every write with ``code``."""

    def __init__(self, room: int, code: int) -> None:
        super().__init__()
        self.room, self.code = room, code

    def write(self, b: Any) -> int:
        if self.tell() + len(b) > self.room:
            raise OSError(self.code, os.strerror(self.code))
        return super().write(b)


@pytest.mark.parametrize("code", FAULTS, ids=NAMES.get)
def test_tlog_stops_on_a_disk_fault_and_keeps_its_records(tmp_path: Path, code: int) -> None:
    """req(26.4): the writer stops at the first disk fault (one line, errno named), counts the
    records it drops, and every record written before reads back."""
    frame = bytes([0xFD, 1, 0, 0, 0, 1, 1, 0, 0, 0, 0, 0, 0])  # a MAVLink 2 frame: 1-byte payload
    stream = _FullStream(10 * (8 + len(frame)) + 5, code)
    w = TlogWriter(stream)
    ok = [w.write(1.0 + k, frame) for k in range(15)]
    assert ok == [True] * 10 + [False] * 5
    assert w.stopped and w.errors == 1 and w.dropped == 4 and NAMES[code] in w.last_error
    assert "\n" not in w.last_error and "10 records" in w.last_error
    path = tmp_path / "x.tlog"
    path.write_bytes(stream.getvalue())
    records, tail = read_tlog(path)
    assert len(records) == 10 and tail is None


def test_probe_says_a_full_disk_in_one_line(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    probe(tmp_path / "ok", 4096)
    assert not list((tmp_path / "ok").iterdir())  # the probe leaves nothing behind
    monkeypatch.setattr(os, "fsync", _failing_fsync(errno.ENOSPC))
    with pytest.raises(StorageError) as err:
        probe(tmp_path / "ok", 4096)
    assert "ENOSPC" in str(err.value) and "\n" not in str(err.value) and "Errno" not in str(err.value)
    assert not list((tmp_path / "ok").iterdir())


class _FullRaw(io.RawIOBase):
    """A raw device that takes ``room`` bytes, then fails every write with ``code``."""

    def __init__(self, room: int, code: int) -> None:
        super().__init__()
        self.data, self.room, self.code = bytearray(), room, code

    def writable(self) -> bool:
        return True

    def write(self, b: Any) -> int:
        if len(self.data) + len(b) > self.room:
            raise OSError(self.code, os.strerror(self.code))
        self.data += bytes(b)
        return len(b)


@pytest.mark.parametrize("code", FAULTS, ids=NAMES.get)
def test_tlog_batch_refused_at_close_is_an_event(code: int) -> None:
    """req(26.4): the .tlog goes to the device in one-second batches; the last batch, written when
    the run closes the task, meets a full disk: TLOG_ERROR (the console copies it), not a silent
    loss of that second's records."""
    from ground_demo import MemoryLink
    from task_rig import TaskRig, task_config

    from fsw.drivers.resources import Resources

    raw = _FullRaw(1 << 20, code)
    rig = TaskRig(task_config(("mavlink", "mavlink")),
                  Resources(mavlink_link=MemoryLink(), mavlink_tlog=io.BufferedWriter(raw, 1 << 16)))
    rig.run(5)  # frames logged, the first batch written at once; the rest wait in the buffer
    task = rig.task("mavlink")
    assert task.tlog.records > 0 and not rig.events("mavlink.TLOG_ERROR")
    raw.room = len(raw.data)  # the disk is full now
    task.close()
    (ev,) = rig.events("mavlink.TLOG_ERROR")
    assert NAMES[code] in ev.text and "\n" not in ev.text
