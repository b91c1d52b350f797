"""The run directory of a lockstep mission: does it hold a mission, has it finished, has its
disk room, and the console copy of the flight's storage events (docs/hil.md, "Resuming a mission").

Before starting or resuming, :func:`check_room` asks the checkpoint directory for room for
two checkpoints (twice the newest, at least ``MIN_PROBE_BYTES``; ``fsw.framework.storage.probe``)
and raises ``StorageError`` (one line) if the disk is full or failing. During the run a
checkpoint or .tlog write that fails is a flight event (``CHECKPOINT_FAILED``,
``TLOG_ERROR``); the bench's console task is quiet, so :func:`echo_storage_events` copies
those to stderr, one line each, and the mission carries on with the newest good checkpoint.
"""

from __future__ import annotations

import sys
from pathlib import Path

from fsw.drivers.map_store import MapStore
from fsw.framework.storage import StorageError, probe
from fsw.framework.telemetry import Event

MANIFEST = "run.json"
#: flight events about storage that the (otherwise quiet) bench copies to stderr
CONSOLE_EVENTS = ("CHECKPOINT_FAILED", "TLOG_ERROR")
MIN_PROBE_BYTES = 256 * 1024


def has_mission(out: Path) -> bool:
    """True if ``out`` holds a mission: its manifest or any checkpoint (or temporary) file."""
    ck = out / "checkpoints"
    return (out / MANIFEST).exists() or (ck.is_dir() and any(ck.glob("map_*.ckpt")) or any(ck.glob(".map_*.tmp")))


def finished(out: Path) -> bool:
    """True if the mission in ``out`` ended (its newest checkpoint is DONE) and has its report."""
    from fsw.core.map.checkpoint import CheckpointConfig

    state = MapStore(CheckpointConfig(directory=str(out / "checkpoints"))).load_latest().state
    mission = state.get("mission") if state else None
    return isinstance(mission, dict) and mission.get("phase") == "DONE" and (out / "summary.json").exists()


def check_room(out: Path, store: MapStore) -> None:
    """``StorageError`` (one line) unless the checkpoint directory takes two checkpoints."""
    newest = store.paths()[-1:] if store.dir.is_dir() else []
    need = max(MIN_PROBE_BYTES, 2 * newest[0].stat().st_size) if newest else MIN_PROBE_BYTES
    try:
        probe(store.dir, need)
    except StorageError as exc:
        raise StorageError(exc.errno, f"{out}: the disk is full or failing, free space first: {exc}") from None


def echo_storage_events(ev: Event) -> None:
    """The bench's console for storage events: one line on stderr (the console task is quiet)."""
    if ev.name.rsplit(".", 1)[-1] in CONSOLE_EVENTS:
        print(f"[{ev.time_s:9.2f}] {ev.severity.name} {ev.name}: {ev.text}", file=sys.stderr)


