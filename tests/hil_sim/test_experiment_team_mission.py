"""``safer-hil experiment team-mission``'s report (hil_sim.lab.experiments.experiment_team_mission):
rows and fix bands from stored team missions (``--report-only``, no mission run)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import pytest

from hil_sim.lab.experiments import experiment_team_mission as tm


def _summary(reached: int, reasons: list[str], fixes: list[tuple[float, float, float, float]]) -> dict:
    return {"team": {
        "map_received": True, "targets": len(reasons), "targets_reachable_by_truth": 2, "targets_reached": reached,
        "reachable_missed": [], "tether_violations": 0, "hazard_cells_entered": 0, "unknown_cells_entered": 0,
        "final_state": "DONE" if reached else "SAFE", "safe_reason": "" if reached else "leg 1: start: hazard",
        "link_bytes_down": 3000, "link_bytes_up": 200, "map_reasons": reasons,
        "fix_ranges_m": [f[0] for f in fixes], "fix_errors_cm": [f[1] for f in fixes],
        "fix_errors_deg": [f[2] for f in fixes], "fix_nees": [f[3] for f in fixes],
        "events": [[900.0, "HOME", "back at the start"], [900.0, "DONE", "all legs driven"]] if reached else
        [[900.0, "TARGET_UNREACHABLE", "leg 4: no safe path"]]}}


def test_the_report_counts_starts_targets_and_fixes_by_range(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                             capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setenv("SAFER_RESULTS_DIR", str(tmp_path / "results"))
    runs = {0: _summary(2, ["", "", "hazard"], [(2.5, 0.4, 0.1, 3.0), (4.5, 1.0, 0.3, 20.0)]),
            1: _summary(0, ["start: hazard"] * 3, [])}
    for seed, s in runs.items():
        (tmp_path / f"seed{seed}").mkdir()
        (tmp_path / f"seed{seed}" / "summary.json").write_text(json.dumps(s))
        (tmp_path / f"seed{seed}" / "team.png").write_bytes(b"png")
    args = argparse.Namespace(scenario="cliff-team", scenes=2, seed=0, steps=10, jobs=1, config="config/fsw.toml",
                              out=tmp_path, report_only=True, results_name="team-mission")
    assert tm.run(args) == 0
    rows = (tmp_path / "team_mission.csv").read_text().splitlines()
    assert rows[1].startswith("0,1,3,2,2,") and rows[2].startswith("1,0,3,2,0,")  # seed, start usable, targets...
    md = (tmp_path / "results" / "team-mission.md").read_text()
    assert "the start usable on the delivered map in 1" in md and "targets reached 2 (of the 4" in md
    assert "the Cliff-bot back at its start at the end in 1;" in md
    assert "| DONE, at its start |" in md and "SAFE (leg 1: start: hazard), away from its start" in md
    assert "| 0-3 | 1 | 0.40 / 0.40 |" in md and "| 4-5 | 1 | 1.00 / 1.00 | 0.30 / 0.30 | 0 % |" in md
    assert "img/team-mission_team.png" in md  # the picture of the scene that reached the most
    assert "NEES within the chi2 95 % bound: 50 %" in capsys.readouterr().out


def test_each_target_says_what_became_of_it_its_looks_and_the_truths_verdict() -> None:
    t = {"map_reasons": ["", "unknown ground (3 looks)", "out of tether reach", ""],
         "reached": [True, False, False, False], "target_looks": [2, 3, 0, 0],
         "truth_reasons": ["", "", "out of tether reach", ""]}
    assert [tm.target_text(t, k) for k in range(4)] == [
        "reached (2 looks)", "unknown ground (3 looks) / truth: reachable",
        "out of tether reach / truth: out of tether reach", "planned, not reached / truth: reachable"]
    row = tm.scene_row({"team": t}, 7)["row"]
    assert row["looks"] == 5 and row["reached_after_looks"] == 1


def test_the_recon_bots_own_safety_figures_are_in_the_table_and_an_edge_violation_fails(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setenv("SAFER_RESULTS_DIR", str(tmp_path / "results"))
    own = {0: (0, 0, 0.021), 1: (641, 0, 0.42), 2: (0, 47, 0.43)}  # edge violations, unknown ground, RMSE m
    for seed, (viol, unknown, rmse) in own.items():
        s = _summary(1, ["", "hazard"], []) | {"edge_violations": viol, "wheels_on_unknown_ground": unknown,
                                               "map_rmse_m": rmse}
        (tmp_path / f"seed{seed}").mkdir()
        (tmp_path / f"seed{seed}" / "summary.json").write_text(json.dumps(s))
        (tmp_path / f"seed{seed}" / "team.png").write_bytes(b"png")
    args = argparse.Namespace(scenario="cliff-team", scenes=3, seed=0, steps=10, jobs=1, config="config/fsw.toml",
                              out=tmp_path, report_only=True, results_name="team-mission")
    assert tm.run(args) == 1
    out = capsys.readouterr()
    assert "FAILED: the RECON-bot had a wheel over the drop (641 frames) in seed(s) 1" in out.err
    md = (tmp_path / "results" / "team-mission.md").read_text()
    assert "| 641 | 0 | 42.00 |" in md and "| 0 | 47 | 43.00 |" in md and "| 0 | 0 | 2.10 |" in md
    assert "edge violations (frames with a wheel over the drop) 641" in md and "unknown ground 47" in md
    assert "map RMSE median 42.00 cm, worst 43.00 cm" in md
    (tmp_path / "seed1" / "summary.json").write_text(json.dumps(
        _summary(1, ["", "hazard"], []) | {"edge_violations": 0, "wheels_on_unknown_ground": 0, "map_rmse_m": 0.02}))
    assert tm.run(args) == 0


def test_a_held_out_run_writes_its_own_results_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """``--results-name`` writes ``NAME.md`` beside the others and leaves ``team-mission.md`` alone."""
    monkeypatch.setenv("SAFER_RESULTS_DIR", str(tmp_path / "results"))
    (tmp_path / "seed30").mkdir()
    (tmp_path / "seed30" / "summary.json").write_text(json.dumps(_summary(1, ["", "hazard"], [])))
    (tmp_path / "seed30" / "team.png").write_bytes(b"png")
    args = argparse.Namespace(scenario="cliff-team", scenes=1, seed=30, steps=10, jobs=1, config="config/fsw.toml",
                              out=tmp_path, report_only=True, results_name="team-mission-heldout")
    assert tm.run(args) == 0
    assert (tmp_path / "results" / "team-mission-heldout.md").is_file()
    assert not (tmp_path / "results" / "team-mission.md").exists()


@pytest.mark.parametrize("name", ["../elsewhere", "Team", ""])
def test_a_results_name_that_is_no_file_name_exits_2(name: str, capsys: pytest.CaptureFixture[str]) -> None:
    from hil_sim.cli import main

    assert main(["experiment", "team-mission", "--results-name", name]) == 2
    err = capsys.readouterr().err
    assert "--results-name takes lower-case letters" in err and "Traceback" not in err


def test_a_missed_target_the_truth_reaches_says_where_its_way_on_the_truth_meets_unknown_ground() -> None:
    t = {"map_reasons": ["unknown ground (3 looks)", "unknown ground", "hazard"], "reached": [False] * 3,
         "target_looks": [3, 0, 0], "truth_reasons": ["", "", "hazard"],
         "truth_way": [{"nodes": 17, "first_unknown": 12, "unknown_cells": 2, "footprint_cells": 177,
                        "slope_deg": 71.4}, {"nodes": 9, "first_unknown": None}, None]}
    assert [tm.target_text(t, k) for k in range(3)] == [
        "unknown ground (3 looks) / truth: reachable (its way on the truth: unknown from node 13 of 17, "
        "2 of 177 cells, 71 deg)",
        "unknown ground / truth: reachable (its way on the truth: known at all 9 nodes)",
        "hazard / truth: hazard"]
    assert tm.target_text({k: v for k, v in t.items() if k != "truth_way"}, 0).endswith("/ truth: reachable")


def test_each_agents_sensing_time_is_read_from_the_mission_and_reported(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The RECON-bot's imaging steps (``steps[].sim_s``) and the Cliff-bot's looks (``SENSE_REQUEST``
    to ``SENSED``) in flight time: what a team imaging cycle holds (docs/team.md, Team views)."""
    s = _summary(1, ["", "hazard"], [])
    s["steps"] = [{"step": k, "sim_s": t} for k, t in enumerate((60.0, 140.0, 190.0, 260.0))]
    s["team"]["events"] = [[900.0, "SENSE_REQUEST", "views 1"], [948.5, "SENSED", "views 1 in the map"],
                           [950.0, "LOOK", "look"], [960.0, "SENSE_REQUEST", "views 2"],
                           [1011.5, "SENSED", "views 2 in the map"], [1012.0, "SENSE_REQUEST", "views 3"]]
    times = tm.scene_row(s, 0)["times"]
    assert times == {"recon_step_s": [80.0, 50.0, 70.0], "cliffbot_look_s": [48.5, 51.5]}  # the last unanswered
    monkeypatch.setenv("SAFER_RESULTS_DIR", str(tmp_path / "results"))
    (tmp_path / "seed0").mkdir()
    (tmp_path / "seed0" / "summary.json").write_text(json.dumps(s))
    (tmp_path / "seed0" / "team.png").write_bytes(b"png")
    args = argparse.Namespace(scenario="cliff-team", scenes=1, seed=0, steps=10, jobs=1, config="config/fsw.toml",
                              out=tmp_path, report_only=True, results_name="team-mission")
    assert tm.run(args) == 0
    md = (tmp_path / "results" / "team-mission.md").read_text()
    assert "a RECON-bot imaging step took median 70.0 s (shortest 50.0 s, 3 steps)" in md
    assert "median 50.0 s (longest 51.5 s, 2 looks)" in md
