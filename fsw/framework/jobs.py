"""Slack jobs: long work resumed in bounded slices in each frame's slack.

A job is a generator that yields after each bounded step and returns its result
(``return value`` -> ``StopIteration.value``). The executive resumes jobs round-robin in
the time left before the next frame (real time) or for a fixed number of slices per frame
(stepped clock, so lockstep runs stay deterministic). A *background* job (a ground preview,
say) runs only in a slice no other job wants: it never delays the flight's own work, so a
mission's sensing keeps the same slices whether or not the ground asked for anything (and a
resumed mission the slices of the uninterrupted one). The result, or the exception, lands in
the :class:`JobHandle` that the submitting task holds and polls.

Each slice is timed twice (as the tasks are, :mod:`fsw.framework.task`): on the schedule's
``timer`` (the handle's ``busy_s`` and ``max_slice_s``, the ``max_slice_*`` figures: telemetry
and events; the stepped clock in lockstep, so deterministic) and on the ``host_timer`` (the
``host_max_slice_*`` figures: what a slice cost on this computer, for the bench's reports).
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Callable, Generator
from dataclasses import dataclass, field
from typing import Any

Job = Generator[Any, None, Any]


@dataclass
class JobHandle:
    """What a task keeps of a job it submitted."""

    name: str
    owner: str
    done: bool = False
    result: Any = None
    error: BaseException | None = None
    slices: int = 0
    busy_s: float = 0.0
    max_slice_s: float = 0.0  # longest single slice (resume to yield) of this job
    cancelled: bool = False
    background: bool = False  # runs only in slices no foreground job wants
    on_done: Callable[[JobHandle], None] | None = field(default=None, repr=False)

    def cancel(self) -> None:
        self.cancelled = True


class JobScheduler:
    """Round-robin runner of slack jobs."""

    def __init__(self, max_jobs: int = 16, timer: Callable[[], float] = time.perf_counter,
                 host_timer: Callable[[], float] | None = None) -> None:
        self.max_jobs = max_jobs
        self.timer = timer
        self.host_timer = host_timer or timer
        self._jobs: deque[tuple[JobHandle, Job]] = deque()
        self.completed = 0
        self.failed = 0
        self.max_slice_s = 0.0  # the longest slice run, any job (reset_max clears it)
        self.max_slice_owner = ""  # the task whose job ran it
        self.max_slice_by_owner: dict[str, float] = {}  # the longest slice per submitting task
        self.host_max_slice_s = 0.0  # the longest slice on the host timer, any job
        self.host_max_slice_by_owner: dict[str, float] = {}  # ... and per submitting task

    def submit(self, gen: Job, name: str, owner: str, on_done: Callable[[JobHandle], None] | None = None,
               background: bool = False) -> JobHandle:
        if len(self._jobs) >= self.max_jobs:
            raise RuntimeError(f"slack job queue full ({self.max_jobs}); {owner}.{name} refused")
        handle = JobHandle(name, owner, background=background, on_done=on_done)
        self._jobs.append((handle, gen))
        return handle

    @property
    def pending(self) -> int:
        return len(self._jobs)

    def run_slice(self) -> JobHandle | None:
        """Resume the next job for one step; returns its handle (None if idle)."""
        while self._jobs:
            # the first foreground job in round-robin order; a background job only when none waits
            k = next((i for i, (h, _) in enumerate(self._jobs) if not h.background), 0)
            handle, gen = self._jobs[k]
            del self._jobs[k]
            if handle.cancelled:
                gen.close()
                self._finish(handle, error=RuntimeError("cancelled"))
                continue
            t0, h0 = self.timer(), self.host_timer()
            try:
                next(gen)
            except StopIteration as stop:
                self._account(handle, self.timer() - t0, self.host_timer() - h0)
                self._finish(handle, result=stop.value)
                return handle
            except Exception as exc:  # noqa: BLE001 - a failing job is reported, not fatal
                self._account(handle, self.timer() - t0, self.host_timer() - h0)
                self._finish(handle, error=exc)
                return handle
            self._account(handle, self.timer() - t0, self.host_timer() - h0)
            self._jobs.append((handle, gen))
            return handle
        return None

    def _account(self, handle: JobHandle, dt: float, host_dt: float) -> None:
        """Count one slice: ``dt`` on the schedule's timer, ``host_dt`` on the host's."""
        handle.busy_s += dt
        handle.slices += 1
        handle.max_slice_s = max(handle.max_slice_s, dt)
        if dt > self.max_slice_s:
            self.max_slice_s, self.max_slice_owner = dt, handle.owner
        if dt > self.max_slice_by_owner.get(handle.owner, 0.0):
            self.max_slice_by_owner[handle.owner] = dt
        self.host_max_slice_s = max(self.host_max_slice_s, host_dt)
        if host_dt > self.host_max_slice_by_owner.get(handle.owner, 0.0):
            self.host_max_slice_by_owner[handle.owner] = host_dt

    def reset_max(self) -> None:
        """Forget the longest slice seen (``exec.RESET_COUNTERS``)."""
        self.max_slice_s, self.max_slice_owner = 0.0, ""
        self.max_slice_by_owner.clear()
        self.host_max_slice_s = 0.0
        self.host_max_slice_by_owner.clear()

    def _finish(self, handle: JobHandle, result: Any = None, error: BaseException | None = None) -> None:
        handle.done, handle.result, handle.error = True, result, error
        if error is None:
            self.completed += 1
        else:
            self.failed += 1
        if handle.on_done is not None:
            handle.on_done(handle)
