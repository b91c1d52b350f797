"""Issue 2: rate groups, budgets, overruns, slips, slack jobs, health and the watchdog.

All on the stepped clock with an injected execution timer, so the tests are exact and
independent of machine load.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from typing import Any, ClassVar

import numpy as np
import pytest

from fsw import registry
from fsw.drivers.resources import Resources
from fsw.executive.executive import Executive
from fsw.framework.clock import SteppedClock
from fsw.framework.params import build
from fsw.framework.task import Task
from fsw.framework.watchdog import SoftwareWatchdog
from fsw.settings import FswConfig


class FakeTimer:
    """Execution-time source that tasks advance explicitly ("CPU time" they burn)."""

    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


TIMER = FakeTimer()


class RecorderTask(Task):
    KIND: ClassVar[str] = "test_recorder"
    cost_s: ClassVar[dict[str, float]] = {}
    log: ClassVar[list[tuple[int, str]]] = []

    def run(self, frame: int) -> None:
        RecorderTask.log.append((frame, self.name))
        TIMER.t += RecorderTask.cost_s.get(self.name, 0.0)


class FailingTask(Task):
    KIND: ClassVar[str] = "test_failing"

    def run(self, frame: int) -> None:
        raise RuntimeError("device unplugged")


class JumpClock:
    """A real-time clock (``realtime = True``) whose time moves only when told: ``sleep_until``
    jumps to the deadline and a :class:`StallTask` burns time on it. Also the execution timer,
    so lateness, catch-up, skips and slips follow from the script, not from the machine."""

    realtime = True

    def __init__(self) -> None:
        self.t = 0.0

    def now(self) -> float:
        return self.t

    def __call__(self) -> float:
        return self.t

    def sleep_until(self, t: float) -> None:
        self.t = max(self.t, t)


class StallTask(Task):
    KIND: ClassVar[str] = "test_stall"
    clock: ClassVar[JumpClock] = JumpClock()
    stall_s: ClassVar[dict[int, float]] = {}

    def run(self, frame: int) -> None:
        StallTask.clock.t += StallTask.stall_s.get(frame, 0.0)


@pytest.fixture(autouse=True, scope="module")
def _test_kinds() -> Iterator[None]:
    """The test task kinds, known to the registry for this module only (``KINDS`` is restored)."""
    with pytest.MonkeyPatch.context() as mp:
        for cls in (RecorderTask, FailingTask, StallTask):
            mp.setitem(registry.KINDS, cls.KIND, f"{__name__}:{cls.__name__}")
        yield


def make_cfg(groups: list[dict[str, Any]], tasks: list[dict[str, Any]], **execu: Any) -> FswConfig:
    data = {"executive": {"frame_period_s": 0.1, "groups": groups, "tasks": tasks, **execu}}
    return build(FswConfig, data, source="<test>")


def make_exec(cfg: FswConfig, **res: Any) -> Executive:
    RecorderTask.log.clear()
    RecorderTask.cost_s.clear()
    TIMER.t = 0.0
    return Executive(cfg, SteppedClock(), resources=Resources(**res), timer=TIMER)


def task(name: str, group: str, kind: str = "test_recorder", budget_ms: float = 10.0) -> dict[str, Any]:
    return {"name": name, "kind": kind, "group": group, "budget_ms": budget_ms}


@pytest.mark.parametrize(("divisor", "offset"), [(1, 0), (2, 1), (5, 0), (5, 3), (10, 7)])
def test_rate_group_firing_pattern(divisor: int, offset: int) -> None:
    """Issue 2, item 5: a group runs exactly on frames k with k % divisor == offset."""
    cfg = make_cfg([{"name": "g", "divisor": divisor, "offset": offset}], [task("a", "g")])
    exe = make_exec(cfg)
    exe.run_lockstep(40)
    assert [f for f, _ in RecorderTask.log] == [k for k in range(40) if k % divisor == offset]


def test_tasks_run_in_declared_order_across_groups() -> None:
    """Issue 2, item 5: groups in declared order, tasks in declared order inside each."""
    cfg = make_cfg(
        [{"name": "fast", "divisor": 1}, {"name": "slow", "divisor": 2, "offset": 0}],
        [task("s1", "slow"), task("f1", "fast"), task("f2", "fast")],
    )
    exe = make_exec(cfg)
    exe.run_lockstep(2)
    assert RecorderTask.log == [(0, "f1"), (0, "f2"), (0, "s1"), (1, "f1"), (1, "f2")]


def test_overruns_are_counters_with_one_event_per_episode_and_a_rate_limited_summary() -> None:
    """Issues 2 and 29 (item 3): every overrun is counted; the first of an episode is an event,
    the rest are summed into at most one exec.TIMING event per timing_event_period_s."""
    cfg = make_cfg([{"name": "g", "divisor": 1}], [task("t", "g", budget_ms=5.0)], timing_event_period_s=2.0)
    exe = make_exec(cfg)
    RecorderTask.cost_s["t"] = 0.008  # 8 ms against a 5 ms budget, every frame for 10 s
    exe.run_lockstep(100)
    t = exe.tasks["t"]
    assert t.overruns == 100 and exe.telemetry.get("t.overruns") == 100
    assert exe.telemetry.limit_state("t.overruns") == "high"
    assert [e.name for e in exe.events.history if e.name == "t.OVERRUN"] == ["t.OVERRUN"]
    assert 4 <= exe.events.count("exec.TIMING") <= 5  # one per 2 s, not 99 events
    summaries = [e for e in exe.events.history if e.name == "exec.TIMING"]
    assert summaries[0].text.startswith("20 more overrun(s)/slip(s) in 2 s (t 20)")
    assert 1 + exe._timing.total == 100  # nothing lost: the episode's event + the summarised ones
    # (identical summaries within the event log's repeat window are themselves counted, not repeated)
    # quiet for a period: the next overrun opens a new episode, an event again
    RecorderTask.cost_s["t"] = 0.001
    exe.run_lockstep(25)
    RecorderTask.cost_s["t"] = 0.008
    exe.run_lockstep(1)
    assert len([e for e in exe.events.history if e.name == "t.OVERRUN"]) == 2
    # The max is resettable by command.
    assert exe.tasks["t"].max_s == pytest.approx(0.008)
    from fsw.framework.commands import CommandRequest, CommandStatus

    resp = exe.commands.dispatch(CommandRequest("t.RESET_COUNTERS", {}))
    assert resp.status is CommandStatus.OK
    assert exe.tasks["t"].max_s == 0.0 and exe.tasks["t"].overruns == 0


def test_slip_detected_and_charged_to_running_group() -> None:
    """Issue 2: a frame whose work runs past the next tick is a slip of the group running then."""
    cfg = make_cfg(
        [{"name": "fast", "divisor": 1}, {"name": "slow", "divisor": 4, "offset": 2}],
        [task("f", "fast"), task("s", "slow", budget_ms=200.0)],
    )
    exe = make_exec(cfg)
    RecorderTask.cost_s.update({"f": 0.01, "s": 0.15})
    exe.run_lockstep(8)
    assert exe.slips == 2  # frames 2 and 6
    assert exe.tasks["rg_slow"].slips == 2 and exe.tasks["rg_fast"].slips == 0
    assert exe.events.count("rg_slow.SLIP") == 1  # the second is within timing_event_period_s: summarised
    assert exe._timing.by_key["rg_slow"] == 1
    assert exe.telemetry.get("exec.slips") == 2


def test_two_second_slack_job_completes_while_10hz_task_never_misses() -> None:
    """Issue 2, item 6: a 2 s job runs in slices; the 10 Hz foreground never misses a frame."""
    cfg = make_cfg([{"name": "fast", "divisor": 1}], [task("fg", "fast")], lockstep_job_slices=2)
    exe = make_exec(cfg)
    RecorderTask.cost_s["fg"] = 0.02

    def job() -> Any:
        total = 0
        for i in range(80):  # 80 slices x 25 ms = 2 s of work
            TIMER.t += 0.025
            total += i
            yield i
        return total

    handle = exe.tasks["fg"].submit_job(job(), "long")
    exe.run_lockstep(60)
    assert handle.done and handle.error is None and handle.result == sum(range(80))
    assert handle.busy_s == pytest.approx(2.0)
    assert handle.slices == 81  # 80 yields + the final resume that returns
    assert [f for f, n in RecorderTask.log if n == "fg"] == list(range(60))
    assert exe.slips == 0
    assert exe.events.count("exec.JOB_DONE") == 1


def test_longest_slack_slice_is_recorded_per_job_per_task_and_overall() -> None:
    """The longest slice (resume to yield) of each job, of each submitting task and overall:
    in the handle, the JOB_DONE event, ``exec.slice_max_ms``; RESET_COUNTERS clears it."""
    from fsw.framework.commands import CommandRequest, CommandStatus

    cfg = make_cfg([{"name": "fast", "divisor": 1}], [task("a", "fast"), task("b", "fast")], lockstep_job_slices=1)
    exe = make_exec(cfg)

    def job(costs: list[float]) -> Any:
        for c in costs:
            TIMER.t += c
            yield None
        return len(costs)

    ha = exe.tasks["a"].submit_job(job([0.004, 0.012, 0.003]), "ja")
    hb = exe.tasks["b"].submit_job(job([0.007, 0.002]), "jb")
    exe.run_lockstep(10)
    assert ha.done and hb.done
    assert ha.max_slice_s == pytest.approx(0.012) and hb.max_slice_s == pytest.approx(0.007)
    assert exe.jobs.max_slice_s == pytest.approx(0.012) and exe.jobs.max_slice_owner == "a"
    assert exe.jobs.max_slice_by_owner == pytest.approx({"a": 0.012, "b": 0.007})
    assert exe.telemetry.get("exec.slice_max_ms") == pytest.approx(12.0)
    assert exe.frame_max_s == pytest.approx(0.012)  # one slice per frame; the foreground costs nothing
    assert exe.telemetry.get("exec.frame_max_ms") == pytest.approx(12.0)
    done = [e.text for e in exe.events.history if e.name == "exec.JOB_DONE"]
    assert any("a.ja" in t and "longest slice 12.0 ms" in t for t in done), done
    resp = exe.commands.dispatch(CommandRequest("exec.RESET_COUNTERS", {}))
    assert resp.status is CommandStatus.OK
    assert exe.jobs.max_slice_s == 0.0 and exe.jobs.max_slice_by_owner == {} and exe.frame_max_s == 0.0


def test_failing_job_is_reported_not_fatal() -> None:
    """Issue 2, item 6: an exception in a job lands in its handle and raises an event."""
    cfg = make_cfg([{"name": "fast", "divisor": 1}], [task("fg", "fast")])
    exe = make_exec(cfg)

    def bad() -> Any:
        yield 1
        raise ValueError("singular matrix")

    h = exe.tasks["fg"].submit_job(bad(), "bad")
    exe.run_lockstep(3)
    assert h.done and isinstance(h.error, ValueError)
    assert exe.events.count("exec.JOB_FAILED") == 1


def test_hung_task_detected_and_watchdog_starves() -> None:
    """Issue 2, item 7: health warns then declares a hung task fatal; strokes stop."""
    cfg = make_cfg(
        [{"name": "fast", "divisor": 1}, {"name": "slow", "divisor": 10, "offset": 3}],
        [task("worker", "fast"), task("health", "slow", kind="health")],
        health_warn_frames=10,
        health_fatal_frames=30,
    )
    clock = SteppedClock()
    wd = SoftwareWatchdog(clock, timeout_s=1.5)
    exe = Executive(cfg, clock, resources=Resources(watchdog=wd), timer=TIMER)
    exe.run_lockstep(100)
    assert not wd.expired() and wd.strokes == 10
    exe.tasks["worker"].hung = True
    exe.run_lockstep(100)
    assert exe.events.count("health.TASK_LATE") == 1
    assert exe.events.count("health.TASK_HUNG") == 1
    assert wd.expired()
    assert exe.telemetry.get("health.tasks_fatal") == 1
    exe.tasks["worker"].hung = False
    exe.run_lockstep(10)
    assert not wd.expired() and exe.events.count("health.TASK_RECOVERED") == 0  # not yet sustained
    exe.run_lockstep(20)
    assert exe.events.count("health.TASK_RECOVERED") == 1 and not wd.expired()


def test_a_flapping_task_is_counted_exactly_and_said_at_most_three_times_a_window() -> None:
    """Issue 29: a task late every 4 s (never hung) for 5 minutes: every late episode is in
    health.late_episodes and in the events (the first TASK_LATE plus the TASK_LATE_REPEATS
    counts), but each 60 s window holds at most 3 health events; TASK_RECOVERED only once the
    task has answered on time for health_recover_frames."""
    cfg = make_cfg(
        [{"name": "fast", "divisor": 1}, {"name": "slow", "divisor": 10, "offset": 3}],
        [task("worker", "fast"), task("health", "slow", kind="health")],
        health_warn_frames=10, health_fatal_frames=30, health_event_period_s=60.0, health_recover_frames=20,
    )
    exe = make_exec(cfg)
    worker, stretches = exe.tasks["worker"], 0
    for k in range(3000):  # 300 s: hung 25 frames (late, never fatal), then answering 15 (< recover)
        hang = k % 40 < 25 and k >= 40
        stretches += hang and not worker.hung
        worker.hung = hang
        exe.run_lockstep(1)
    worker.hung = False
    exe.run_lockstep(700)  # quiet: the pending count is reported and the task recovers
    health = [e for e in exe.events.history if e.name.startswith("health.")]
    repeats = [int(re.search(r"late (\d+) more", e.text).group(1))  # type: ignore[union-attr]
               for e in health if e.name == "health.TASK_LATE_REPEATS"]
    assert exe.telemetry.get("health.late_episodes") == stretches == 74
    assert exe.events.count("health.TASK_LATE") + sum(repeats) == stretches  # no lateness lost
    assert exe.events.count("health.TASK_RECOVERED") == 1 and not exe.events.count("health.TASK_HUNG")
    for e in health:
        window = [f for f in health if e.time_s <= f.time_s < e.time_s + 60.0]
        assert len(window) <= 3, [f.text for f in window]
    assert len(health) < stretches / 10


def test_task_raising_every_frame_is_caught_and_detected() -> None:
    """Issue 2, items 7/8: exceptions are events (throttled), never crashes; health sees it."""
    cfg = make_cfg(
        [{"name": "fast", "divisor": 1}],
        [task("bad", "fast", kind="test_failing"), task("health", "fast", kind="health")],
        health_warn_frames=5,
        health_fatal_frames=10,
    )
    exe = make_exec(cfg)
    exe.run_lockstep(30)
    assert exe.tasks["bad"].exceptions == 30
    assert exe.events.count("bad.EXCEPTION") == 30
    assert exe.events.count("health.TASK_HUNG") == 1


def test_stalled_executive_stops_stroking_watchdog() -> None:
    """Issue 2, item 7: if frames stop running the watchdog expires."""
    cfg = make_cfg([{"name": "fast", "divisor": 1}], [task("health", "fast", kind="health")])
    clock = SteppedClock()
    wd = SoftwareWatchdog(clock, timeout_s=0.5)
    exe = Executive(cfg, clock, resources=Resources(watchdog=wd), timer=TIMER)
    exe.run_lockstep(10)
    assert not wd.expired()
    clock.advance(2.0)  # the executive is stuck: time passes, no frame runs
    assert wd.expired()


def test_disable_task_by_command() -> None:
    """Issue 2, item 8: executive command SET_TASK_ENABLED."""
    from fsw.framework.commands import CommandRequest, CommandStatus

    cfg = make_cfg([{"name": "fast", "divisor": 1}], [task("a", "fast")])
    exe = make_exec(cfg)
    r = exe.commands.dispatch(CommandRequest("exec.SET_TASK_ENABLED", {"target": "a", "enabled": False}))
    assert r.status is CommandStatus.OK
    exe.run_lockstep(3)
    assert RecorderTask.log == []
    r = exe.commands.dispatch(CommandRequest("exec.SET_TASK_ENABLED", {"target": "zz", "enabled": True}))
    assert r.status is CommandStatus.EXECUTION_ERROR


def test_realtime_clock_absolute_deadlines() -> None:
    """Issue 2, item 4: frame k starts at start + k*period; a late frame is counted, not drifted."""
    from fsw.framework.clock import MonotonicClock

    cfg = make_cfg([{"name": "fast", "divisor": 1}], [task("a", "fast")], frame_period_s=0.01, lag_limit_frames=2)
    exe = Executive(cfg, MonotonicClock())
    RecorderTask.log.clear()
    clock = exe.clock
    t0 = clock.now()
    exe.run_realtime(20)
    elapsed = clock.now() - t0
    assert 0.19 <= elapsed < 0.5  # 20 frames of 10 ms: no accumulated drift beyond one frame
    assert len(exe.lateness_s) == 20


def _stalled_exec(stall_s: dict[int, float]) -> Executive:
    StallTask.clock, StallTask.stall_s = JumpClock(), stall_s
    cfg = make_cfg(
        [{"name": "fast", "divisor": 1}],
        [task("st", "fast", kind="test_stall", budget_ms=50)],
        frame_period_s=0.01,
        lag_limit_frames=2,
    )
    return Executive(cfg, StallTask.clock, timer=StallTask.clock)


def test_realtime_skip_ahead_past_lag_limit() -> None:
    """Issue 2, item 5: bounded catch-up; past the lag limit the executive skips and says so.
    Frame 2 takes 85 ms of a 10 ms period: frame 3 would start 7.5 periods late (limit 2), so
    the executive skips 7 frames once, runs frame 10 on time and goes on from there."""
    exe = _stalled_exec({2: 0.085})
    exe.run_realtime(10)
    assert exe.skipped_frames == 7 and exe.frame == 17
    assert exe.events.count("exec.SKIPPED") == 1
    assert [e.text for e in exe.events.history if e.name == "exec.SKIPPED"] == [
        "executive 7 frames behind; skipped ahead to frame 10"
    ]
    assert exe.slips == 1 and exe.tasks["st"].overruns == 1
    assert exe.lateness_s == pytest.approx([0.0, 0.0, 0.0] + [0.005] + [0.0] * 6, abs=1e-9)


def test_realtime_late_frames_within_the_lag_limit_catch_up() -> None:
    """Issue 2, item 5: up to ``lag_limit_frames`` late, frames run back to back (no skip):
    frame 2 takes 25 ms, frames 3 and 4 start 15 and 5 ms late, frame 5 is on time again."""
    exe = _stalled_exec({2: 0.025})
    exe.run_realtime(8)
    assert exe.skipped_frames == 0 and exe.events.count("exec.SKIPPED") == 0 and exe.frame == 8
    assert exe.lateness_s == pytest.approx([0.0, 0.0, 0.0, 0.015, 0.005, 0.0, 0.0, 0.0], abs=1e-9)
    assert exe.slips == 1


def test_malloc_thresholds_fixed_on_glibc_and_off_for_zero() -> None:
    """[executive] malloc_mmap_threshold_kib (issue 15): glibc accepts the fixed thresholds; 0
    leaves the allocator alone."""
    import platform

    from fsw.executive.executive import fix_malloc_thresholds

    assert fix_malloc_thresholds(0) is False
    if platform.system() == "Linux" and platform.libc_ver()[0] == "glibc":
        assert fix_malloc_thresholds(128 * 1024) is True


def test_realtime_slack_starts_a_slice_only_when_a_whole_one_fits() -> None:
    """Issue 15: with 19 ms slices a frame of 100 ms never overruns (a slice begun a few ms
    before the margin used to run past the frame); with no reserve it did, the old way."""
    results = {}
    for reserve in (0.02, 0.0):
        clock = JumpClock()
        cfg = make_cfg([{"name": "fast", "divisor": 1}], [task("fg", "fast")], frame_period_s=0.1,
                       slack_margin_s=0.005, slack_slice_reserve_s=reserve)
        exe = Executive(cfg, clock, timer=clock)

        def job(c: JumpClock) -> Any:
            for _ in range(200):
                c.t += 0.019  # one bounded slice of work
                yield None

        handle = exe.tasks["fg"].submit_job(job(clock), "long")
        exe.run_realtime(30)
        results[reserve] = (exe.slips, handle.slices)
    assert results[0.02][0] == 0 and results[0.02][1] >= 30 * 3  # still 3-4 slices a frame
    assert results[0.0][0] > 0  # without the reserve the fifth slice of a frame overruns it


def test_malloc_top_pad_keeps_freed_heap_pages_resident() -> None:
    """[executive] malloc_top_pad_kib: with the pad, arrays below the mmap threshold allocated
    and freed again and again reuse resident pages (almost no page faults after the first
    round); 0 leaves the allocator alone."""
    import platform
    import resource

    from fsw.executive.executive import fix_malloc_thresholds, pad_malloc_heap

    assert pad_malloc_heap(0) is False
    if platform.system() != "Linux" or platform.libc_ver()[0] != "glibc":
        pytest.skip("glibc's mallopt")
    assert fix_malloc_thresholds(128 * 1024) is True
    assert pad_malloc_heap(64 << 20) is True

    def churn() -> None:  # 80 blocks of 96 KiB (below the 128 KiB mmap threshold): 1920 pages
        blocks = [np.ones(96 * 1024 // 8) for _ in range(80)]
        del blocks

    churn()
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    for _ in range(5):
        churn()
    faults = resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before
    assert faults < 5 * 1920 // 4, faults  # the default 128 KiB pad faults every page in again (~9600)
