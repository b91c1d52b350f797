"""The campaign's results table: one row a mission, written as Parquet and CSV.

A row holds the mission's inputs (family, scenario parameters as ``p.<key>`` columns, scenario
string, seed, method, steps, fault set) and its results from the mission summary
(``hil_sim.mission.mission_run``): mapped cells per imaging step, map RMS error against the truth,
variance calibration (fraction of mapped cells within 2 sigma of the truth, docs/algorithm.md §4),
edge violations, geofence refusals, off-map events, slips, overruns, SAFE entries,
recoveries (left SAFE) and recoveries that resumed the mission (a step completed or the mission
ended before any new SAFE), whether SAFE became final (a persistent fault), hung-task reports
and watchdog-expired frames, how the map transfer ended, odometer, looks, steps taken without their move
(stays), frames moving on unknown ground, bench and wall time,
and the outcome class (:func:`outcome`). Wall-clock fields
(:data:`WALL_CLOCK_COLUMNS`) depend on the machine; every other column is a function of the
spec.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

OUTCOMES = ("done", "edge_violation", "undelivered", "safe", "time_limit", "error", "killed")
WALL_CLOCK_COLUMNS = ("wall_s", "slips", "overruns")
RESULT_COLUMNS = (
    "outcome", "error", "end_reason", "final_state", "safe_reason", "steps_done", "mapped_cells",
    "mapped_cells_per_step", "map_rmse_m", "calib_2sigma", "edge_violations", "geofence_refusals",
    "off_map", "slips", "overruns", "safe_entries", "safe_recoveries", "safe_recoveries_resumed", "safe_final",
    "tasks_hung", "watchdog_expired_frames", "map_transfer", "transfer_s", "odometer_m", "looks", "stays",
    "wheels_on_unknown_ground", "sim_s", "wall_s",
)


def outcome(summary: dict[str, Any]) -> str:
    """Outcome class of a finished mission: an edge violation outranks everything; then DONE,
    a map not delivered, an unrecovered SAFE, or the bench-time limit reached in any other state."""
    if summary["edge_violations"] > 0:
        return "edge_violation"
    if summary["final_state"] == "DONE":
        return "done"
    if summary.get("map_delivered") is False:
        return "undelivered"  # mapping ended, the map never reached the Cliff-bot
    if summary["final_state"] == "SAFE":
        return "safe"
    return "time_limit"


def base_row(m: dict[str, Any]) -> dict[str, Any]:
    """The inputs part of a row (``m``: a :class:`hil_sim.lab.campaign.spec.Mission` as a dict)."""
    return {
        "id": m["id"], "key": m["key"], "family": m["family"], "scenario": m["scenario"],
        "params": json.dumps(m["params"], sort_keys=True), "method": m["method"], "seed": m["seed"],
        "steps": m["steps"], "fault_set": m["fault_set"],
    }


def result_row(m: dict[str, Any], summary: dict[str, Any]) -> dict[str, Any]:
    steps = summary["steps"]
    return {
        **base_row(m),
        "outcome": outcome(summary),
        "error": "",
        "end_reason": summary["end_reason"] or "",
        "final_state": summary["final_state"],
        "safe_reason": summary["safe_reason"] or "",
        "steps_done": max((s["step"] for s in steps), default=-1),
        "mapped_cells": summary["mapped_cells"],
        "mapped_cells_per_step": ";".join(str(s["mapped_cells"]) for s in steps),
        "map_rmse_m": summary["map_rmse_m"],
        "calib_2sigma": summary["calib_2sigma"],
        "edge_violations": summary["edge_violations"],
        "geofence_refusals": summary["geofence_refusals"],
        "off_map": summary["off_map"],
        "slips": summary["slips"],
        "overruns": summary["overruns"],
        "safe_entries": summary["safe_entries"],
        "safe_recoveries": summary["safe_recoveries"],
        "safe_recoveries_resumed": summary["safe_recoveries_resumed"],
        "safe_final": summary["final_state"] == "SAFE" and summary["safe_reason"] is not None
        and summary["safe_reason"].startswith("persistent fault"),
        "tasks_hung": summary["tasks_hung"],
        "watchdog_expired_frames": summary["watchdog_expired_frames"],
        "map_transfer": summary["map_transfer"],
        "transfer_s": summary["transfer_s"],
        "odometer_m": summary["odometer_m"],
        "looks": summary["looks"],
        "stays": len(summary["stays"]),
        "wheels_on_unknown_ground": summary["wheels_on_unknown_ground"],
        "sim_s": summary["sim_s"],
        "wall_s": summary["wall_s"],
    }


def failed_row(m: dict[str, Any], kind: str, error: str, wall_s: float) -> dict[str, Any]:
    """A mission that raised (``error``) or was killed (``killed``: timeout, lost process)."""
    row: dict[str, Any] = {**base_row(m), **dict.fromkeys(RESULT_COLUMNS)}
    row.update(outcome=kind, error=error[:500], end_reason="", final_state="", safe_reason="",
               mapped_cells_per_step="", map_transfer="", wall_s=round(wall_s, 3))
    return row


def frame(rows: list[dict[str, Any]]) -> Any:
    """The table (a pyarrow Table) sorted by mission id, one ``p.<key>`` column a scenario
    parameter (null where a family does not vary it; text if any value is text)."""
    import pyarrow as pa

    rows = sorted(rows, key=lambda r: r["id"])
    params = [json.loads(r["params"]) for r in rows]
    pkeys = sorted({k for p in params for k in p})
    cols: dict[str, list[Any]] = {k: [r.get(k) for r in rows] for k in rows[0] if k != "params"} if rows else {}
    for k in pkeys:
        vals = [p.get(k) for p in params]
        if any(isinstance(v, (str, bool)) for v in vals):
            vals = [None if v is None else str(v) for v in vals]
        elif any(isinstance(v, float) for v in vals):
            vals = [None if v is None else float(v) for v in vals]
        cols[f"p.{k}"] = vals
    return pa.table(cols)


def write_table(out: Path, rows: list[dict[str, Any]]) -> Any:
    """``results.parquet`` and ``results.csv`` (atomically replaced); returns the table."""
    import pyarrow.csv as pacsv
    import pyarrow.parquet as pq

    table = frame(rows)
    tmp = out / "results.parquet.tmp"
    pq.write_table(table, tmp)
    tmp.replace(out / "results.parquet")
    tmp = out / "results.csv.tmp"
    pacsv.write_csv(table, tmp)
    tmp.replace(out / "results.csv")
    return table
