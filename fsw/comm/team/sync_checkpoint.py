"""The checkpoint of one end of the two-way map sync (docs/sync.md, "The state machine of one end").

:func:`save` serialises the whole sync state of a :class:`~fsw.comm.team.map_sync.MapSync`
(both layers, versions, beliefs) as JSON bytes; :func:`restore` rebuilds an end from it after a
restart, numbering its versions past any it may have published after the checkpoint.
"""

from __future__ import annotations

import json
from collections.abc import Callable

from fsw.comm.team.map_replica import F32
from fsw.comm.team.map_sync import MapSync, Priority
from fsw.comm.team.sync_config import SyncConfig
from fsw.core.codec.mapcodec import CodecConfig, MapCodecError
from fsw.core.codec.tileformat import profile_from_bytes

CHECKPOINT_VERSION = 2  # 2: tiles in the compact tile format with their profiles
# A restored end numbers its versions from its checkpoint's counter plus this, so nothing it
# publishes reuses a version it published after the checkpoint (4096 restarts fit in u32).
RESTART_VERSION_STEP = 1 << 20


def save(end: MapSync) -> bytes:
    """The sync state as bytes (JSON): both layers, the counter, the beliefs."""
    return json.dumps({
        "v": CHECKPOINT_VERSION, "agent": end.agent, "peer": end.peer, "frame": end.frame,
        "shape": list(end.rep.shape), "tile_cells": end.cfg.tile_cells, "counter": end.rep.counter,
        "rounds": end.stats.rounds, **end.rep.layers_state(), "profile": end.rep.profile.pid,
        "peer_profile": None if end.peer_profile is None else end.peer_profile.to_bytes().hex(),
        "belief": {str(t): list(b) for t, b in end.belief.items()},
    }).encode()


def restore(state: bytes, cfg: SyncConfig, cell_m: float, wheel_diameter_m: float, *, boot: int,
            codec: CodecConfig | None = None, priority: Priority | None = None,
            on_adopt: Callable[[int, F32], None] | None = None,
            origin: tuple[float, float] = (0.0, 0.0)) -> MapSync:
    """An end rebuilt from :func:`save` (raises ``ValueError`` with one line if the
    state is not a valid sync checkpoint for ``cfg``)."""
    try:
        s = json.loads(state)
        if s["v"] != CHECKPOINT_VERSION or s["tile_cells"] != cfg.tile_cells:
            raise ValueError("checkpoint of another version or tile size")
        m = MapSync(cfg, int(s["agent"]), int(s["peer"]), (int(s["shape"][0]), int(s["shape"][1])), cell_m,
                    wheel_diameter_m, frame=int(s["frame"]), boot=boot, codec=codec, priority=priority,
                    on_adopt=on_adopt, origin=origin)
        if int(s["profile"]) != m.rep.profile.pid:
            raise ValueError("its tiles are of another tile profile (frame, grid or codec settings)")
        peer = s["peer_profile"]
        m.peer_profile = None if peer is None else profile_from_bytes(bytes.fromhex(str(peer)))
        m.rep.load_layers(s["own"], s["held"], s["source"], m.peer_profile)
        m.rep.counter = int(s["counter"]) + RESTART_VERSION_STEP
        m.fresh = False
        m.stats.rounds = int(s["rounds"])
        m.stats.minimal_bytes = 0  # the peer kept my profile (its holdings say so, or not)
        m.attach_profile = False
        m.belief = {int(t): (int(b[0]), int(b[1])) for t, b in s["belief"].items()}
    except (KeyError, TypeError, IndexError, json.JSONDecodeError, MapCodecError, ValueError) as exc:
        raise ValueError(f"not a usable map-sync checkpoint: {exc}") from None
    return m
