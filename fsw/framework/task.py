"""The task base class: declarations, counters, timing, pings and slack jobs.

A task declares its ``CHANNELS``, ``EVENTS`` and ``COMMANDS`` as class data; the executive
registers them under the instance name (``stereo.points``, ``stereo.NOOP``) and the ground
dictionary is generated from them. Every task also has the common ones below (cFS: NOOP,
RESET_COUNTERS; F Prime: execution-time channels, throttled overrun events). A task's
handler for command ``X`` is its method ``cmd_X``.

A task's timing comes in two kinds (docs/architecture.md, "The cyclic executive"): the
*schedule's* (``last_s``, ``max_s``, ``overruns``: its channels, OVERRUN events), measured on
the executive's schedule timer, which in lockstep is the stepped clock, so telemetry is
deterministic; and the *host's* (:class:`HostTiming`), what the work cost on this computer, a
metric for the bench's reports and never telemetry.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, ClassVar, Protocol

from fsw.framework.bus import Mailbox, Policy, SoftwareBus
from fsw.framework.clock import Clock
from fsw.framework.commands import CommandDef, CommandDispatcher
from fsw.framework.jobs import Job, JobHandle, JobScheduler
from fsw.framework.telemetry import Channel, ChannelValue, EventDef, EventLog, Severity, TelemetryStore, differs


class Runtime(Protocol):
    """The executive as its components see it."""

    @property
    def period_s(self) -> float: ...

    @property
    def slips(self) -> int: ...

    @property
    def tasks(self) -> Mapping[str, Task]: ...

    @property
    def jobs(self) -> JobScheduler: ...

    def is_enabled(self, name: str) -> bool: ...

    def set_enabled(self, name: str, enabled: bool) -> None: ...

    def schedule(self) -> Mapping[str, int]:
        """The scheduled tasks in run order (group by group), each with its group's divisor."""
        ...

    def busy_s(self, frame: int) -> float:
        """Foreground time of the rate groups that ran on ``frame``, s."""
        ...

    def reset_counters(self) -> None:
        """Zero the executive's slip, skip, frame and slice maxima (RESET_COUNTERS on ``exec``)."""
        ...



@dataclass
class HostTiming:
    """Execution time of a task's activations on the executive's host timer: what the work cost
    on this computer (real time, or the thread's CPU time on a bench that asks for it). On the
    real-time clock it is the time the schedule sees; in lockstep the schedule runs on the
    stepped clock, and this is the only place the host's speed shows (a mission's
    ``summary.json``: ``task_max_ms``, ``task_ms_per_frame``, ``overruns``)."""

    last_s: float = 0.0
    max_s: float = 0.0
    total_s: float = 0.0  # summed over all activations (the foreground cost)
    overruns: int = 0  # activations over the task's budget on this timer

    def add(self, dt: float, budget_s: float) -> None:
        """Count one activation that took ``dt`` on the host timer."""
        self.last_s = dt
        self.max_s = max(self.max_s, dt)
        self.total_s += dt
        if dt > budget_s:
            self.overruns += 1

    def reset(self) -> None:
        """Forget the maximum and the overruns (RESET_COUNTERS)."""
        self.max_s = 0.0
        self.overruns = 0


@dataclass(kw_only=True)
class TaskContext:
    """Everything a task may touch besides its own state (the flight tasks' context adds the
    configuration and the drivers: ``fsw.tasks.base.FlightContext``)."""

    clock: Clock
    telemetry: TelemetryStore
    events: EventLog
    commands: CommandDispatcher
    bus: SoftwareBus
    jobs: JobScheduler
    runtime: Runtime
    frame_period_s: float
    frame: int = 0


COMMON_CHANNELS = (
    Channel("exec_last_ms", "ms", doc="execution time of the last activation"),
    Channel("exec_max_ms", "ms", doc="maximum execution time since reset"),
    Channel("overruns", "count", hi=0, doc="activations over budget"),
    Channel("cmds", "count", doc="commands accepted"),
    Channel("cmd_errors", "count", hi=0, doc="commands refused or failed"),
)
COMMON_EVENTS = (
    EventDef("OVERRUN", Severity.WARNING_LO, "{task} took {ms:.2f} ms, budget {budget_ms:.2f} ms", throttle=5),
    EventDef("EXCEPTION", Severity.WARNING_HI, "{task} raised {error}", throttle=5),
    EventDef("NOOP", Severity.ACTIVITY_HI, "{task} NOOP received"),
    EventDef("COUNTERS_RESET", Severity.ACTIVITY_HI, "{task} counters reset"),
    EventDef("COMMAND_REFUSED", Severity.COMMAND, "{command} -> {status}: {reason}", throttle=10),
)
COMMON_COMMANDS = (
    CommandDef("NOOP", doc="does nothing but answer and raise an event"),
    CommandDef("RESET_COUNTERS", doc="zero the command, error and overrun counters and the max execution time"),
)


class Task:
    """Base of every executive task; subclasses override :meth:`run`."""

    KIND: ClassVar[str] = ""
    DOC: ClassVar[str] = ""
    CHANNELS: ClassVar[tuple[Channel, ...]] = ()
    EVENTS: ClassVar[tuple[EventDef, ...]] = ()
    COMMANDS: ClassVar[tuple[CommandDef, ...]] = ()
    #: design range of the activation rate, Hz (the schedule is refused outside it)
    RATE_HZ: ClassVar[tuple[float, float]] = (0.0, float("inf"))
    #: task kinds that must be scheduled with this one (it talks to them over the bus or polls their devices)
    REQUIRES: ClassVar[tuple[str, ...]] = ()

    @classmethod
    def required_kinds(cls, cfg: Any) -> tuple[str, ...]:
        """The kinds this task needs scheduled with it under the configuration ``cfg``."""
        return cls.REQUIRES

    def __init__(self, name: str, ctx: TaskContext, budget_s: float) -> None:
        self.name = name
        self.ctx = ctx
        self.budget_s = budget_s
        self.activations = 0
        self.last_s = 0.0  # on the schedule's timer (the stepped clock in lockstep)
        self.max_s = 0.0
        self.overruns = 0
        self.host = HostTiming()  # on the host's timer: a metric, never telemetry
        self.cmd_count = 0
        self.cmd_errors = 0
        self.exceptions = 0
        self.ping_sent = 0
        self.ping_answered = 0
        self.ping_answered_frame = 0
        self.hung = False  # fault injection / self-diagnosis: a hung task stops answering pings
        self._tlm_cells: dict[str, ChannelValue] = {}  # channel -> its store cell, resolved once

    # -- declarations -------------------------------------------------------------------
    @classmethod
    def all_channels(cls) -> tuple[Channel, ...]:
        return COMMON_CHANNELS + cls.CHANNELS

    @classmethod
    def all_events(cls) -> tuple[EventDef, ...]:
        return COMMON_EVENTS + cls.EVENTS

    @classmethod
    def all_commands(cls) -> tuple[CommandDef, ...]:
        return COMMON_COMMANDS + cls.COMMANDS

    # -- the work -------------------------------------------------------------------------
    def setup(self) -> None:
        """Called once after every task is registered (subscribe to topics here)."""

    def run(self, frame: int) -> None:
        """One activation; keep it within ``budget_s``."""

    def answer_ping(self) -> None:
        """Called by the executive after a successful activation."""
        if not self.hung and self.ping_answered != self.ping_sent:
            self.ping_answered = self.ping_sent
            self.ping_answered_frame = self.ctx.frame

    def ping(self, key: int) -> None:
        self.ping_sent = key

    # -- helpers for subclasses -------------------------------------------------------------
    def _tlm_cell(self, channel: str) -> ChannelValue:
        cv = self._tlm_cells.get(channel)
        if cv is None:  # KeyError = undeclared channel: a software bug
            cv = self._tlm_cells[channel] = self.ctx.telemetry.values[f"{self.name}.{channel}"]
        return cv

    def tlm(self, channel: str, value: float | int | str) -> None:
        cv = self._tlm_cell(channel)
        if differs(value, cv.value):
            self.ctx.telemetry.changed[cv.name] = None
        cv.value, cv.time_s = value, self.ctx.clock.now()
        cv.updates += 1

    def tlm_record(self, values: Mapping[str, float | int | str]) -> None:
        """One telemetry record: several channels of this task sampled at one time (one clock
        read, each channel's store cell resolved once per task, not a call per channel)."""
        now = self.ctx.clock.now()
        cells, changed = self._tlm_cells, self.ctx.telemetry.changed
        for channel, value in values.items():
            cv = cells.get(channel)
            if cv is None:  # first write of this channel
                cv = self._tlm_cell(channel)
            try:  # telemetry.differs, inlined: ~200 channels a frame
                if value != cv.value:
                    changed[cv.name] = None
            except (TypeError, ValueError):
                changed[cv.name] = None
            cv.value, cv.time_s = value, now
            cv.updates += 1

    def event(self, name: str, **args: Any) -> None:
        self.ctx.events.emit(f"{self.name}.{name}", task=self.name, **args)

    def subscribe(self, topic: str, depth: int | None = None, policy: Policy = "drop_oldest") -> Mailbox[Any]:
        return self.ctx.bus.subscribe(topic, self.name, depth, policy)

    def publish(self, topic: str, msg: Any) -> None:
        self.ctx.bus.publish(topic, msg)

    def submit_job(self, gen: Job, name: str, on_done: Callable[[JobHandle], None] | None = None,
                   background: bool = False) -> JobHandle:
        return self.ctx.jobs.submit(gen, name, self.name, on_done, background)

    def publish_timing(self) -> None:
        self.tlm_record({"exec_last_ms": self.last_s * 1e3, "exec_max_ms": self.max_s * 1e3,
                         "overruns": self.overruns, "cmds": self.cmd_count,
                         "cmd_errors": self.cmd_errors})

    # -- common commands -------------------------------------------------------------------
    def cmd_NOOP(self) -> None:
        self.event("NOOP")

    def cmd_RESET_COUNTERS(self) -> None:
        self.cmd_count = self.cmd_errors = self.overruns = self.exceptions = 0
        self.max_s = 0.0
        self.host.reset()
        self.ctx.events.reset_throttle(f"{self.name}.OVERRUN")
        self.event("COUNTERS_RESET")
