"""Builds the flight software from its configuration: clock, executive, resources.

Drivers are opened here from the ``devices`` configuration into the typed ``Resources``
(``fsw.drivers.resources``) and handed to the tasks, so tasks never open devices themselves
and the same tasks run on the rover and on the bench. A bench in the same process hands in
its already-open ``Endpoints`` and whatever resources it brings (a radio port, the oracle's
truth); a map store and a software watchdog are made here unless it brought its own.
"""

from __future__ import annotations

from fsw.drivers.factory import open_devices
from fsw.drivers.resources import Endpoints, Resources
from fsw.executive.executive import Executive
from fsw.framework.clock import Clock, MonotonicClock
from fsw.framework.watchdog import SoftwareWatchdog
from fsw.settings import FswConfig


def build_executive(
    cfg: FswConfig,
    clock: Clock | None = None,
    resources: Resources | None = None,
    endpoints: Endpoints | None = None,
    watchdog_timeout_s: float = 1.0,
    map_store: bool = True,
) -> Executive:
    """An executive for ``cfg`` on ``clock`` (real time by default) with a software watchdog.

    ``map_store=False`` runs without checkpoints even when ``[checkpoint]`` names a directory
    (a bench run never restores another's map)."""
    clock = clock or MonotonicClock()
    res = resources or Resources()
    if res.watchdog is None:
        res.watchdog = SoftwareWatchdog(clock, watchdog_timeout_s)
    if map_store and res.map_store is None and cfg.checkpoint.directory:
        from fsw.drivers.map_store import MapStore

        # on the real clock the file writes and fsyncs run on the store's writer thread
        res.map_store = MapStore(cfg.checkpoint, cfg.fusion, background=clock.realtime)
    open_devices(cfg.devices, res, endpoints)
    return Executive(cfg, clock, res)
