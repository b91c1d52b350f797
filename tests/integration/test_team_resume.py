"""The whole team resumes (docs/team.md, "Running a team mission"): a team mission stopped inside
the RECON-bot's second step and continued with ``mode="resume"`` (``safer-hil run --resume``) ends
as the uninterrupted one, the Cliff-bot from the checkpoint it held at the RECON-bot's last
checkpoint and its hardware from where it stood."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest
from resume_checks import assert_same

from hil_sim.mission.mission_report import strip_wall_clock
from hil_sim.mission.mission_run import RunSpec, run_mission

pytestmark = pytest.mark.slow  # three short team missions (two RECON-bot steps each)


def test_a_stopped_team_mission_resumes_to_the_uninterrupted_result(tmp_path: Path) -> None:
    spec = RunSpec("cliff-team", "5", steps=2, seed=3, out=tmp_path / "ref")
    ref = run_mission(spec)
    assert ref["team"]["map_received"] and ref["team"]["final_state"] in ("DONE", "SAFE")
    cut = dataclasses.replace(spec, out=tmp_path / "cut")
    part = run_mission(cut, max_sim_s=ref["steps"][1]["sim_s"] + 1.0)
    assert part["final_state"] not in ("DONE", "SAFE") and len(part["steps"]) == 2
    assert part["team"]["final_state"] == "WAIT_MAP"  # the Cliff-bot still waited for the map
    done = run_mission(cut, mode="resume")
    assert (tmp_path / "cut" / "cliffbot_checkpoints" / "cliffbot_state.json").exists()
    same = {"files": None}
    a, b = strip_wall_clock(done) | same, strip_wall_clock(ref) | same
    assert_same(a["team"], b["team"])
    assert_same(a, b)
