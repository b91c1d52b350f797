"""The close-edge experiment's judgement (hil_sim/lab/experiments/experiment_close_edge.py, issue
30 item 1): a start that a raster method left and an information method did not is counted;
a mission that never moved without a reason is counted; bad arguments exit 2."""

from __future__ import annotations

from typing import Any

import pytest

from hil_sim.cli import main
from hil_sim.lab.experiments.experiment_close_edge import report, start_spec


def _row(method: str, bearing: float, moved: bool, reasons: list[str]) -> dict[str, Any]:
    return {"method": method, "bearing_deg": bearing, "distance_m": 0.3, "seed": 0, "moved": moved,
            "odometer_m": 1.2 if moved else 0.0, "stay_reasons": reasons, "edge_violations": 0,
            "wheels_on_unknown_ground": 0, "wheels_off_terrain": 0}


def test_a_start_left_by_the_raster_but_not_by_method_5_is_not_met() -> None:
    rows = [_row("1", 0.0, True, []), _row("5", 0.0, False, []),  # frozen, and silent about it
            _row("1", -90.0, False, []), _row("5", -90.0, False, ["step 1: no move the geofence allows"])]
    md = report(rows, [], ["5", "1"])
    assert "moved: **1** (target 0) NOT MET" in md and "bearing 0, edge 0.3 m, seed 0: method 5" in md
    assert "without a reason in their summary: **1** (target 0) NOT MET" in md
    chose = {**_row("5", -90.0, False, []), "reachable_max": 24}  # it could move and viewed from its start
    assert "M5: chose views from where it stood (24 stations reachable)" in report([chose], [], ["5", "1"])
    assert "without a reason in their summary: **0**" in report([chose], [], ["5", "1"])
    ok = report([_row("1", 0.0, True, []), _row("5", 0.0, True, [])], [], ["5", "1"])
    assert "moved: **0** (target 0) met" in ok
    assert "nothing to judge" in report([], ["x: BrokenProcessPool"], ["5", "1"])


def test_start_spec_adds_the_bearing_and_distance_to_the_family() -> None:
    assert start_spec("terrain", 0.0, 0.3) == "terrain?edge_bearing_deg=0&edge_distance_m=0.3"
    spec = start_spec("terrain?slope_deg=4", -45.0, 0.2)
    assert spec == "terrain?slope_deg=4&edge_bearing_deg=-45&edge_distance_m=0.2"


@pytest.mark.parametrize("args", [["--distances", "0.1"], ["--methods", "7"], ["--bearings", "x"],
                                  ["--near-edge", "file:no/such/dem.npy"]])
def test_bad_arguments_exit_2_with_one_line(args: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["experiment", "close-edge", *args]) == 2
    assert len(capsys.readouterr().err.strip().splitlines()) == 1


def _summary(method: str, odometer: float, stays: list[str]) -> dict[str, Any]:
    return {"method": method, "odometer_m": odometer, "stays": stays, "steps": [{"step": 0}, {"step": 1}],
            "edge_violations": 0, "geofence_refusals": 0, "mapped_cells": 100, "map_rmse_m": 0.02,
            "final_state": "DONE"}


def test_raster_when_stuck_runs_the_raster_method_only_where_method_5_stayed(tmp_path, monkeypatch, capsys) -> None:
    """Seed 0: Method 5 stayed, Method 1 left (both taken from their run directories); seed 1:
    Method 5 left, so Method 1 is not run there (no directory, no mission: '-' in the table)."""
    import json

    monkeypatch.setenv("SAFER_RESULTS_DIR", str(tmp_path / "results"))
    runs = tmp_path / "out" / "runs"
    for name, s in (("b0_d0.3_seed0_m5", _summary("5", 0.0, ["step 1: no move the geofence allows"])),
                    ("b0_d0.3_seed0_m1", _summary("1", 1.5, [])), ("b0_d0.3_seed1_m5", _summary("5", 2.0, []))):
        (runs / name).mkdir(parents=True)
        (runs / name / "summary.json").write_text(json.dumps(s))
    argv = ["experiment", "close-edge", "--bearings", "0", "--distances", "0.3", "--seeds", "0,1", "--methods", "5,1",
            "--steps", "1", "--raster-when-stuck", "--reuse", "--out", str(tmp_path / "out")]
    assert main(argv) == 0
    md = (tmp_path / "out" / "close_edge.md").read_text()
    assert "| terrain | 0 | 0.3 | 0 | 0 | 1.5 |" in md and "| terrain | 0 | 0.3 | 1 | 2 | - |" in md
    assert "moved: **1** (target 0) NOT MET" in md and not (runs / "b0_d0.3_seed1_m1").exists()
