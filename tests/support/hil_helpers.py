"""Shared helpers of the HIL tests (flat worlds, quiet lockstep benches, free ports)."""

from __future__ import annotations

import dataclasses
import os
import select
import socket
import subprocess
import time
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


def read_until(proc: subprocess.Popen[str], marker: str, timeout_s: float) -> list[str]:
    """Lines of ``proc``'s stdout up to the first one that holds ``marker``.

    Reads the raw descriptor: ``select`` on a buffered text stream misses lines that the
    stream already pulled into its buffer, so two lines arriving in one chunk would stall."""
    lines: list[str] = []
    buf = b""
    deadline = time.monotonic() + timeout_s
    assert proc.stdout is not None
    fd = proc.stdout.fileno()
    while time.monotonic() < deadline:
        ready, _, _ = select.select([fd], [], [], 0.2)
        if not ready:
            continue
        chunk = os.read(fd, 4096)
        if not chunk:
            break
        buf += chunk
        while b"\n" in buf:
            raw, buf = buf.split(b"\n", 1)
            line = raw.decode(errors="replace") + "\n"
            lines.append(line)
            if marker in line:
                return lines
    raise AssertionError(f"no {marker!r} from serve within {timeout_s} s: {''.join(lines)}")
