"""Slack jobs (fsw.framework.jobs): round-robin slices; a background job never takes a slice a
foreground job wants, so the flight's own work finishes in the same slice with or without it."""

from __future__ import annotations

from collections.abc import Generator

from fsw.framework.jobs import JobScheduler


def _job(log: list[str], name: str, steps: int) -> Generator[None, None, str]:
    for k in range(steps):
        log.append(f"{name}{k}")
        yield
    return name


def _slices_to_finish(sched: JobScheduler, handle_name: str) -> int:
    n = 0
    while True:
        n += 1
        h = sched.run_slice()
        assert h is not None
        if h.done and h.name == handle_name:
            return n


def test_foreground_jobs_share_slices_round_robin() -> None:
    log: list[str] = []
    s = JobScheduler()
    s.submit(_job(log, "a", 2), "a", "t")
    s.submit(_job(log, "b", 2), "b", "t")
    while s.run_slice() is not None:
        pass
    assert log == ["a0", "b0", "a1", "b1"] and s.completed == 2


def test_a_background_job_waits_for_every_foreground_slice() -> None:
    alone = JobScheduler()
    alone.submit(_job([], "merge", 5), "merge", "perception")
    with_bg = JobScheduler()
    log: list[str] = []
    with_bg.submit(_job(log, "preview", 3), "preview", "mavlink", background=True)
    with_bg.submit(_job(log, "merge", 5), "merge", "perception")
    assert _slices_to_finish(with_bg, "merge") == _slices_to_finish(alone, "merge")
    assert not any(e.startswith("preview") for e in log)  # not one slice went to it before the merge ended
    while with_bg.run_slice() is not None:
        pass
    assert log[-3:] == ["preview0", "preview1", "preview2"] and with_bg.completed == 2


def test_a_lone_background_job_runs_and_a_cancelled_one_ends() -> None:
    s = JobScheduler()
    h = s.submit(_job([], "p", 2), "p", "mavlink", background=True)
    while s.run_slice() is not None:
        pass
    assert h.done and h.result == "p"
    h2 = s.submit(_job([], "q", 5), "q", "mavlink", background=True)
    h2.cancel()
    s.run_slice()
    assert h2.done and h2.error is not None and s.pending == 0
