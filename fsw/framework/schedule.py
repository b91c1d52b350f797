"""Configuration of the cyclic executive: minor frame, rate groups, tasks and their budgets.

The schedule is a table (cFS SCH style): rate groups by ``(divisor, offset)`` and tasks
assigned to groups in declared order. It is validated before the executive starts.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from fsw.framework.params import param

#: a rate-group or task name: it prefixes channel, event and command names (``name.CHANNEL``)
NAME_RE = re.compile(r"[A-Za-z][A-Za-z0-9_-]{0,31}")


def check_name(what: str, name: str) -> None:
    """``ValueError`` unless ``name`` is a usable identifier (non-empty, no dots or spaces)."""
    if not NAME_RE.fullmatch(name):
        raise ValueError(f"{what} name {name!r} must be 1-32 letters, digits, '_' or '-', starting with a letter")


@dataclass(frozen=True)
class RateGroupConfig:
    """A rate group runs on frames ``k`` with ``k % divisor == offset`` (F Prime RateGroupDriver)."""

    name: str = param(doc="rate group name")
    divisor: int = param(lo=1, hi=10000, doc="runs every `divisor` minor frames")
    offset: int = param(0, lo=0, hi=9999, doc="frame offset inside the divisor, spreads load")

    def __post_init__(self) -> None:
        check_name("rate group", self.name)
        if self.offset >= self.divisor:
            raise ValueError(f"rate group {self.name!r}: offset {self.offset} must be below divisor {self.divisor}")

    def due(self, frame: int) -> bool:
        return frame % self.divisor == self.offset


@dataclass(frozen=True)
class TaskConfig:
    """One task instance of the schedule."""

    name: str = param(doc="instance name; prefixes its channels, events and commands")
    kind: str = param(doc="task kind from fsw.registry")
    group: str = param(doc="rate group the task runs in")
    budget_ms: float = param(lo=0.001, hi=100000.0, units="ms", doc="execution-time budget per activation")
    enabled: bool = param(True, doc="a disabled task is built but never activated")

    def __post_init__(self) -> None:
        check_name("task", self.name)
        if not self.kind.strip():
            raise ValueError(f"task {self.name!r}: empty kind")


@dataclass(frozen=True, kw_only=True)
class ExecutiveConfig:
    """The cyclic executive (docs/architecture.md, "The cyclic executive")."""

    flight: bool = param(
        True, doc="a flight file: every section and key present, a mission scheduled (false: bench and ground-tool "
        "files, whose left-out keys take their defaults)")
    frame_period_s: float = param(0.1, lo=0.001, hi=10.0, units="s", doc="minor frame period")
    groups: tuple[RateGroupConfig, ...] = param(doc="rate groups, in execution order")
    tasks: tuple[TaskConfig, ...] = param(doc="tasks, in execution order within their group")
    lag_limit_frames: int = param(
        3, lo=0, hi=1000, doc="frames behind that are caught up back to back; beyond, skip ahead"
    )
    slack_margin_s: float = param(
        0.005, lo=0.0, hi=1.0, units="s", doc="slack work stops this long before the next frame"
    )
    slack_slice_reserve_s: float = param(
        0.02, lo=0.0, hi=1.0, units="s",
        doc="real time: a slice starts only if this much is left before the margin (the slice bound)")
    lockstep_job_slices: int = param(
        4, lo=1, hi=1000, doc="slack-job slices per frame on the stepped clock (deterministic)"
    )
    event_throttle: int = param(5, lo=1, hi=10000, doc="overrun/slip events emitted before the throttle closes")
    throttle_decay_frames: int = param(10, lo=1, hi=100000, doc="good frames that reopen one throttle slot")
    timing_event_period_s: float = param(
        60.0, lo=0.1, hi=86400.0, units="s",
        doc="the first overrun or slip after this long without one is an event; the others, of every task, "
            "are counted and summarised by at most one exec.TIMING event per period")
    health_warn_frames: int = param(10, lo=1, hi=100000, doc="frames without a ping answer before WARNING_HI")
    health_fatal_frames: int = param(30, lo=1, hi=100000, doc="frames without a ping answer before FATAL")
    health_event_period_s: float = param(
        60.0, lo=0.1, hi=86400.0, units="s",
        doc="per task: the first lateness after this long without one is a TASK_LATE event; the later ones are "
            "counted and summarised by at most one TASK_LATE_REPEATS event per period")
    health_recover_frames: int = param(
        20, lo=1, hi=100000, doc="frames a late or hung task answers on time before TASK_RECOVERED")
    queue_depth: int = param(8, lo=1, hi=100000, doc="default software-bus mailbox depth")
    opencv_threads: int = param(
        1, lo=1, hi=64, doc="OpenCV worker threads for the whole process (cv2.setNumThreads), set at start-up"
    )
    malloc_mmap_threshold_kib: int = param(
        8192, lo=0, hi=1 << 20, units="KiB",
        doc="glibc: blocks this large or larger are mmapped and returned when freed (0 = glibc's sliding default)")
    malloc_top_pad_kib: int = param(
        65536, lo=0, hi=1 << 20, units="KiB",
        doc="glibc: the heap grows by this much beyond a request and keeps this much free when trimmed, so "
            "the blocks below the mmap threshold reuse resident pages instead of faulting fresh ones in every "
            "cycle (0 = glibc's default)")

    def __post_init__(self) -> None:
        if not self.groups or not self.tasks:
            raise ValueError("the schedule needs at least one rate group and one task")
        names = [g.name for g in self.groups]
        if len(set(names)) != len(names):
            raise ValueError("rate group names must be unique")
        tnames = [t.name for t in self.tasks]
        if len(set(tnames)) != len(tnames):
            dup = next(n for n in tnames if tnames.count(n) > 1)
            raise ValueError(f"task name {dup!r} is used twice")
        for t in self.tasks:
            if t.group not in names:
                raise ValueError(f"task {t.name!r} names unknown rate group {t.group!r} (groups: {', '.join(names)})")
        if self.health_fatal_frames <= self.health_warn_frames:
            raise ValueError("health_fatal_frames must exceed health_warn_frames")
