"""Save and resume the mission sequencer's state with the map (paper Figure 4; docs/algorithm.md §1-§3).

``save`` runs when an imaging step completes (and on entering SAFE or DONE): it writes the
map of that step (``MapUpdate.snapshot``: the map the step's state was computed from, never
the map of a later or half-merged view) together with the mission state, every task's
``checkpoint_state()`` and the ``checkpoint_hooks`` sections, as ONE checkpoint through the
map store (atomic: temporary file, fsync, rename; ``fsw.drivers.map_store``).

``resume`` runs in the sequencer's ``setup``: it reads the start-up checkpoint (loaded once
by ``MapStore.restore``) and puts the sequencer back where the step ended: SELECT of the next
step (the next-view request is re-issued in the same frame as in an uninterrupted run), or
SAFE, or DONE. A malformed or incompatible state raises ``StateError``. The sequencer
re-publishes the restored map update on its first frame (for the radio task's map).
"""

from __future__ import annotations

from typing import Any

import shapely

from fsw.core.geometry import MapGrid
from fsw.framework.storage import describe
from fsw.tasks.messages import MapUpdate
from fsw.tasks.mission_state import (
    SCHEMA,
    MissionPhase,
    StateError,
    check_schema,
    collect_hooks,
    collect_task_states,
    edge_from_json,
    edge_to_json,
    fingerprint,
    mask_from_json,
    mask_to_json,
    nav_from_json,
    nav_to_json,
    records_from_json,
    records_to_json,
)

_RESUMABLE = (MissionPhase.SELECT, MissionPhase.SAFE, MissionPhase.DONE)


def mission_state(m: Any, phase: MissionPhase) -> dict[str, Any]:
    """The whole checkpoint state of mission task ``m`` (JSON-able)."""
    up: MapUpdate | None = m.latest
    latest = None
    if up is not None:
        latest = {
            "view_id": up.view_id, "time_s": up.time_s, "mapped_cells": up.mapped_cells, "new_cells": up.new_cells,
            "points": up.points, "misses": up.misses, "expected_new_cells": up.expected_new_cells,
            "edge": edge_to_json(up.edge),
            "extra": {"outliers": up.outliers, "edge_points": up.edge_points,
                      "roi_mapped_fraction": up.roi_mapped_fraction},
            "drop": mask_to_json(up.drop),
        }
    tasks = {n: t for n, t in m.ctx.runtime.tasks.items() if n != m.name}
    return {
        "schema": SCHEMA,
        "fingerprint": fingerprint(m.ctx.cfg),
        "time_s": m.ctx.clock.now(),
        "frame": m.ctx.frame,
        "mission": {
            "phase": str(phase), "step": m.step, "records": records_to_json(m.records),
            "request_id": m.request_id, "edge_violations": m.edge_violations, "safe_entries": m.safe_entries,
            "end": m.end, "safe_reason": m.safe_reason,
            "edge": edge_to_json(m.edge), "nav": nav_to_json(m.nav), "latest": latest,
            "looks": m.looks, "stays": list(m.stays),
            "looked": None if m._looked is None else list(m._looked),
            "looked_from": None if m._looked_from is None else list(m._looked_from),
            "look_n": m._look_n, "look_left": m._look_left,
            "stood_on": [shapely.to_wkb(g, hex=True) for g in m.geofence.known._stood],
        },
        "tasks": collect_task_states(tasks),
        "hooks": collect_hooks(m.ctx.res.checkpoint_hooks),
    }


def save(m: Any, phase: MissionPhase) -> None:
    """Checkpoint the map of the last merged step with the mission state (events either way)."""
    store = m.ctx.res.map_store
    if store is None or m.latest is None:
        return
    try:
        store.save_next(m.latest.snapshot, m.ctx.clock.now(), mission_state(m, phase))
    except OSError as exc:  # a full or failing device: the newest good checkpoint stays, the mission goes on
        m.event("CHECKPOINT_FAILED", error=describe(exc))
        return
    except (ValueError, TypeError) as exc:
        m.event("CHECKPOINT_FAILED", error=f"{type(exc).__name__}: {exc}")
        return
    m.event("CHECKPOINT_SAVED", step=m.step, seq=store.seq, kib=store.last_size / 1024)


def resume(m: Any) -> MissionPhase | None:
    """Restore mission task ``m`` from the start-up checkpoint; the phase to continue in, or
    None (no checkpoint, or a map-only one). ``StateError`` if it cannot be used."""
    store = m.ctx.res.map_store
    if store is None:
        return None
    loaded = store.restore()
    if loaded.state is None or loaded.emap is None:
        return None
    if loaded.errors:
        raise StateError("task state unusable: " + "; ".join(loaded.errors))
    try:
        s = check_schema(loaded.state, fingerprint(m.ctx.cfg))
        phase = MissionPhase(s["phase"])
        if phase not in _RESUMABLE:
            raise StateError(f"cannot resume from phase {phase}")
        records = records_from_json(s["records"])
        edge, nav = edge_from_json(s["edge"]), nav_from_json(s["nav"])
        lt = s["latest"]
        latest = None
        if lt is not None:
            latest = MapUpdate(
                int(lt["view_id"]), float(lt["time_s"]), int(lt["mapped_cells"]), int(lt["new_cells"]),
                int(lt["points"]), int(lt["misses"]), float(lt["expected_new_cells"]), loaded.emap.copy(),
                edge_from_json(lt["edge"]), int(lt["extra"].get("outliers", 0)),
                int(lt["extra"].get("edge_points", 0)), float(lt["extra"].get("roi_mapped_fraction", 0.0)),
                drop=mask_from_json(lt.get("drop"), loaded.emap.grid.shape),
            )
        counters = [int(s[k]) for k in ("step", "request_id", "edge_violations", "safe_entries")]
    except StateError:
        raise
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        raise StateError(f"malformed mission state ({type(exc).__name__}: {exc})") from None
    if loaded.emap.grid != MapGrid.from_config(m.ctx.cfg.map):
        raise StateError("the checkpoint's map grid differs from the configured one")
    m.step, m.request_id, m.edge_violations, m.safe_entries = counters
    m.records, m.edge, m.nav, m.latest = records, edge, nav, latest
    m.end, m.safe_reason = s.get("end"), s.get("safe_reason")
    m.looks, m.stays = int(s.get("looks", 0)), [str(x) for x in s.get("stays", [])]
    looked, looked_from = s.get("looked"), s.get("looked_from")
    m._looked = None if looked is None else tuple(float(v) for v in looked)
    m._looked_from = None if looked_from is None else tuple(float(v) for v in looked_from)
    m._look_n, m._look_left = int(s.get("look_n", 0)), int(s.get("look_left", 0))
    m.geofence.known._stood = [shapely.from_wkb(h) for h in s.get("stood_on", [])]
    m.event("RESUMED", step=m.step, seq=loaded.meta.seq, phase=str(phase))
    return phase


def resume_mission(m: Any) -> None:
    """``resume`` into mission task ``m`` at set-up: the phase entered, or an event saying why
    the checkpoint was not used (the mission then waits for START instead of auto-starting)."""
    try:
        phase = resume(m)
    except StateError as exc:
        m._auto_start = False
        m.event("RESUME_REFUSED", reason=str(exc))
        return
    if phase is None:
        return
    m._auto_start = False
    m._republish = m.latest
    m._goto(phase)
    if phase is MissionPhase.SELECT:
        m._next_view()  # the next-view request goes out in the frame it did before the stop
    elif phase is MissionPhase.SAFE:
        m._safe_since = m.ctx.clock.now()
