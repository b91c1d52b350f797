"""Campaign table and report (issue 16, item 3) from known rows: the headline figures, the
Parquet/CSV table (a row a mission, parameters as columns) and the report's plots."""

from __future__ import annotations

import csv
import json
from pathlib import Path
from typing import Any

import pyarrow.parquet as pq

from hil_sim.lab.campaign.report import classes, headline, write_report
from hil_sim.lab.campaign.table import failed_row, outcome, result_row, write_table


def mission(i: int, method: str, seed: int, fault_set: str = "none") -> dict[str, Any]:
    return {"id": f"f-p000-s{seed}-{fault_set}-m{method}", "key": f"k{i}", "family": "f",
            "scenario": "lab?lab.drop_m=0.4", "params": {"lab.drop_m": 0.4}, "method": method, "seed": seed,
            "steps": 2, "fault_set": fault_set}


def summary(cells: int, rmse: float, state: str = "DONE", edge: int = 0, safe: int = 0, rec: int = 0,
            resumed: int = 0, reason: str = "bus off", odo: float = 1.0, transfer: str = "delivered",
            off_map: int = 1) -> dict[str, Any]:
    return {"steps": [{"step": 0, "mapped_cells": cells // 2}, {"step": 1, "mapped_cells": cells}],
            "end_reason": "step limit", "final_state": state, "safe_reason": reason if safe else None,
            "mapped_cells": cells, "map_rmse_m": rmse, "calib_2sigma": 0.9, "edge_violations": edge,
            "geofence_refusals": 0, "off_map": off_map, "slips": 0, "overruns": 0, "safe_entries": safe,
            "safe_recoveries": rec, "safe_recoveries_resumed": resumed, "tasks_hung": 0,
            "watchdog_expired_frames": 0, "map_transfer": transfer, "transfer_s": 2.0, "odometer_m": odo,
            "looks": 0, "stays": [], "wheels_on_unknown_ground": 0, "sim_s": 100.0, "wall_s": 5.0}


def rows() -> list[dict[str, Any]]:
    return [
        result_row(mission(0, "5", 0), summary(800, 0.01, off_map=0)),
        result_row(mission(1, "oracle", 0), summary(1000, 0.02)),
        result_row(mission(2, "5", 1, "bus_off"), summary(450, 0.03, safe=1, rec=1, resumed=1)),
        result_row(mission(3, "oracle", 1, "bus_off"), summary(500, 0.01, state="SAFE", safe=4, rec=3,
                                                               reason="persistent fault: bus off", transfer="none")),
        result_row(mission(4, "1", 0), summary(300, 0.05, edge=3, odo=0.0, transfer="timeout")),
        failed_row(mission(5, "1", 1), "error", "ScenarioError: bad DEM", 0.5),
    ]


def test_outcome_classes() -> None:
    assert outcome(summary(1, 0.0)) == "done"
    assert outcome(summary(1, 0.0, edge=1)) == "edge_violation"
    assert outcome(summary(1, 0.0, state="SAFE")) == "safe"
    assert outcome(summary(1, 0.0, state="MOVE")) == "time_limit"
    assert outcome({**summary(1, 0.0, state="SAFE"), "map_delivered": False}) == "undelivered"
    assert outcome({**summary(1, 0.0, state="SAFE"), "map_delivered": None}) == "safe"  # never tried


def test_headline_figures() -> None:
    h = headline(rows())
    assert h["missions"] == 6 and h["crashed_lost"] == 0
    assert h["outcomes"] == {"done": 3, "edge_violation": 1, "undelivered": 0, "safe": 1, "time_limit": 0,
                             "error": 1, "killed": 0}
    assert h["edge_violations"] == 3 and h["off_map_events"] == 4
    assert h["map_rmse_worst_m"] == 0.05 and abs(h["map_rmse_median_m"] - 0.02) < 1e-12
    assert h["m5_oracle_pairs"] == 2 and abs(h["m5_oracle_median"] - 0.85) < 1e-12  # 0.8 and 0.9
    assert h["safe_recoveries_resumed"] == 1 and h["missions_with_safe"] == 2 and h["faulted_missions"] == 2
    assert h["safe_entries"] == 5 and h["safe_recoveries"] == 4 and h["missions_safe_final"] == 1
    assert h["missions_never_moved"] == 1 and h["maps_not_delivered"] == 1


def test_failure_classes() -> None:
    rs = {r["id"]: r for r in rows()}
    assert classes(rs["f-p000-s0-none-m5"]) == []
    assert classes(rs["f-p000-s1-bus_off-moracle"]) == ["safe", "safe_final", "off_map"]
    assert classes(rs["f-p000-s0-none-m1"]) == ["edge_violation", "off_map", "never_moved", "map_timeout"]
    assert classes(rs["f-p000-s1-none-m1"]) == ["error"]


def test_table_and_report_files(tmp_path: Path) -> None:
    rs = rows()
    write_table(tmp_path, rs)
    t = pq.read_table(tmp_path / "results.parquet").to_pylist()
    assert len(t) == 6 and [r["id"] for r in t] == sorted(r["id"] for r in rs)
    assert all(r["p.lab.drop_m"] == 0.4 for r in t)
    failed = next(r for r in t if r["outcome"] == "error")
    assert failed["mapped_cells"] is None and "bad DEM" in failed["error"]
    with (tmp_path / "results.csv").open() as fh:
        csv_rows = list(csv.DictReader(fh))
    assert [r["id"] for r in csv_rows] == [r["id"] for r in t]
    assert csv_rows[0]["mapped_cells_per_step"].count(";") == 1
    h = write_report(tmp_path, rs, "t")
    md = (tmp_path / "report.md").read_text()
    for png in ("coverage_by_method.png", "m5_vs_oracle.png", "failures.png", "fault_recovery.png",
                "failure_params.png"):
        assert (tmp_path / png).stat().st_size > 1000 and png in md
    # fault set, missions, with SAFE, SAFE entries, recoveries, resumed, final SAFE, DONE, delivered
    assert "ScenarioError: bad DEM" in md and "| bus_off | 2 | 0 | 2 | 5 | 4 | 1 | 1 | 1 | 1 | 0 | 0 |" in md
    assert "| never_moved | 1 | 1 1 | none 1 |" in md
    # per method: missions, mapped cells of those that ran (median, min, max), median RMSE (cm)
    for line in ("| 1 | 2 | 300 | 300 | 300 | 5.00 |", "| 5 | 2 | 625 | 450 | 800 | 2.00 |",
                 "| oracle | 2 | 750 | 500 | 1000 | 1.50 |"):
        assert line in md
    assert abs(h["m5_oracle_p10"] - 0.81) < 1e-12  # linear between the order statistics 0.8 and 0.9
    assert json.loads((tmp_path / "report.json").read_text()) == json.loads(json.dumps(h))


def test_fault_timing_tells_faults_that_began_before_the_mission_ended() -> None:
    """A fault drawn after the mission's end never happened: the row says so."""
    from types import SimpleNamespace

    from hil_sim.commands.campaign import with_fault_timing

    rs = rows()
    ms = [SimpleNamespace(id=r["id"], faults=({"start_s": 150.0}, {"start_s": 20.0}) if r["fault_set"] != "none"
                          else ()) for r in rs]
    out = {r["id"]: r for r in with_fault_timing(rs, ms)}
    assert out["f-p000-s1-bus_off-m5"]["fault_start_s"] == 20.0 and out["f-p000-s1-bus_off-m5"]["fault_in_mission"]
    assert out["f-p000-s0-none-m5"]["fault_start_s"] is None and out["f-p000-s0-none-m5"]["fault_in_mission"] is None
    late = [SimpleNamespace(id=m.id, faults=({"start_s": 500.0},) if m.faults else ()) for m in ms]
    assert with_fault_timing(rs, late)[2]["fault_in_mission"] is False  # sim_s 100 < 500
    assert out["f-p000-s1-none-m1"]["fault_in_mission"] is None  # the error row: no sim_s
