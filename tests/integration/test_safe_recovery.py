"""The automatic SAFE recovery end to end in lockstep (issue 16, fsw/tasks/mission_safe.py):
the real mast driver latches a controller fault, so a recovery must clear it before the mission
can move the mast again. A fault that ends is recovered from and the mission finishes; one that
stays ends the mission in SAFE after the configured number of tries, with the reason, and the
run stops there (no SAFE loop until the bench-time limit)."""

from __future__ import annotations

import pytest

from hil_sim.faults import FaultSpec
from hil_sim.mission.mission_run import RunSpec, run_mission


def _run(duration_s: float) -> dict:
    faults = (FaultSpec("mast_stall", start_s=5.0, duration_s=duration_s),)  # during the panorama
    return run_mission(RunSpec("lab", "5", steps=0, seed=0, transmit=False, faults=faults, safe_recover_s=10.0))


@pytest.mark.slow
def test_a_latched_fault_that_ends_is_cleared_and_the_mission_finishes() -> None:
    s = _run(20.0)
    assert s["final_state"] == "DONE" and s["mapped_cells"] > 1000
    # SAFE at the stall; the first recovery (at ~15 s + 10 s) may meet the stall still there,
    # a later one clears the latched fault for good and the panorama completes
    assert 1 <= s["safe_entries"] <= 3 and s["safe_recoveries"] == s["safe_entries"]
    assert s["safe_recoveries_resumed"] == 1 and "mast faults" in s["safe_reason"]


@pytest.mark.slow
def test_a_fault_that_stays_ends_the_mission_in_safe_after_the_bounded_tries() -> None:
    s = _run(1e9)
    assert s["final_state"] == "SAFE" and s["safe_reason"].startswith("persistent fault: mast move")
    tries = 3  # config/fsw.toml [mission] safe_max_recoveries
    assert s["safe_entries"] == tries + 1 and s["safe_recoveries"] == tries and s["safe_recoveries_resumed"] == 0
    assert s["sim_s"] < 5.0 + (tries + 2) * 40.0  # stopped at the final SAFE, not at the time limit
