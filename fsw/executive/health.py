"""Health monitoring: pings every task, warns and declares fatal, strokes the watchdog.

Each activation the health task sends every other enabled task a new ping; a task answers
when it next completes an activation normally (``Task.answer_ping``). A task whose answer
is older than ``health_warn_frames`` (plus its rate-group divisor) raises WARNING_HI; older
than ``health_fatal_frames``, FATAL. The watchdog is stroked only while no task is fatal,
so a hung task, or a stalled executive that no longer runs this task, lets it expire.
"""

from __future__ import annotations

from typing import ClassVar, Protocol

from fsw.framework.clock import Clock
from fsw.framework.task import Task
from fsw.framework.telemetry import Channel, EventDef, Severity


class Watchdog(Protocol):
    def stroke(self) -> None: ...


class SoftwareWatchdog:
    """A watchdog timer on a clock: expired once ``timeout_s`` passes without a stroke."""

    def __init__(self, clock: Clock, timeout_s: float) -> None:
        self.clock, self.timeout_s = clock, timeout_s
        self.last_stroke_s = clock.now()
        self.strokes = 0

    def stroke(self) -> None:
        self.last_stroke_s = self.clock.now()
        self.strokes += 1

    def expired(self) -> bool:
        return self.clock.now() - self.last_stroke_s > self.timeout_s


class HealthTask(Task):
    KIND: ClassVar[str] = "health"
    DOC: ClassVar[str] = "Pings every task; strokes the watchdog while all are alive."
    CHANNELS = (
        Channel("tasks_warning", "count", hi=0),
        Channel("tasks_fatal", "count", hi=0),
        Channel("watchdog_strokes", "count"),
    )
    EVENTS = (
        EventDef("TASK_LATE", Severity.WARNING_HI, "task {target} has not answered for {frames} frames"),
        EventDef(
            "TASK_HUNG", Severity.FATAL, "task {target} hung: no answer for {frames} frames; watchdog no longer stroked"
        ),
        EventDef("TASK_RECOVERED", Severity.ACTIVITY_HI, "task {target} answering again"),
    )

    def setup(self) -> None:
        e = self.ctx.cfg.executive
        self.warn_frames, self.fatal_frames = e.health_warn_frames, e.health_fatal_frames
        self.state: dict[str, str] = {}
        self.strokes = 0
        exe = self.ctx.resources["executive"]
        self._divisor = {}
        for rg in exe.groups:
            for t in rg.members:
                self._divisor[t.name] = rg.group.divisor

    def run(self, frame: int) -> None:
        exe = self.ctx.resources["executive"]
        n_warn = n_fatal = 0
        for name, div in self._divisor.items():
            task = exe.tasks[name]
            if task is self or not exe.enabled[name]:
                self.state.pop(name, None)
                continue
            task.ping(frame)
            age = frame - task.ping_answered_frame
            if task.ping_answered == task.ping_sent or age <= div:
                age = 0
            prev = self.state.get(name, "ok")
            if age > self.fatal_frames + div:
                now = "fatal"
            elif age > self.warn_frames + div:
                now = "warn"
            else:
                now = "ok"
            if now != prev:
                if now == "fatal":
                    self.event("TASK_HUNG", target=name, frames=age)
                elif now == "warn" and prev == "ok":
                    self.event("TASK_LATE", target=name, frames=age)
                elif now == "ok":
                    self.event("TASK_RECOVERED", target=name)
                self.state[name] = now
            n_warn += now == "warn"
            n_fatal += now == "fatal"
        watchdog = self.ctx.resources.get("watchdog")
        if n_fatal == 0 and watchdog is not None:
            watchdog.stroke()
            self.strokes += 1
        self.tlm("tasks_warning", n_warn)
        self.tlm("tasks_fatal", n_fatal)
        self.tlm("watchdog_strokes", self.strokes)
