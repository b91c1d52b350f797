"""The flight tasks' base: a task context that adds the configuration and the drivers.

``fsw.framework.task.Task`` knows nothing of this project's configuration; every flight task
derives from :class:`FlightTask`, whose context carries the validated :class:`FswConfig` and
the typed :class:`Resources` (drivers, stores, hooks) the app or the bench opened. So a task
reads ``self.ctx.cfg.camera`` and ``self.ctx.res.camera`` with their types, never a string key.
"""

from __future__ import annotations

from dataclasses import dataclass

from fsw.drivers.resources import Resources
from fsw.framework.task import Task, TaskContext
from fsw.settings import FswConfig


@dataclass(kw_only=True)
class FlightContext(TaskContext):
    """The task context of the flight software."""

    cfg: FswConfig
    res: Resources


class FlightTask(Task):
    """Base of every flight task (``Task`` with a :class:`FlightContext`)."""

    ctx: FlightContext

    def __init__(self, name: str, ctx: FlightContext, budget_s: float) -> None:
        super().__init__(name, ctx, budget_s)
