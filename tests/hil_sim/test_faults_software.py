"""The fault backdoor's software and link faults (issue 16): a stuck flight task and a radio
outage. A hung task must be caught by health and the watchdog and come back when the fault
ends; an overrunning one is counted as overruns of that task; a radio outage loses every
packet on the air in its window. Validation: one line, never a traceback."""

from __future__ import annotations

import pytest
from hil_helpers import bench

from fsw.framework.params import ConfigError, build
from hil_sim.faults import FaultInjector, FaultSpec
from hil_sim.link.radio_channel import RadioChannel, RadioChannelConfig


def test_a_hung_task_is_caught_by_health_and_the_watchdog_then_recovers() -> None:
    with bench(faults=(FaultSpec("stuck_task", start_s=2.0, duration_s=6.0, target="motion"),)) as b:
        wd = b.exe.ctx.res.watchdog
        motion = b.exe.tasks["motion"]
        b.run(20)  # 2 s: healthy
        assert not wd.expired() and not b.events("health.TASK_LATE")
        activations = motion.activations
        expired = 0
        for _ in range(60):  # the 6 s the task is stuck
            b.run(1)
            expired += wd.expired()
        assert motion.activations == activations  # no activation of the task completed
        assert b.events("health.TASK_LATE") and b.events("health.TASK_HUNG")
        assert "motion" in b.events("health.TASK_HUNG")[0].text and b.tlm("health.tasks_fatal") == 1
        assert expired > 0, "the watchdog must expire while a task is hung"
        b.run(30)  # the fault is over
        assert motion.activations > activations and b.events("health.TASK_RECOVERED")
        assert not wd.expired() and b.tlm("health.tasks_fatal") == 0
        assert not b.events(".EXCEPTION") and b.faults.counts["task_hung_activations"] == 60


def test_an_overrunning_task_is_counted_as_its_overruns_and_slips() -> None:
    with bench(faults=(FaultSpec("stuck_task", start_s=1.0, duration_s=1.0, target="motion", mode="overrun",
                                 delay_s=0.3),)) as b:
        motion = b.exe.tasks["motion"]
        b.run(10)
        before, slips, host_before = motion.overruns, b.exe.slips, motion.host.overruns
        b.run(10)
        assert motion.overruns - before == 10 and b.exe.slips - slips == 10
        assert motion.max_s >= 0.3 and b.events("motion.OVERRUN")
        # the host's measure is charged too (and may count the machine's own overruns besides)
        assert motion.host.overruns - host_before >= 10 and motion.host.max_s >= 0.3
        b.run(10)
        assert motion.overruns - before == 10  # over when the fault is
        assert all(t.overruns == 0 for n, t in b.exe.tasks.items() if n != "motion")


@pytest.mark.parametrize("row,match", [
    ({"kind": "stuck_task"}, "needs a target task"),
    ({"kind": "stuck_task", "target": "nbv", "mode": "overrun"}, "delay_s > 0"),
    ({"kind": "stuck_task", "target": "nbv", "mode": "stall"}, "mode 'stall'"),
    ({"kind": "radio_outage", "duration_s": float("nan")}, "duration_s"),
])
def test_bad_software_fault_rows_are_one_line_errors(row: dict, match: str) -> None:
    with pytest.raises(ConfigError, match=match) as exc:
        build(FaultSpec, row, source="faults.toml")
    assert "\n" not in str(exc.value)


def test_a_stuck_task_must_name_a_flight_task() -> None:
    with pytest.raises(ValueError, match="'navigation' is not a flight task"):
        bench(faults=(FaultSpec("stuck_task", target="navigation"),))
    with bench() as b:
        with pytest.raises(ValueError, match="not a flight task"):
            b.faults.inject("stuck_task", target="navigation")
        b.faults.inject("stuck_task", target="motion", duration_s=0.5)
        b.run(10)
        assert b.faults.counts["task_hung_activations"] == 5


def test_a_radio_outage_loses_the_packets_on_the_air_in_its_window() -> None:
    faults = FaultInjector(0, (FaultSpec("radio_outage", start_s=10.0, duration_s=5.0), FaultSpec("bus_off")))
    assert faults.radio_outages() == ((10.0, 5.0),)
    ch = RadioChannel(RadioChannelConfig(rate_bps=1e6, outages=faults.radio_outages()), seed=0)
    for t in (5.0, 11.0, 14.9, 16.0):
        ch.send("a", b"x" * 100, t)
    assert len(ch.receive("b", 20.0)) == 2 and ch.stats("a").outage_drops == 2


def test_a_resumed_run_is_not_reported_hung_at_its_first_frame() -> None:
    """A run resumed from a checkpoint starts at that frame, not 0: no task may look as old as
    the frame number (health counted from frame 0 and declared every task hung at once)."""
    with bench(start=(100.0, 1000)) as b:
        b.run(40)
        assert not b.events("health.TASK_LATE") and not b.events("health.TASK_HUNG")
        assert not b.exe.ctx.res.watchdog.expired() and b.tlm("health.tasks_fatal") == 0
