"""Trivial tasks for benchmarks and tests: one that does nothing and one that burns time."""

from __future__ import annotations

import time
from typing import ClassVar

from fsw.framework.commands import Arg, CommandDef
from fsw.framework.task import Task
from fsw.framework.telemetry import Channel


class NoopTask(Task):
    KIND: ClassVar[str] = "noop"
    DOC: ClassVar[str] = "Does nothing; measures executive overhead."


class BusyTask(Task):
    """Spins for ``work_ms`` each activation (settable by command) to exercise budgets."""

    KIND: ClassVar[str] = "busy"
    CHANNELS = (Channel("work_ms", "ms", doc="commanded busy time per activation"),)
    COMMANDS = (
        CommandDef(
            "SET_WORK", (Arg("work_ms", float, lo=0.0, hi=10000.0, units="ms"),), doc="set the busy time per activation"
        ),
    )

    def setup(self) -> None:
        self.work_s = 0.0

    def cmd_SET_WORK(self, work_ms: float) -> None:
        self.work_s = work_ms / 1e3

    def run(self, frame: int) -> None:
        t_end = time.perf_counter() + self.work_s
        while time.perf_counter() < t_end:
            pass
        self.tlm("work_ms", self.work_s * 1e3)
