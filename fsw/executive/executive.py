"""The cyclic executive: minor frames, rate groups, budgets, slips and slack jobs.

Each minor frame ``k`` starts at ``k * period`` on the injected clock. Rate groups due on
``k`` (``k % divisor == offset``) run their tasks in declared order; each activation is
timed against the task's budget. Whatever time is left before the next frame runs slack
jobs (:mod:`fsw.framework.jobs`). A frame whose work ends after the next frame's start is
a *slip*, charged to the rate group that was running when the deadline passed. On the
real-time clock, lateness up to ``lag_limit_frames`` is caught up back to back; beyond
that the executive skips ahead and says so (cFS SCH). Overruns and slips are counters
(channels ``<task>.overruns``, ``<group>.slips``, ``exec.slips``); the first one after
``timing_event_period_s`` without any is an OVERRUN (SLIP) event of its task (group), the
later ones, of every task, are summarised by at most one ``exec.TIMING`` event per period
(``fsw.framework.summary``); the OVERRUN/SLIP events are throttled besides (a slot reopens
every ``throttle_decay_frames`` good frames).

Two timers time the work. The *schedule's* ``timer`` decides budgets, overruns and slips and
gives every timing channel and event: on the real-time clock it is the real clock; in lockstep
it is the stepped clock, which does not move while a frame runs, so a lockstep run's telemetry
and events (and its .tlog) are the same every time and only time a bench charges (an injected
overrun) counts. The *host's* ``host_timer`` measures what the work cost on this computer, as
a metric (``Task.host``, ``host_slips``, ``host_frame_max_s``, the jobs' ``host_max_slice_*``)
for the bench's reports; it never reaches telemetry.
"""

from __future__ import annotations

import ctypes
import dataclasses
import gc
import time
from collections.abc import Callable, Mapping

import cv2
import numpy as np

from fsw.drivers.resources import Resources
from fsw.executive.components import RateGroupComponent
from fsw.executive.topology import components
from fsw.framework.bus import Mailbox, SoftwareBus
from fsw.framework.clock import Clock
from fsw.framework.commands import CommandDispatcher, CommandRequest, CommandResponse
from fsw.framework.jobs import JobHandle, JobScheduler
from fsw.framework.summary import Summary
from fsw.framework.task import Task
from fsw.framework.telemetry import EventLog, TelemetryStore
from fsw.settings import FswConfig
from fsw.tasks.base import FlightContext

THROTTLED = ("OVERRUN", "SLIP")


def fix_malloc_thresholds(nbytes: int) -> bool:
    """Fix glibc's mmap and trim thresholds at ``nbytes`` (process-wide; no-op for 0 or off
    glibc). glibc raises its mmap threshold to the largest block freed so far (up to 32 MiB),
    after which the per-view arrays of stereo and the merge come from the heap and the freed
    space stays resident; fixed, they are mapped and returned to the system when freed (a few
    MB less peak resident memory in a mission; issue 15)."""
    if nbytes <= 0:
        return False
    try:
        libc = ctypes.CDLL("libc.so.6")
        m_trim_threshold, m_mmap_threshold = -1, -3  # malloc.h
        return bool(libc.mallopt(m_mmap_threshold, nbytes) == 1 and libc.mallopt(m_trim_threshold, nbytes) == 1)
    except (OSError, AttributeError):
        return False


def pad_malloc_heap(nbytes: int) -> bool:
    """Set glibc's heap top pad to ``nbytes`` (process-wide; no-op for 0 or off glibc): the heap
    grows by this much beyond a request and a trim leaves this much free. With the default pad
    (128 KiB) the heap of a mission's small and mid-size arrays (below the mmap threshold) grows
    and is trimmed back many times a view, and every regrowth faults its pages in afresh: a third
    of a lockstep mission's CPU time was spent in the kernel on those page faults."""
    if nbytes <= 0:
        return False
    try:
        libc = ctypes.CDLL("libc.so.6")
        m_top_pad = -2  # malloc.h
        return bool(libc.mallopt(m_top_pad, nbytes) == 1)
    except (OSError, AttributeError):
        return False


class Executive:
    """Runs the schedule in ``cfg.executive`` on ``clock``."""

    def __init__(
        self,
        cfg: FswConfig,
        clock: Clock,
        resources: Resources | None = None,
        timer: Callable[[], float] | None = None,
        host_timer: Callable[[], float] = time.perf_counter,
    ) -> None:
        """``timer``: the schedule's (module docstring); by default the real clock on a real-time
        clock and the stepped clock's time in lockstep. ``host_timer``: the host's measure."""
        ecfg = cfg.executive
        self.cfg, self.ecfg, self.clock = cfg, ecfg, clock
        self.timer: Callable[[], float] = timer or (time.perf_counter if clock.realtime else clock.now)
        self.host_timer = host_timer
        # OpenCV's worker pool is process-wide: the flight computer has one core, and two bench
        # missions sharing a 2-core machine must not each spread a slice over both cores.
        cv2.setNumThreads(ecfg.opencv_threads)
        fix_malloc_thresholds(ecfg.malloc_mmap_threshold_kib * 1024)
        pad_malloc_heap(ecfg.malloc_top_pad_kib * 1024)
        self.period_s = ecfg.frame_period_s
        self.telemetry = TelemetryStore()
        self.events = EventLog(clock.now)
        self.commands = CommandDispatcher(on_response=self._on_response)
        self.jobs = JobScheduler(timer=self.timer, host_timer=host_timer)
        self.bus = SoftwareBus(ecfg.queue_depth, on_drop=self._on_drop)
        self.ctx = FlightContext(
            clock=clock,
            telemetry=self.telemetry,
            events=self.events,
            commands=self.commands,
            bus=self.bus,
            jobs=self.jobs,
            runtime=self,
            frame_period_s=self.period_s,
            cfg=cfg,
            res=resources or Resources(),
        )
        self.frame = 0
        self.slips = 0
        self.frame_max_s = 0.0  # longest frame's work (foreground + slack), s
        self.host_slips = 0  # frames whose work took longer than the period on the host timer
        self.host_frame_max_s = 0.0  # longest frame's work on the host timer, s
        self.skipped_frames = 0
        self.lateness_s: list[float] = []
        self.tasks: dict[str, Task] = {}
        self.enabled: dict[str, bool] = {}
        self.groups: list[RateGroupComponent] = []
        self._jobs_seen: set[int] = set()
        self._timing = Summary(ecfg.timing_event_period_s)  # overruns and slips: exec.TIMING

        budgets = {t.name: t.budget_ms / 1e3 for t in ecfg.tasks}
        group_of = {t.name: t.group for t in ecfg.tasks}
        for comp in components(cfg):
            task = comp.cls(comp.name, self.ctx, budgets.get(comp.name, float("inf")))
            self._register(task, comp.opcode_base)
            self.tasks[comp.name] = task
            self.enabled[comp.name] = True
        by_name = {g.name: g for g in ecfg.groups}
        for g in ecfg.groups:
            rg = self.tasks[f"rg_{g.name}"]
            assert isinstance(rg, RateGroupComponent)
            rg.group = g
            rg.members = [self.tasks[t.name] for t in ecfg.tasks if group_of[t.name] == g.name]
            self.groups.append(rg)
        for t in ecfg.tasks:
            self.enabled[t.name] = t.enabled
            assert t.group in by_name
        self.exec_component = self.tasks["exec"]
        self._divisor = {t.name: rg.group.divisor for rg in self.groups if rg.group for t in rg.members}
        for task in self.tasks.values():
            task.setup()

    @staticmethod
    def freeze_heap() -> None:
        """Collect once, then move every live object out of the garbage collector's reach
        (``gc.freeze``): the start-up heap (modules, tasks, maps) is then never traversed
        again, so a full collection during a frame costs a few ms, not tens. Call it after
        start-up, before the first frame; :func:`thaw_heap` undoes it."""
        gc.collect()
        gc.freeze()

    @staticmethod
    def thaw_heap() -> None:
        """Give the frozen objects back to the garbage collector (end of a bench run)."""
        gc.unfreeze()

    # -- the runtime as components see it (fsw.framework.task.Runtime) -----------------------
    def is_enabled(self, name: str) -> bool:
        return self.enabled.get(name, False)

    def set_enabled(self, name: str, enabled: bool) -> None:
        self.enabled[name] = enabled

    def schedule(self) -> Mapping[str, int]:
        return self._divisor

    def busy_s(self, frame: int) -> float:
        return sum(g.last_s for g in self.groups if g.group is not None and g.group.due(frame))

    def reset_counters(self) -> None:
        self.skipped_frames = self.slips = self.host_slips = 0
        self.frame_max_s = self.host_frame_max_s = 0.0
        self.jobs.reset_max()

    # -- registration ---------------------------------------------------------------------
    def _register(self, task: Task, opcode_base: int) -> None:
        for ch in task.all_channels():
            self.telemetry.register(f"{task.name}.{ch.name}", ch)
        for ev in task.all_events():
            if ev.name in THROTTLED:
                ev = dataclasses.replace(ev, throttle=self.ecfg.event_throttle)
            self.events.register(f"{task.name}.{ev.name}", ev)
        for j, cd in enumerate(task.all_commands()):
            handler = getattr(task, f"cmd_{cd.name}", None)
            if handler is None:
                raise TypeError(f"{type(task).__name__} declares {cd.name} but has no cmd_{cd.name}")
            self.commands.register(f"{task.name}.{cd.name}", opcode_base + j, cd, handler)

    def _on_response(self, req: CommandRequest, resp: CommandResponse) -> None:
        owner = self.tasks.get(req.name.split(".", 1)[0])
        if owner is None:
            self.exec_component.cmd_errors += 1
            owner = self.exec_component
        elif resp.status.name == "OK":
            owner.cmd_count += 1
        else:
            owner.cmd_errors += 1
        if resp.status.name != "OK":
            owner.event("COMMAND_REFUSED", command=req.name, status=resp.status.name, reason=resp.message)

    def _on_drop(self, box: Mailbox[object]) -> None:
        self.exec_component.event(
            "QUEUE_FULL", mailbox=box.name, depth=box.depth, policy=box.policy, dropped=box.dropped
        )

    # -- one frame ------------------------------------------------------------------------
    def step(self) -> None:
        """Run minor frame ``self.frame`` now, then advance the frame counter."""
        k = self.frame
        self.ctx.frame = k
        period = self.period_s
        t0, h0 = self.timer(), self.host_timer()
        slip_group: RateGroupComponent | None = None
        for rg in self.groups:
            assert rg.group is not None
            if not rg.group.due(k) or not self.enabled[rg.name]:
                continue
            g0, gh0 = self.timer(), self.host_timer()
            for task in rg.members:
                if self.enabled[task.name]:
                    self._activate(task, k)
            rg.last_s = self.timer() - g0
            rg.host.add(self.host_timer() - gh0, rg.budget_s)
            rg.max_s = max(rg.max_s, rg.last_s)
            rg.activations += 1
            if slip_group is None and self.timer() - t0 > period:
                slip_group = rg
        self._run_slack(t0)
        elapsed, host_elapsed = self.timer() - t0, self.host_timer() - h0
        self.frame_max_s = max(self.frame_max_s, elapsed)
        self.host_frame_max_s = max(self.host_frame_max_s, host_elapsed)
        if host_elapsed > period:
            self.host_slips += 1
        if slip_group is None and elapsed > period:
            slip_group = self.groups[-1] if self.groups else None
        self._account_slip(slip_group, k, elapsed)
        self._publish(k)
        self.frame = k + 1

    def _activate(self, task: Task, k: int) -> None:
        a0, h0 = self.timer(), self.host_timer()
        try:
            task.run(k)
        except Exception as exc:  # noqa: BLE001 - a task fault is an event, never a crash
            task.exceptions += 1
            task.event("EXCEPTION", error=f"{type(exc).__name__}: {exc}")
        else:
            task.answer_ping()
        task.last_s = self.timer() - a0
        task.host.add(self.host_timer() - h0, task.budget_s)
        task.max_s = max(task.max_s, task.last_s)
        task.activations += 1
        if task.last_s > task.budget_s:
            task.overruns += 1
            if self._timing_episode(task.name, f"{task.name} took {task.last_s * 1e3:.1f} ms"):
                task.event("OVERRUN", ms=task.last_s * 1e3, budget_ms=task.budget_s * 1e3)
        elif task.activations % self.ecfg.throttle_decay_frames == 0:
            self.events.decay(f"{task.name}.OVERRUN")
        task.publish_timing()

    def _run_slack(self, t0: float) -> None:
        if self.clock.realtime:
            # a slice is only started when a whole slice (the slice bound) fits before the
            # margin: one begun 2 ms before it ran 10-20 ms past the frame (a slip)
            deadline = t0 + self.period_s - self.ecfg.slack_margin_s - self.ecfg.slack_slice_reserve_s
            while self.jobs.pending and self.timer() < deadline:
                self._job_slice()
        else:
            for _ in range(self.ecfg.lockstep_job_slices):
                if not self.jobs.pending:
                    break
                self._job_slice()

    def _job_slice(self) -> None:
        handle = self.jobs.run_slice()
        if handle is not None and handle.done:
            self._job_finished(handle)

    def _job_finished(self, h: JobHandle) -> None:
        ex = self.exec_component
        if h.error is not None:
            ex.event("JOB_FAILED", owner=h.owner, job=h.name, error=f"{type(h.error).__name__}: {h.error}")
        else:
            ex.event(
                "JOB_DONE",
                owner=h.owner,
                job=h.name,
                slices=h.slices,
                busy_ms=h.busy_s * 1e3,
                max_slice_ms=h.max_slice_s * 1e3,
            )

    def _account_slip(self, rg: RateGroupComponent | None, k: int, elapsed: float) -> None:
        if rg is not None:
            rg.slips += 1
            self.slips += 1
            rg.good_frames = 0
            if self._timing_episode(rg.name, f"{rg.name} frame {k} ran {elapsed * 1e3:.1f} ms"):
                rg.event("SLIP", frame=k, ms=elapsed * 1e3, period_ms=self.period_s * 1e3)
        for g in self.groups:
            if g is not rg:
                g.good_frames += 1
                if g.good_frames % self.ecfg.throttle_decay_frames == 0:
                    self.events.decay(f"{g.name}.SLIP")

    def _timing_episode(self, name: str, detail: str) -> bool:
        """True when timing has been quiet for ``timing_event_period_s`` (nothing reported or
        pending): this overrun (slip) is an event of its own; else it is counted into the next
        exec.TIMING summary (at most one a period, whatever the number of tasks)."""
        now, t = self.clock.now(), self._timing
        if not t.pending and now - t.last_report_s >= self.ecfg.timing_event_period_s:
            t.last_report_s = now  # this event is the period's report
            return True
        t.note(now, name, detail)
        return False

    def _publish(self, k: int) -> None:
        r = self._timing.report(self.clock.now())
        if r is not None:
            self.exec_component.event("TIMING", n=r.count, span_s=r.span_s, top=r.top(), latest=r.latest)
        jobs = self.jobs
        self.exec_component.tlm_record({
            "frame": k, "slips": self.slips, "skipped_frames": self.skipped_frames,
            "jobs_pending": jobs.pending, "jobs_completed": jobs.completed, "jobs_failed": jobs.failed,
            "slice_max_ms": jobs.max_slice_s * 1e3, "frame_max_ms": self.frame_max_s * 1e3,
            "bus_drops": sum(b.dropped for b in self.bus.mailboxes()),
        })
        for rg in self.groups:
            rg.tlm_record({"cycles": rg.activations, "slips": rg.slips})
            rg.publish_timing()

    # -- drivers of frames --------------------------------------------------------------------
    def frame_start(self, k: int) -> float:
        return k * self.period_s

    def run_lockstep(self, frames: int, before_frame: Callable[[int], None] | None = None) -> None:
        """Run ``frames`` frames on a stepped clock; ``before_frame(k)`` lets the simulator act."""
        for _ in range(frames):
            self.clock.sleep_until(self.frame_start(self.frame))
            if before_frame is not None:
                before_frame(self.frame)
            self.step()

    def run_realtime(self, frames: int | None = None, stop: Callable[[], bool] = lambda: False) -> None:
        """Run on the real clock with absolute deadlines until ``frames`` ran or ``stop()``."""
        start = self.clock.now()
        base_frame = self.frame
        n = 0
        while (frames is None or n < frames) and not stop():
            t_k = start + (self.frame - base_frame) * self.period_s
            self.clock.sleep_until(t_k)
            late = self.clock.now() - t_k
            lag = int(late // self.period_s)
            if lag > self.ecfg.lag_limit_frames:
                self.frame += lag
                self.skipped_frames += lag
                self.exec_component.event("SKIPPED", lag=lag, frame=self.frame)
                continue
            self.lateness_s.append(late)
            if len(self.lateness_s) > 100000:
                del self.lateness_s[:50000]
            self.exec_component.tlm("lateness_ms", late * 1e3)
            self.step()
            n += 1

    def lateness_percentiles_ms(self) -> dict[str, float]:
        arr = np.asarray(self.lateness_s) * 1e3
        if arr.size == 0:
            return {"p50": float("nan"), "p99": float("nan"), "max": float("nan")}
        return {"p50": float(np.percentile(arr, 50)), "p99": float(np.percentile(arr, 99)), "max": float(arr.max())}
