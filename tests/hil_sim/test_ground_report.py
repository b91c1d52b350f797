"""The report of ``safer-hil experiment ground`` (issue 13 "Done when"): one row per mission,
the stuck / unused-steps criteria computed from the summary fields, and argument checks."""

from __future__ import annotations

import json

from hil_sim.cli import main
from hil_sim.lab.ground_report import report_markdown, row_of


def _summary(odometer_m: float, reachable: list[int], steps: int, reason: str | None) -> dict:
    return {"method": "5", "steps": [{}] * (steps + 1), "odometer_m": odometer_m,
            "reachable_stations": reachable, "steps_unused_reason": reason, "stays": [],
            "looks": 1, "edge_violations": 0, "geofence_refusals": 0, "wheels_off_terrain": 0,
            "wheels_on_unknown_ground": 0, "mapped_cells": 1000, "map_rmse_m": 0.02,
            "map_error_tilt_deg": 0.5, "map_rmse_detilted_m": 0.01, "final_state": "DONE"}


def test_rows_flag_stuck_missions_and_unexplained_unused_steps():
    moved = row_of(_summary(1.2, [0, 3, 2], 4, None), "terrain", 0, 4)
    stuck = row_of(_summary(0.0, [0, 2, 0], 4, None), "terrain", 1, 4)
    boxed = row_of(_summary(0.0, [0, 0, 0], 2, "no reachable view worth taking"), "terrain", 2, 4)
    assert moved["moved"] and not moved["stuck"]
    assert stuck["stuck"] and not stuck["moved"]
    assert not boxed["stuck"] and boxed["unused_reason"]
    md = report_markdown([moved, stuck, boxed], [], {"family": "terrain", "terrains": 3,
                         "first_seed": 0, "methods": "5", "steps": 4, "extra": [], "jobs": 2})
    assert "never moved while a reachable station existed: **1** (target 0) NOT MET" in md
    assert "unused steps and no reason: **0** (target 0) met" in md
    assert md.count("\n| terrain |") == 3


def test_bad_arguments_exit_2(tmp_path, capsys):
    assert main(["experiment", "ground", "--methods", "7", "--out", str(tmp_path)]) == 2
    assert main(["experiment", "ground", "--family", "terrain?slope_deg=40", "--terrains", "1",
                 "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and all(line.startswith("safer-hil experiment ground:") for line in err)


def test_map_criteria_are_medians_over_generated_terrains_up_to_10_deg():
    def row(seed: int, slope: float | None, rmse: float, tilt: float) -> dict:
        r = row_of(_summary(1.0, [1], 2, None), "terrain" if slope is not None else "file:dem.npy", seed, 2)
        return {**r, "slope_deg": slope, "map_rmse_cm": rmse, "error_tilt_deg": tilt, "seam_cm": 0.3,
                "within_2sigma": 0.95}
    rows = [row(0, 2.0, 2.0, 0.1), row(1, 9.9, 2.4, 0.3), row(2, 5.0, 3.0, 0.15),
            row(3, 11.5, 50.0, 5.0), row(0, None, 9.0, 1.0)]  # > 10 deg and the DEM stay out
    md = report_markdown(rows, [], {"family": "terrain", "terrains": 4, "first_seed": 0, "methods": "5",
                                    "steps": 2, "extra": ["file:dem.npy"], "jobs": 2})
    assert "Method 5, 3 missions:" in md
    assert "map RMS error against truth, cm: median **2.4** (target <= 2.5) met; worst 3" in md
    assert "fitted tilt of the map's error, deg: median **0.15** (target <= 0.2) met; worst 0.3" in md
    assert "mapped cells within 2 sigma: median **0.95** (target 0.90-0.99) met" in md
    assert "- file:dem.npy method 5: RMSE 9.0 cm" in md
    rows[0]["error_tilt_deg"] = rows[2]["error_tilt_deg"] = 0.25
    md = report_markdown(rows, [], {"family": "terrain", "terrains": 4, "first_seed": 0, "methods": "5",
                                    "steps": 2, "extra": [], "jobs": 2})
    assert "median **0.25** (target <= 0.2) NOT MET" in md


def test_issue30_criteria_pool_method_5s_rated_views_against_method_1():
    """Item 2: Method 5's RMSE median against Method 1's, its 2-sigma median and worst; item 3: the
    obtained / expected new cells of every rated view of every Method 5 mission, pooled."""
    def row(method: str, rmse: float, w2: float, views: list[tuple[str, float, int]]) -> dict:
        s = {**_summary(1.0, [1], 2, None), "method": method, "map_rmse_m": rmse / 100,
             "steps": [{"step": 0, "view": "panorama", "expected_new_cells": 0.0, "view_new_cells": 500}]
             + [{"step": k, "view": v, "expected_new_cells": e, "view_new_cells": o}
                for k, (v, e, o) in enumerate(views, start=1)]}
        return {**row_of(s, "terrain", 0, 2), "within_2sigma": w2}
    rows = [row("1", 2.0, 0.97, [("1", 0.0, 300)]),
            row("1", 2.2, 0.95, [("1", 0.0, 300)]),
            row("5", 2.1, 0.96, [("5", 1000.0, 900), ("look", 0.0, 4000)]),
            row("5", 2.5, 0.86, [("5", 1000.0, 1100), ("5", 500.0, 1000)])]
    assert rows[3]["rated_views"] == 2 and rows[3]["pred_ratio"] == 1.55 and rows[0]["rated_views"] == 0
    md = report_markdown(rows, [], {"family": "terrain", "terrains": 2, "first_seed": 0, "methods": "5,1",
                                    "steps": 2, "extra": [], "jobs": 2})
    assert "Method 5 map RMSE median 2.30 cm against Method 1's 2.10 cm: ratio **1.10** (target <= 1.10) met" in md
    assert "within 2 sigma: median **0.910** (target 0.90-0.99), worst **0.860** (target >= 0.85) met" in md
    assert "over 3 rated views: median **1.10** (target 0.8-1.25) met" in md  # of 0.9, 1.1, 2.0; the look is apart
    rows[2]["map_rmse_cm"] = 3.0
    rows[3]["within_2sigma"] = 0.80
    md = report_markdown(rows, [], {"family": "terrain", "terrains": 2, "first_seed": 0, "methods": "5,1",
                                    "steps": 2, "extra": [], "jobs": 2})
    assert "ratio **1.31** (target <= 1.10) NOT MET" in md and "worst **0.800** (target >= 0.85) NOT MET" in md


def test_a_lab_command_without_pandas_says_which_extra(monkeypatch, capsys):
    """The lab's tables are the ``lab`` extra: a lab command on an install without it says so
    in one line (exit 1), no traceback."""
    import argparse
    import sys

    from hil_sim import cli

    def lab_command(args):
        import pandas  # noqa: F401 - what a lab report does first

    parser = argparse.ArgumentParser()
    parser.set_defaults(_run=lab_command)
    monkeypatch.setattr(cli, "build_parser", lambda only=None: parser)
    monkeypatch.setitem(sys.modules, "pandas", None)  # as if not installed
    assert cli.main([]) == 1
    assert capsys.readouterr().err.splitlines() == ["safer-hil: the lab's tables need pandas: pip install -e '.[lab]'"]


def test_reuse_takes_a_finished_mission_of_the_same_spec_and_refuses_another(tmp_path):
    from hil_sim.lab.experiments.experiment_ground import _reused

    run = tmp_path / "000_m5_seed0"
    run.mkdir()
    s = {**_summary(1.0, [1], 3, None), "scenario": "terrain", "seed": 0, "camera": "config",
         "steps_unused": 1, "edge_violations": 0}
    (run / "summary.json").write_text(json.dumps(s))
    got = _reused(run, "terrain", "5", 4, 0, "config")  # 3 steps run + 1 unused = 4 asked
    assert got is not None and got["odometer_m"] == 1.0 and "slope_deg" in got["drawn"]
    assert _reused(run, "terrain", "5", 6, 0, "config") is None  # other steps
    assert _reused(run, "terrain", "1", 4, 0, "config") is None  # other method
    assert _reused(run, "terrain", "5", 4, 1, "config") is None  # other seed
    assert _reused(run, "terrain", "5", 4, 0, "ideal") is None  # other camera
    (run / "summary.json").write_text("{not json")
    assert _reused(run, "terrain", "5", 4, 0, "config") is None
