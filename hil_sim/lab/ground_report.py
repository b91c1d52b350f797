"""Rows and the markdown report of ``safer-hil experiment ground`` (issue 13, "Done when").

One row per mission, from its ``summary.json`` (hil_sim/mission/mission_run.py) and the map it wrote.
The map's error against truth is also summarised by the plane fitted to it (least squares
over mapped cells, ``hil_sim.mission.mission_run.error_plane``): its tilt shows how much of the error is
the map tilted by the rover's own attitude, its RMS after removing the plane what is left.
"""

from __future__ import annotations

from typing import Any

import pandas as pd

COLUMNS = ("scenario", "seed", "slope_deg", "edge_gap_m", "method", "moved", "odometer_m", "reachable_max", "stuck",
           "steps_used", "steps_asked", "unused_reason", "stays", "looks", "edge_violations",
           "geofence_refusals", "wheels_off_terrain", "wheels_on_unknown_ground", "mapped_cells",
           "map_rmse_cm", "error_tilt_deg", "rmse_detilted_cm", "seam_cm", "within_2sigma", "final_state",
           "views_registered", "views_height_tilt_only", "views_unregistered", "views_halves_disagree",
           "rated_views", "pred_ratio", "tilt_offset_deg", "tilt_offset_true_deg", "imu_roll_deg",
           "imu_roll_true_deg")
MOVED_M = 0.05  # the rover moved if its true odometer passed this
MAP_SLOPE_MAX_DEG = 10.0  # the map criteria hold on generated terrains up to this slope
# issue 13 "Done when", map figures: (column, what, target test on the median, target text)
MAP_CRITERIA = (
    ("map_rmse_cm", "map RMS error against truth, cm", lambda m: m <= 2.5, "<= 2.5"),
    ("error_tilt_deg", "fitted tilt of the map's error, deg", lambda m: m <= 0.2, "<= 0.2"),
    ("seam_cm", "station seams, cm", lambda m: m <= 1.0, "<= 1"),
    ("within_2sigma", "mapped cells within 2 sigma", lambda m: 0.90 <= m <= 0.99, "0.90-0.99"),
)


def row_of(s: dict[str, Any], spec: str, seed: int, steps: int) -> dict[str, Any]:
    """The table row of one mission summary."""
    reach = [int(v) for v in s.get("reachable_stations", [])]
    moved = float(s.get("odometer_m", 0.0)) > MOVED_M
    detilted = s.get("map_rmse_detilted_m")
    q = s.get("map_quality") or {}
    seam = q.get("seam_m")
    return {
        "scenario": spec, "seed": seed, "method": s["method"],
        "slope_deg": _r(s.get("drawn", {}).get("slope_deg")),
        "edge_gap_m": _r(s.get("drawn", {}).get("edge_distance_m")),
        "moved": moved, "odometer_m": s.get("odometer_m", 0.0),
        "reachable_max": max(reach, default=0),
        "stuck": (not moved) and max(reach, default=0) > 0,
        "steps_used": len(s["steps"]) - 1, "steps_asked": steps,
        "unused_reason": s.get("steps_unused_reason") or "",
        "stays": len(s.get("stays", [])), "looks": s.get("looks", 0),
        "edge_violations": s["edge_violations"], "geofence_refusals": s["geofence_refusals"],
        "wheels_off_terrain": s.get("wheels_off_terrain", 0),
        "wheels_on_unknown_ground": s.get("wheels_on_unknown_ground", 0),
        "mapped_cells": s["mapped_cells"],
        "map_rmse_cm": None if s["map_rmse_m"] is None else round(100 * s["map_rmse_m"], 2),
        "error_tilt_deg": s.get("map_error_tilt_deg"),
        "rmse_detilted_cm": None if detilted is None else round(100 * detilted, 2),
        "seam_cm": None if seam is None else round(100 * seam, 2),
        "within_2sigma": None if q.get("within_2sigma") is None else round(float(q["within_2sigma"]), 3),
        "final_state": s["final_state"], "stay_reasons": s.get("stays", []),
        **_registration_counts(s.get("registration") or []),
        **_prediction(s.get("steps", [])),
        **_mount_bias(s),
    }


def _mount_bias(s: dict[str, Any]) -> dict[str, Any]:
    """The flight's estimate of the mast tilt offset and attitude roll bias (``mount_bias``) and
    the bench's true values."""
    est = (s.get("mount_bias") or {}).get("estimate_deg") or {}
    true = s.get("mount_bias_truth_deg") or {}
    return {"tilt_offset_deg": _r(est.get("mast_tilt"), 3), "tilt_offset_true_deg": _r(true.get("mast_tilt"), 3),
            "imu_roll_deg": _r(est.get("imu_roll"), 3), "imu_roll_true_deg": _r(true.get("imu_roll"), 3)}


def _prediction(steps: list[dict[str, Any]]) -> dict[str, Any]:
    """The rated views' obtained / expected new cells (issue 30 item 3,
    ``mission_report.prediction_ratios``): their count, the mission's median, and every view's
    ratio (``view_ratios``, pooled over missions by :func:`_issue30_criteria`)."""
    from hil_sim.mission.mission_report import UNRATED_VIEWS, prediction_ratios

    pr = prediction_ratios(steps)
    ratios = [s["view_new_cells"] / s["expected_new_cells"] for s in steps
              if s.get("view", "") not in UNRATED_VIEWS and float(s.get("expected_new_cells", 0.0)) > 0.0
              and int(s.get("view_new_cells", -1)) >= 0]
    med = pr.get("median_ratio")
    return {"rated_views": pr["rated_steps"], "pred_ratio": None if med is None else round(float(med), 3),
            "view_ratios": ratios}


def _registration_counts(records: list[dict[str, Any]]) -> dict[str, int]:
    """Per-mission counts of the views' registration outcomes (``fsw.core.registration.registration``):
    registered in all six directions, in height and tilt only (the halves disagreed in six),
    not registered (merged with an inflated covariance), and of those or the partial ones how
    many because the overlap's halves disagreed (a false or ambiguous minimum)."""
    reg = [r for r in records if r.get("status") == "registered"]
    partial = [r for r in reg if str(r.get("reason", "")).startswith("height and tilt only")]
    unreg = [r for r in records if r.get("status") == "unregistered"]
    return {"views_registered": len(reg) - len(partial), "views_height_tilt_only": len(partial),
            "views_unregistered": len(unreg),
            "views_halves_disagree": sum("halves disagree" in str(r.get("reason", "")) for r in records)}


def _r(v: float | None, digits: int = 2) -> float | None:
    return None if v is None else round(float(v), digits)


def _median_worst(values: pd.Series, worst_high: bool = True) -> str:
    v = pd.to_numeric(values, errors="coerce").dropna()
    if v.empty:
        return "-"
    worst = v.max() if worst_high else v.min()
    return f"{v.median():.2f} / {worst:.2f}"


def per_method(rows: list[dict[str, Any]]) -> pd.DataFrame:
    """The summary per method: missions, moved, stuck, all steps used, unused steps explained, the
    counts summed, and median / worst of the map figures (text)."""
    df = pd.DataFrame(rows)
    df["full"] = df["steps_used"] >= df["steps_asked"]
    df["explained"] = df["full"] | df["unused_reason"].astype(bool)
    g = df.groupby("method")
    out = g[["moved", "stuck", "full", "explained", "edge_violations", "wheels_off_terrain",
             "wheels_on_unknown_ground"]].sum().astype(int)
    out.insert(0, "missions", g.size())
    for col, worst_high in (("mapped_cells", False), ("map_rmse_cm", True), ("error_tilt_deg", True),
                            ("rmse_detilted_cm", True), ("seam_cm", True), ("within_2sigma", False)):
        out[col] = g[col].apply(lambda v, hi=worst_high: _median_worst(v, hi))
    return out.sort_index()


def report_markdown(rows: list[dict[str, Any]], failed: list[str], args: dict[str, Any]) -> str:
    cmd = (f"safer-hil experiment ground --family '{args['family']}' --terrains {args['terrains']} "
           f"--first-seed {args['first_seed']} --methods {args['methods']} --steps {args['steps']} "
           + "".join(f"--extra '{e}' " for e in args["extra"])
           + (f"--camera {args['camera']} " if args.get("camera", "config") != "config" else "")
           + f"--jobs {args['jobs']}")
    out = [f"# Missions on unfamiliar ground\n\n```\n{cmd}\n```\n",
           "| " + " | ".join(c for c in COLUMNS) + " |", "|" + "---|" * len(COLUMNS)]
    for r in rows:
        out.append("| " + " | ".join("-" if r[c] is None else str(r[c]) for c in COLUMNS) + " |")
    out.append("\n## Summary per method (median / worst)\n")
    out.append("| method | missions | moved | stuck | steps used (all?) | edge violations | wheels off "
               "terrain | wheels on unknown ground | mapped cells (median / min) | map RMSE cm | "
               "error tilt deg | RMSE detilted cm | seams cm | within 2 sigma |")
    out.append("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for m, st in (per_method(rows).iterrows() if rows else ()):
        out.append(
            f"| {m} | {st['missions']} | {st['moved']} | {st['stuck']} | "
            f"{st['full']} all, {st['explained'] - st['full']} with a reason | {st['edge_violations']} | "
            f"{st['wheels_off_terrain']} | {st['wheels_on_unknown_ground']} | {st['mapped_cells']} | "
            f"{st['map_rmse_cm']} | {st['error_tilt_deg']} | {st['rmse_detilted_cm']} | {st['seam_cm']} | "
            f"{st['within_2sigma']} |")
    out.append("\n## Criteria (issue 13 item 3)\n")
    crit = [
        ("missions where the rover never moved while a reachable station existed",
         sum(r["stuck"] for r in rows)),
        ("edge violations (frames with a wheel over the drop)", sum(r["edge_violations"] for r in rows)),
        ("frames with a wheel off the world's terrain", sum(r["wheels_off_terrain"] for r in rows)),
        ("frames moving with a wheel on ground the flight software did not know",
         sum(r["wheels_on_unknown_ground"] for r in rows)),
        ("missions with unused steps and no reason",
         sum(r["steps_used"] < r["steps_asked"] and not r["unused_reason"] for r in rows)),
    ]
    for text, n in crit:
        out.append(f"- {text}: **{n}** (target 0) {'met' if n == 0 else 'NOT MET'}")
    out.extend(_map_criteria(rows))
    out.extend(_issue30_criteria(rows))
    never = [r for r in rows if not r["moved"]]
    if never:
        out.append(f"\nMissions where the rover did not move ({len(never)}): reachable stations 0 at every "
                   "step boundary unless marked stuck. Their first reasons:")
        for r in never[:20]:
            why = r["stay_reasons"][0] if r["stay_reasons"] else "planner chose to stay (no reachable station)"
            out.append(f"- {r['scenario']} seed {r['seed']} method {r['method']}: {why}")
    if failed:
        out.append("\n## Failed missions\n" + "\n".join(f"- {f}" for f in failed))
    return "\n".join(out) + "\n"


def _map_criteria(rows: list[dict[str, Any]]) -> list[str]:
    """The map figures of issue 13's "Done when" per method: median (target checked) and
    worst over the generated terrains with slope <= ``MAP_SLOPE_MAX_DEG``; rows without a
    drawn slope (``file:`` DEMs) are listed apart, as they were measured."""
    gen = [r for r in rows if r["slope_deg"] is not None and r["slope_deg"] <= MAP_SLOPE_MAX_DEG]
    other = [r for r in rows if r["slope_deg"] is None]
    out = [f"\n## Map criteria (issue 13; generated terrains with slope <= {MAP_SLOPE_MAX_DEG:g} deg)\n"]
    for m in sorted({r["method"] for r in gen}):
        rs = [r for r in gen if r["method"] == m]
        out.append(f"Method {m}, {len(rs)} missions:")
        for col, what, ok, target in MAP_CRITERIA:
            v = pd.Series([r[col] for r in rs], dtype=float).dropna()
            if v.empty:
                out.append(f"- {what}: no value")
                continue
            med = float(v.median())
            worst = float(v.min() if col == "within_2sigma" else v.max())
            out.append(f"- {what}: median **{med:.3g}** (target {target}) {'met' if ok(med) else 'NOT MET'}; "
                       f"worst {worst:.3g}")
    for r in other:
        out.append(f"- {r['scenario']} method {r['method']}: RMSE {r['map_rmse_cm']} cm, tilt "
                   f"{r['error_tilt_deg']} deg, seams {r['seam_cm']} cm, within 2 sigma {r['within_2sigma']}")
    return out


def _issue30_criteria(rows: list[dict[str, Any]]) -> list[str]:
    """Issue 30 items 2 and 3 over every mission run: Method 5's map RMSE median against Method
    1's (within 10 %), its within-2-sigma median (0.90-0.99) and worst (>= 0.85), and the
    obtained / expected new cells of its rated views pooled over the missions (median 0.8-1.25,
    10th-90th percentile reported)."""
    import numpy as np

    out = ["\n## Criteria (issue 30 items 2 and 3; every mission)\n"]
    by = {m: [r for r in rows if r["method"] == m] for m in ("1", "5")}
    rmse = {m: pd.Series([r["map_rmse_cm"] for r in rs], dtype=float).dropna() for m, rs in by.items()}
    if not rmse["5"].empty and not rmse["1"].empty:
        m5, m1 = float(rmse["5"].median()), float(rmse["1"].median())
        out.append(f"- Method 5 map RMSE median {m5:.2f} cm against Method 1's {m1:.2f} cm: ratio **{m5 / m1:.2f}** "
                   f"(target <= 1.10) {'met' if m5 <= 1.1 * m1 else 'NOT MET'}")
    w2 = pd.Series([r["within_2sigma"] for r in by["5"]], dtype=float).dropna()
    if not w2.empty:
        med, worst = float(w2.median()), float(w2.min())
        ok = 0.90 <= med <= 0.99 and worst >= 0.85
        out.append(f"- Method 5 within 2 sigma: median **{med:.3f}** (target 0.90-0.99), worst **{worst:.3f}** "
                   f"(target >= 0.85) {'met' if ok else 'NOT MET'}")
    ratios = np.array([x for r in by["5"] for x in r.get("view_ratios", [])], dtype=float)
    if ratios.size:
        p10, med, p90 = np.percentile(ratios, [10, 50, 90])
        out.append(f"- Method 5 obtained / expected new cells over {ratios.size} rated views: median **{med:.2f}** "
                   f"(target 0.8-1.25) {'met' if 0.8 <= med <= 1.25 else 'NOT MET'}; "
                   f"10th-90th percentile {p10:.2f}-{p90:.2f}")
    return out
