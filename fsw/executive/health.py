"""Health monitoring: pings every task, warns and declares fatal, strokes the watchdog.

Each activation the health task sends every other enabled task a new ping; a task answers
when it next completes an activation normally (``Task.answer_ping``). A task whose answer
is older than ``health_warn_frames`` (plus its rate-group divisor) is late (WARNING_HI);
older than ``health_fatal_frames``, hung (FATAL). The watchdog is stroked only while no task
is fatal, so a hung task, or a stalled executive that no longer runs this task, lets it expire.

Events stay quiet on a loaded machine (as cFS EVS filters and F Prime throttles): every late
episode of a task is counted (``late_episodes``, ``TASK_LATE_REPEATS``); per task, the first one
after ``health_event_period_s`` without one is a TASK_LATE event, the later ones are summed into
at most one TASK_LATE_REPEATS per period. TASK_HUNG is always an event. TASK_RECOVERED follows
a reported TASK_LATE or TASK_HUNG once the task has answered on time for ``health_recover_frames``.
"""

from __future__ import annotations

from typing import ClassVar

from fsw.framework.summary import Summary
from fsw.framework.telemetry import Channel, EventDef, Severity
from fsw.tasks.base import FlightTask


class HealthTask(FlightTask):
    KIND: ClassVar[str] = "health"
    RATE_HZ: ClassVar[tuple[float, float]] = (0.5, 10.0)  # pings answered within health_warn_frames
    DOC: ClassVar[str] = "Pings every task; strokes the watchdog while all are alive."
    CHANNELS = (
        Channel("tasks_warning", "count", hi=0),
        Channel("tasks_fatal", "count", hi=0),
        Channel("watchdog_strokes", "count"),
        Channel("late_episodes", "count"),  # every late episode of every task, reported or summarised
    )
    EVENTS = (
        EventDef("TASK_LATE", Severity.WARNING_HI, "task {target} has not answered for {frames} frames"),
        EventDef(
            "TASK_HUNG", Severity.FATAL, "task {target} hung: no answer for {frames} frames; watchdog no longer stroked"
        ),
        EventDef("TASK_RECOVERED", Severity.ACTIVITY_HI, "task {target} answering again"),
        EventDef("TASK_LATE_REPEATS", Severity.WARNING_LO,
                 "task {target} late {n} more time(s) in {span_s:.0f} s; latest: {latest}"),
    )

    def setup(self) -> None:
        e = self.ctx.cfg.executive
        self.warn_frames, self.fatal_frames = e.health_warn_frames, e.health_fatal_frames
        self.period_s, self.recover_frames = e.health_event_period_s, e.health_recover_frames
        self.level: dict[str, str] = {}  # per task, this activation: "ok", "warn" or "fatal"
        self.reported: dict[str, str] = {}  # per task, what the events said: "ok", "late" or "hung"
        self.on_time_since: dict[str, int] = {}  # per task, the frame since which it answers on time
        self.late: dict[str, Summary] = {}  # per task, late episodes not yet reported
        self.late_episodes = 0
        self._first_frame: int | None = None  # a resumed run starts at its checkpoint's frame
        self.strokes = 0
        runtime = self.ctx.runtime
        self._divisor = dict(runtime.schedule())

    def run(self, frame: int) -> None:
        runtime = self.ctx.runtime
        now_s = self.ctx.clock.now()
        n_warn = n_fatal = 0
        if self._first_frame is None:
            self._first_frame = frame
        for name, div in self._divisor.items():
            task = runtime.tasks[name]
            if task is self or not runtime.is_enabled(name):
                self.level.pop(name, None)
                continue
            task.ping(frame)
            age = frame - max(task.ping_answered_frame, self._first_frame)  # not older than the monitor
            if task.ping_answered == task.ping_sent or age <= div:
                age = 0
            if age > self.fatal_frames + div:
                now = "fatal"
            elif age > self.warn_frames + div:
                now = "warn"
            else:
                now = "ok"
            self._judge(name, self.level.get(name, "ok"), now, age, frame, now_s)
            self.level[name] = now
            n_warn += now == "warn"
            n_fatal += now == "fatal"
        for name, late in self.late.items():
            r = late.report(now_s)
            if r is not None:
                self.event("TASK_LATE_REPEATS", target=name, n=r.count, span_s=r.span_s, latest=r.latest)
        watchdog = self.ctx.res.watchdog
        if n_fatal == 0 and watchdog is not None:
            watchdog.stroke()
            self.strokes += 1
        self.tlm("tasks_warning", n_warn)
        self.tlm("tasks_fatal", n_fatal)
        self.tlm("watchdog_strokes", self.strokes)
        self.tlm("late_episodes", self.late_episodes)

    def _judge(self, name: str, prev: str, now: str, age: int, frame: int, now_s: float) -> None:
        """Events for one task's level change: every late episode counted, few of them said."""
        reported = self.reported.get(name, "ok")
        if now == "ok":
            since = self.on_time_since.setdefault(name, frame)
            if reported != "ok" and frame - since >= self.recover_frames:
                self.event("TASK_RECOVERED", target=name)
                self.reported[name] = "ok"
            return
        self.on_time_since.pop(name, None)
        said_hung = now == "fatal" and reported != "hung"
        if said_hung:
            self.event("TASK_HUNG", target=name, frames=age)  # always said: the watchdog starves
            self.reported[name] = "hung"
        if prev != "ok":
            return  # the same episode
        self.late_episodes += 1
        late = self.late.setdefault(name, Summary(self.period_s))
        if said_hung:
            return  # this episode was said by TASK_HUNG
        if reported == "ok" and not late.pending and now_s - late.last_report_s >= self.period_s:
            late.last_report_s = now_s  # this event is the period's report
            self.event("TASK_LATE", target=name, frames=age)
            self.reported[name] = "late"
        else:
            late.note(now_s, name, f"no answer for {age} frames at frame {frame}")
