"""Non-volatile store of map checkpoints: atomic write, newest-good load (docs/algorithm.md §1).

The device is a directory. ``save`` writes ``map_<seq>.ckpt`` atomically: the bytes go to a
temporary file in the same directory, which is flushed and fsync'ed, then renamed over the
final name (``os.replace``) and the directory is fsync'ed, so a power cut leaves either the
old set of checkpoints or the new one, never a half-written file under a final name. Only
the newest ``keep`` checkpoints stay. ``load_latest`` tries checkpoints newest first and
skips any that fail ``fsw.core.map.checkpoint.decode`` (truncated, corrupt), reporting each one
it skipped, so a bad newest checkpoint falls back to the previous one.

A checkpoint may carry the mission state with its map (``save(..., state=...)``: one file,
one checksum, so a map and a mission state of different steps never pair up). ``restore``
is the start-up load: it first removes the temporary files a kill during ``save`` left
behind (``remove_stale``), then loads the newest good checkpoint once and keeps the result
for every task that restores from it (docs/hil.md, "Resuming a mission").

A full or failing device (``ENOSPC``, ``EIO``: ``fsw.framework.storage``) fails one ``save``:
its temporary file is removed, no older checkpoint is pruned, so the newest good checkpoint
stays what it was; the error (one line, with the errno name) is raised inline or, on the
writer thread, kept for :meth:`take_error`; the tasks turn it into a ``CHECKPOINT_FAILED``
event and the mission carries on (the next save tries again).
"""

from __future__ import annotations

import math
import os
import queue
import re
import tempfile
import threading
from dataclasses import dataclass, field
from pathlib import Path

from fsw.core.map.checkpoint import CheckpointConfig, CheckpointError, CheckpointMeta, decode, encode
from fsw.core.map.elevation_map import ElevationMap, FusionConfig
from fsw.framework.storage import describe

_NAME = re.compile(r"^map_(\d{10})\.ckpt$")
_TEMP = re.compile(r"^\.map_.*\.tmp$")


@dataclass
class LoadResult:
    """The newest good checkpoint (or none) and the ones skipped on the way, with reasons."""

    emap: ElevationMap | None
    meta: CheckpointMeta | None
    path: Path | None
    skipped: list[tuple[Path, str]] = field(default_factory=list)
    stale_removed: int = 0  # temporary files of interrupted saves removed at start-up
    errors: list[str] = field(default_factory=list)  # task sections that could not be restored

    @property
    def state(self) -> dict[str, object] | None:
        """The mission state saved with the map (None: none, or a map-only checkpoint)."""
        return None if self.meta is None else self.meta.state


class MapStore:
    """Checkpoint files in one directory."""

    def __init__(self, cfg: CheckpointConfig, fusion: FusionConfig | None = None,
                 background: bool = False) -> None:
        """``background``: the file write and its fsyncs run on a writer thread (real time:
        an fsync on a busy disk took 75-160 ms, a slipped frame, when the executive's thread
        waited for it); ``save`` then returns once the bytes are encoded and queued, and a
        failed write is reported by :meth:`take_error`."""
        self.cfg = cfg
        self.fusion = fusion
        self.dir = Path(cfg.directory)
        self.seq = 0  # the highest sequence number saved or found
        self.last_save_s = -math.inf  # mission time of the last save (any writer)
        self.last_size = 0  # bytes of the last checkpoint saved (or queued)
        self._restored: LoadResult | None = None
        self._queue: queue.Queue[tuple[bytes, Path] | None] | None = None
        self._errors: list[str] = []
        if background:
            self._queue = queue.Queue()
            self._thread = threading.Thread(target=self._writer, name="map-store", daemon=True)
            self._thread.start()

    def paths(self) -> list[Path]:
        """Checkpoint files, oldest first (by sequence number)."""
        if not self.dir.is_dir():
            return []
        found = [(int(m.group(1)), p) for p in self.dir.iterdir() if (m := _NAME.match(p.name))]
        return [p for _, p in sorted(found)]

    def save(self, emap: ElevationMap, seq: int, time_s: float, state: dict[str, object] | None = None) -> Path:
        """Write one checkpoint atomically; raises ``OSError`` if the device fails."""
        if not 0 <= seq < 10**10:
            raise ValueError(f"sequence number {seq} out of range")
        data = encode(emap, seq, time_s, self.cfg.compression_level, state)
        final = self.dir / f"map_{seq:010d}.ckpt"
        if self._queue is not None:
            self._queue.put((data, final))
        else:
            self._write(data, final)
        self.seq = max(self.seq, seq)
        self.last_save_s = time_s
        self.last_size = len(data)
        return final

    def _write(self, data: bytes, final: Path) -> None:
        self.dir.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=".map_", suffix=".tmp", dir=self.dir)
        try:
            with os.fdopen(fd, "wb") as fh:
                fh.write(data)
                fh.flush()
                os.fsync(fh.fileno())
            os.replace(tmp, final)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise
        self._fsync_dir()
        for old in self.paths()[: -self.cfg.keep]:
            old.unlink(missing_ok=True)

    def _writer(self) -> None:
        assert self._queue is not None
        while (job := self._queue.get()) is not None:
            try:
                self._write(*job)
            except OSError as exc:
                self._errors.append(f"{job[1].name}: {describe(exc)}")
            finally:
                self._queue.task_done()
        self._queue.task_done()

    def take_error(self) -> str | None:
        """The oldest background write that failed since the last call (None: none)."""
        return self._errors.pop(0) if self._errors else None

    def flush(self) -> None:
        """Wait until every queued checkpoint is on the device (no-op when writing inline)."""
        if self._queue is not None:
            self._queue.join()

    def close(self) -> None:
        """Finish the queued writes and stop the writer thread."""
        if self._queue is not None:
            self._queue.put(None)
            self._queue.join()
            self._thread.join(timeout=10.0)
            self._queue = None

    def save_next(self, emap: ElevationMap, time_s: float, state: dict[str, object] | None = None) -> Path:
        """``save`` under the next sequence number (after every one saved or on the device)."""
        found = self.paths()
        last = int(_NAME.match(found[-1].name).group(1)) if found else 0  # type: ignore[union-attr]
        return self.save(emap, max(self.seq, last) + 1, time_s, state)

    def remove_stale(self) -> int:
        """Remove temporary files that a kill or power cut during ``save`` left behind."""
        if not self.dir.is_dir():
            return 0
        n = 0
        for p in self.dir.iterdir():
            if _TEMP.match(p.name):
                p.unlink(missing_ok=True)
                n += 1
        return n

    def restore(self) -> LoadResult:
        """The start-up load (stale temporaries removed first), done once and kept."""
        if self._restored is None:
            stale = self.remove_stale()
            self._restored = self.load_latest()
            self._restored.stale_removed = stale
            if self._restored.meta is not None:
                self.seq = max(self.seq, self._restored.meta.seq)
        return self._restored

    def clear(self) -> int:
        """Delete every checkpoint and temporary file (a new survey); returns files removed."""
        self.flush()
        n = self.remove_stale()
        for p in self.paths():
            p.unlink(missing_ok=True)
            n += 1
        self.seq = 0
        self._restored = None
        return n

    def load_latest(self) -> LoadResult:
        """The newest checkpoint that decodes; earlier ones are fallbacks."""
        self.flush()
        result = LoadResult(None, None, None)
        for path in reversed(self.paths()):
            try:
                emap, meta = decode(path.read_bytes(), self.fusion)
            except (CheckpointError, OSError) as exc:
                result.skipped.append((path, str(exc)))
                continue
            result.emap, result.meta, result.path = emap, meta, path
            break
        return result

    def _fsync_dir(self) -> None:
        try:
            fd = os.open(self.dir, os.O_RDONLY)
        except OSError:
            return
        try:
            os.fsync(fd)
        except OSError:
            pass
        finally:
            os.close(fd)
