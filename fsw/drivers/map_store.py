"""Non-volatile store of map checkpoints: atomic write, newest-good load (ALGORITHM.md §1).

The device is a directory. ``save`` writes ``map_<seq>.ckpt`` atomically: the bytes go to a
temporary file in the same directory, which is flushed and fsync'ed, then renamed over the
final name (``os.replace``) and the directory is fsync'ed, so a power cut leaves either the
old set of checkpoints or the new one, never a half-written file under a final name. Only
the newest ``keep`` checkpoints stay. ``load_latest`` tries checkpoints newest first and
skips any that fail ``fsw.core.checkpoint.decode`` (truncated, corrupt), reporting each one
it skipped, so a bad newest checkpoint falls back to the previous one.
"""

from __future__ import annotations

import os
import re
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

from fsw.core.checkpoint import CheckpointConfig, CheckpointError, CheckpointMeta, decode, encode
from fsw.core.elevation_map import ElevationMap, FusionConfig

_NAME = re.compile(r"^map_(\d{10})\.ckpt$")


@dataclass
class LoadResult:
    """The newest good checkpoint (or none) and the ones skipped on the way, with reasons."""

    emap: ElevationMap | None
    meta: CheckpointMeta | None
    path: Path | None
    skipped: list[tuple[Path, str]] = field(default_factory=list)


class MapStore:
    """Checkpoint files in one directory."""

    def __init__(self, cfg: CheckpointConfig, fusion: FusionConfig | None = None) -> None:
        self.cfg = cfg
        self.fusion = fusion
        self.dir = Path(cfg.directory)

    def paths(self) -> list[Path]:
        """Checkpoint files, oldest first (by sequence number)."""
        if not self.dir.is_dir():
            return []
        found = [(int(m.group(1)), p) for p in self.dir.iterdir() if (m := _NAME.match(p.name))]
        return [p for _, p in sorted(found)]

    def save(self, emap: ElevationMap, seq: int, time_s: float) -> Path:
        """Write one checkpoint atomically; raises ``OSError`` if the device fails."""
        if not 0 <= seq < 10**10:
            raise ValueError(f"sequence number {seq} out of range")
        data = encode(emap, seq, time_s, self.cfg.compression_level)
        self.dir.mkdir(parents=True, exist_ok=True)
        final = self.dir / f"map_{seq:010d}.ckpt"
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
        return final

    def load_latest(self) -> LoadResult:
        """The newest checkpoint that decodes; earlier ones are fallbacks."""
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
