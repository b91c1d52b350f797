"""Save and resume the mission sequencer's state with the map (paper Figure 4; docs/algorithm.md §1-§3).

The sequencer (``fsw.tasks.mission``) saves when an imaging step completes (and on entering
SAFE or DONE): the map of that step (``MapUpdate.snapshot``: the map the step's state was
computed from, never the map of a later or half-merged view) together with its own section
(:class:`fsw.tasks.mission_state.MissionSection`), every task's ``checkpoint_state()`` and the
``checkpoint_hooks`` sections, as ONE checkpoint through the map store (atomic: temporary file,
fsync, rename; ``fsw.drivers.map_store``); :func:`full_state` assembles it.

At set-up the sequencer reads the start-up checkpoint (loaded once by ``MapStore.restore``)
with :func:`load` and puts itself back where the step ended: SELECT of the next step (the
next-view request is re-issued in the same frame as in an uninterrupted run), or SAFE, or
DONE. A malformed or incompatible state raises ``StateError``; the sequencer turns it into an
event. It re-publishes the restored map update on its first frame (for the radio task's map).
"""

from __future__ import annotations

from dataclasses import dataclass

import shapely
import shapely.errors
from shapely.geometry.base import BaseGeometry

from fsw.core.geometry import MapGrid
from fsw.tasks.base import FlightContext
from fsw.tasks.messages import MapUpdate
from fsw.tasks.mission_state import (
    SCHEMA,
    MissionPhase,
    MissionSection,
    StateError,
    check_schema,
    collect_hooks,
    collect_task_states,
    fingerprint,
)
from fsw.tasks.state_json import JsonObject

RESUMABLE = (MissionPhase.SELECT, MissionPhase.SAFE, MissionPhase.DONE)


def full_state(ctx: FlightContext, own: str, section: MissionSection) -> JsonObject:
    """The whole checkpoint state: the mission's ``section`` (task ``own``), every other task's
    ``checkpoint_state()`` and the hooks' sections (JSON-able)."""
    tasks = {n: t for n, t in ctx.runtime.tasks.items() if n != own}
    return {
        "schema": SCHEMA,
        "fingerprint": fingerprint(ctx.cfg),
        "time_s": ctx.clock.now(),
        "frame": ctx.frame,
        "mission": section.to_json(),
        "tasks": collect_task_states(tasks),
        "hooks": collect_hooks(ctx.res.checkpoint_hooks),
    }


@dataclass(frozen=True)
class Loaded:
    """A mission checkpoint that can be resumed: its section, the map update on its map, its number."""

    section: MissionSection
    latest: MapUpdate | None
    stood_on: list[BaseGeometry]  # the ground stood on (the geofence's known ground)
    seq: int


def load(ctx: FlightContext) -> Loaded | None:
    """The start-up checkpoint's mission, or None (no checkpoint, or a map-only one);
    ``StateError`` if it cannot be used."""
    store = ctx.res.map_store
    if store is None:
        return None
    loaded = store.restore()
    if loaded.state is None or loaded.emap is None:
        return None
    if loaded.errors:
        raise StateError("task state unusable: " + "; ".join(loaded.errors))
    mission = check_schema(loaded.state, fingerprint(ctx.cfg))
    try:
        s = MissionSection.from_json(mission, loaded.emap.grid.shape)
    except StateError as exc:
        raise StateError(f"malformed mission state ({exc})") from None
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        raise StateError(f"malformed mission state ({type(exc).__name__}: {exc})") from None
    if s.phase not in RESUMABLE:
        raise StateError(f"cannot resume from phase {s.phase}")
    if loaded.emap.grid != MapGrid.from_config(ctx.cfg.map):
        raise StateError("the checkpoint's map grid differs from the configured one")
    try:
        stood = [shapely.from_wkb(h) for h in s.stood_on]
    except shapely.errors.ShapelyError as exc:
        raise StateError(f"malformed mission state (stood_on: {exc})") from None
    latest = None if s.latest is None else s.latest.update(loaded.emap.copy())
    return Loaded(s, latest, stood, loaded.meta.seq if loaded.meta is not None else -1)
