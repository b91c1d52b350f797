"""The executive's own components: ``exec`` (frames, jobs, the bus) and one per rate group.

They are tasks in form only: the executive registers their channels, events and commands like
any other component's, but never schedules them; it updates their counters itself.
"""

from __future__ import annotations

from typing import ClassVar

from fsw.framework.commands import Arg, CommandDef, CommandError
from fsw.framework.schedule import RateGroupConfig
from fsw.framework.task import Task, TaskContext
from fsw.framework.telemetry import Channel, EventDef, Severity


class ExecutiveComponent(Task):
    """The executive's own channels, events and commands (component ``exec``)."""

    KIND: ClassVar[str] = "executive"
    CHANNELS = (
        Channel("frame", "count", doc="minor frames run"),
        Channel("lateness_ms", "ms", hi=2.0, doc="frame-start lateness (real time)"),
        Channel("skipped_frames", "count", hi=0, doc="frames skipped past the lag limit"),
        Channel("slips", "count", hi=0, doc="frames that overran into the next (all groups)"),
        Channel("jobs_pending", "count", doc="slack jobs in progress"),
        Channel("jobs_completed", "count"),
        Channel("jobs_failed", "count", hi=0),
        Channel("slice_max_ms", "ms", doc="longest slack-job slice since start or RESET_COUNTERS"),
        Channel("frame_max_ms", "ms", doc="longest frame (foreground + slack) since start or RESET_COUNTERS"),
        Channel("bus_drops", "count", hi=0, doc="messages dropped by full mailboxes"),
    )
    EVENTS = (
        EventDef(
            "SKIPPED", Severity.WARNING_HI, "executive {lag} frames behind; skipped ahead to frame {frame}", throttle=5
        ),
        EventDef(
            "QUEUE_FULL",
            Severity.WARNING_LO,
            "mailbox {mailbox} full (depth {depth}, policy {policy}); {dropped} dropped",
            throttle=5,
        ),
        EventDef("JOB_FAILED", Severity.WARNING_HI, "slack job {owner}.{job} failed: {error}", throttle=5),
        EventDef(
            "JOB_DONE",
            Severity.DIAGNOSTIC,
            "slack job {owner}.{job} done in {slices} slices, {busy_ms:.1f} ms (longest slice {max_slice_ms:.1f} ms)",
        ),
        EventDef("TASK_ENABLED", Severity.ACTIVITY_HI, "task {target} enabled={enabled}"),
        EventDef("TIMING", Severity.WARNING_LO, "{n} more overrun(s)/slip(s) in {span_s:.0f} s ({top}); "
                                                "latest: {latest}"),
    )
    COMMANDS = (
        CommandDef(
            "SET_TASK_ENABLED", (Arg("target", str), Arg("enabled", bool)), doc="enable or disable a task's activation"
        ),
    )

    def cmd_SET_TASK_ENABLED(self, target: str, enabled: bool) -> None:
        runtime = self.ctx.runtime
        if target not in runtime.tasks or target == "exec":
            raise CommandError(f"no task {target!r}")
        runtime.set_enabled(target, enabled)
        self.event("TASK_ENABLED", target=target, enabled=enabled)

    def cmd_RESET_COUNTERS(self) -> None:
        self.ctx.runtime.reset_counters()
        super().cmd_RESET_COUNTERS()


class RateGroupComponent(Task):
    """One rate group's timing: last/max execution time, cycles and slips."""

    KIND: ClassVar[str] = "rate_group"
    CHANNELS = (
        Channel("cycles", "count"),
        Channel("slips", "count", hi=0, doc="frames this group was running when the next tick came"),
    )
    EVENTS = (
        EventDef(
            "SLIP",
            Severity.WARNING_HI,
            "rate group {task} slipped: frame {frame} ran {ms:.1f} ms of a {period_ms:.0f} ms period",
            throttle=5,
        ),
    )

    def __init__(self, name: str, ctx: TaskContext, budget_s: float) -> None:
        super().__init__(name, ctx, budget_s)
        self.group: RateGroupConfig | None = None
        self.members: list[Task] = []
        self.slips = 0
        self.good_frames = 0

    def cmd_RESET_COUNTERS(self) -> None:
        self.slips = 0
        self.ctx.events.reset_throttle(f"{self.name}.SLIP")
        super().cmd_RESET_COUNTERS()
