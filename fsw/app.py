"""Builds the flight software from its configuration: clock, executive, resources.

Drivers are created here from the ``devices`` configuration (when present) and handed to
tasks as resources, so tasks never open devices themselves and the same tasks run on the
rover and on the bench.
"""

from __future__ import annotations

from typing import Any

from fsw.executive.executive import Executive
from fsw.executive.health import SoftwareWatchdog
from fsw.framework.clock import Clock, MonotonicClock
from fsw.settings import FswConfig


def build_executive(
    cfg: FswConfig, clock: Clock | None = None, resources: dict[str, Any] | None = None, watchdog_timeout_s: float = 1.0
) -> Executive:
    """An executive for ``cfg`` on ``clock`` (real time by default) with a software watchdog."""
    clock = clock or MonotonicClock()
    res = dict(resources or {})
    res.setdefault("watchdog", SoftwareWatchdog(clock, watchdog_timeout_s))
    if "map_store" not in res and cfg.checkpoint.directory:
        from fsw.drivers.map_store import MapStore

        res["map_store"] = MapStore(cfg.checkpoint, cfg.fusion)
    devices = getattr(cfg, "devices", None)
    if devices is not None:  # drivers from [devices]; a bench may hand in open endpoints
        from fsw.drivers.factory import open_devices

        for key, drv in open_devices(devices, res).items():
            res.setdefault(key, drv)
    return Executive(cfg, clock, res)
