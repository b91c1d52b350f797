"""A rig for unit tests of one flight task (or a few) on a stepped clock.

Builds the executive the way ``fsw.app.build_executive`` does (``Executive(cfg, clock,
Resources)``) but opens no ``[devices]``: the test hands in the typed ``Resources`` it wants
(fakes or in-process ports). The configuration is the flight one (``config/fsw.toml``) with
only the named tasks scheduled, in one rate group that runs every frame. The test plays the
other components: it publishes their messages on the bus and reads what the task publishes
through taps (its own mailboxes on the topics).
"""

from __future__ import annotations

import dataclasses
from typing import Any

from fsw.drivers.resources import Resources
from fsw.executive.executive import Executive
from fsw.framework.bus import Mailbox
from fsw.framework.clock import SteppedClock
from fsw.framework.schedule import RateGroupConfig, TaskConfig
from fsw.settings import FswConfig, load_settings
from hil_sim.bench import ExecutiveDriver


def task_config(*tasks: tuple[str, str], **sections: Any) -> FswConfig:
    """The flight configuration with only ``tasks`` ((name, kind), in run order) scheduled in
    one group that runs every frame (generous budgets: these tests are not about time);
    ``sections`` replace whole configuration sections (``mission=...``)."""
    cfg = load_settings()
    ex = dataclasses.replace(
        cfg.executive,
        groups=(RateGroupConfig(name="fast", divisor=1),),
        tasks=tuple(TaskConfig(name=n, kind=k, group="fast", budget_ms=1000.0) for n, k in tasks),
    )
    return dataclasses.replace(cfg, executive=ex, **sections)


class TaskRig(ExecutiveDriver):
    """An executive on a :class:`SteppedClock` with taps on the bus."""

    COMMAND_SOURCE = "test"

    def __init__(self, cfg: FswConfig, resources: Resources | None = None) -> None:
        self.clock = SteppedClock()
        super().__init__(Executive(cfg, self.clock, resources or Resources()))

    def task(self, name: str) -> Any:
        return self.exe.tasks[name]

    def tap(self, topic: str, depth: int = 256) -> Mailbox[Any]:
        return self.exe.bus.subscribe(topic, f"test.{topic}", depth=depth)

    def publish(self, topic: str, msg: Any) -> None:
        self.exe.bus.publish(topic, msg)

    def run(self, frames: int = 1) -> None:
        self.exe.run_lockstep(frames)

    def events(self, name: str) -> list[Any]:
        """Events whose full name is ``name`` (``mission.SAFE``)."""
        return [e for e in self.exe.events.history if e.name == name]
