"""Shared helpers of the HIL tests (flat worlds, quiet lockstep benches, free ports)."""

from __future__ import annotations

import dataclasses
import socket
from typing import Any

from fsw.settings import load_settings
from hil_sim.bench import LockstepBench

HW_TASKS = ("health", "can_drv", "imu_drv", "mast_drv", "cam_drv", "motion")


def only_hw_tasks(c: Any) -> Any:
    """``c`` scheduling only the tasks these tests are about (no mission stack moving the rover)."""
    tasks = tuple(t for t in c.executive.tasks if t.name in HW_TASKS)
    return dataclasses.replace(c, executive=dataclasses.replace(c.executive, tasks=tasks))


def cfg() -> Any:
    return only_hw_tasks(load_settings())


def lab_world() -> Any:
    """The lab scenario; a flat stub (None: level ground, no camera) if it cannot be built."""
    try:
        from hil_sim.world import load_scenario

        return load_scenario("lab", 0)
    except ImportError:
        return None


def bench(world: Any = None, seed: int = 0, **kw: Any) -> LockstepBench:
    return LockstepBench(cfg(), world, seed=seed, quiet=True, **kw)


def free_tcp_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])

