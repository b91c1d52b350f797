"""``report.md`` of a campaign and its plots, from the results rows (:mod:`hil_sim.campaign.table`).

Headline figures: missions run and lost (a lost mission is one without a row: always 0 here,
since a crash is a recorded ``error``/``killed`` row), outcome classes, edge violations,
off-map events, median and worst map RMS error, variance calibration, Method 5 against the
oracle (mapped cells, ALGORITHM.md §7: paired on family, parameters, seed and fault set; median
and 10th percentile of the ratio), and SAFE recoveries that resumed the mission. Plots:
``coverage_by_method.png`` (mapped cells per method), ``m5_vs_oracle.png``,
``failures.png`` (outcome classes per family and fault set) and ``fault_recovery.png``.
Failure classes are listed with the parameters of the missions that produced them.
"""

from __future__ import annotations

import json
from collections import Counter, defaultdict
from pathlib import Path
from typing import Any

import numpy as np

from hil_sim.campaign.table import OUTCOMES

FAILED = ("error", "killed")


def headline(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """The campaign's figures (also written as ``report.json``)."""
    ran = [r for r in rows if r["outcome"] not in FAILED]
    rmse = np.array([r["map_rmse_m"] for r in ran if r["map_rmse_m"] is not None], float)
    calib = np.array([r["calib_2sigma"] for r in ran if r["calib_2sigma"] is not None], float)
    ratios = m5_oracle_ratios(rows)
    faulted = [r for r in ran if r["fault_set"] != "none"]
    return {
        "missions": len(rows),
        "outcomes": {k: sum(r["outcome"] == k for r in rows) for k in OUTCOMES},
        "crashed_lost": 0,
        "edge_violations": int(sum(r["edge_violations"] for r in ran)),
        "off_map_events": int(sum(r["off_map"] for r in ran)),
        "geofence_refusals": int(sum(r["geofence_refusals"] for r in ran)),
        "map_rmse_median_m": _q(rmse, 50),
        "map_rmse_worst_m": float(rmse.max()) if rmse.size else None,
        "calib_2sigma_median": _q(calib, 50),
        "m5_oracle_pairs": len(ratios),
        "m5_oracle_median": _q(ratios, 50),
        "m5_oracle_p10": _q(ratios, 10),
        "faulted_missions": len(faulted),
        "safe_entries": int(sum(r["safe_entries"] for r in ran)),
        "safe_recoveries_resumed": sum(r["safe_recoveries"] > 0 and r["outcome"] == "done" for r in ran),
        "missions_with_safe": sum(r["safe_entries"] > 0 for r in ran),
    }


def _q(a: Any, pct: float) -> float | None:
    a = np.asarray(a, float)
    return float(np.percentile(a, pct)) if a.size else None


def m5_oracle_ratios(rows: list[dict[str, Any]]) -> Any:
    """Method 5 mapped cells / oracle mapped cells, per paired (family, params, seed, faults)."""
    pairs: dict[tuple[str, ...], dict[str, int]] = defaultdict(dict)
    for r in rows:
        if r["outcome"] not in FAILED and r["method"] in ("5", "oracle"):
            pairs[(r["family"], r["params"], str(r["seed"]), r["fault_set"])][r["method"]] = r["mapped_cells"]
    return np.array([p["5"] / p["oracle"] for p in pairs.values() if len(p) == 2 and p["oracle"] > 0], float)


def write_report(out: Path, rows: list[dict[str, Any]], name: str, extra: str = "") -> dict[str, Any]:
    """``report.md``, ``report.json`` and the PNGs in ``out``; returns the headline figures."""
    import matplotlib

    matplotlib.use("Agg")
    h = headline(rows)
    (out / "report.json").write_text(json.dumps(h, indent=2) + "\n")
    _plots(out, rows)
    f = _fmt
    lines = [
        f"# Campaign {name}: {h['missions']} missions",
        "",
        extra,
        "| figure | value |",
        "|---|---|",
        f"| missions (rows) / lost | {h['missions']} / {h['crashed_lost']} |",
        "| outcomes | " + ", ".join(f"{k} {v}" for k, v in h["outcomes"].items()) + " |",
        f"| edge violations (frames with a wheel over the drop) | {h['edge_violations']} |",
        f"| off-map events (frames with a wheel off the truth grid) | {h['off_map_events']} |",
        f"| geofence refusals | {h['geofence_refusals']} |",
        f"| map RMS error: median / worst | {f(h['map_rmse_median_m'], 100, 'cm')} / "
        f"{f(h['map_rmse_worst_m'], 100, 'cm')} |",
        f"| fraction of mapped cells within 2 sigma (median) | {f(h['calib_2sigma_median'])} |",
        f"| Method 5 / oracle mapped cells ({h['m5_oracle_pairs']} pairs): median / 10th percentile | "
        f"{f(h['m5_oracle_median'])} / {f(h['m5_oracle_p10'])} |",
        f"| missions with faults / with SAFE entries / SAFE recovered and DONE | {h['faulted_missions']} / "
        f"{h['missions_with_safe']} / {h['safe_recoveries_resumed']} |",
        "",
        "## Coverage per method",
        "",
        "![coverage](coverage_by_method.png) ![m5 vs oracle](m5_vs_oracle.png)",
        "",
        "| method | missions | mapped cells median | min | max | map RMSE median (cm) |",
        "|---|---|---|---|---|---|",
    ]
    for m, rs in sorted(_by(rows, "method").items()):
        cells = np.array([r["mapped_cells"] for r in rs if r["outcome"] not in FAILED], float)
        err = np.array([r["map_rmse_m"] for r in rs if r["map_rmse_m"] is not None], float)
        lines.append(f"| {m} | {len(rs)} | {f(_q(cells, 50), 1, '', 0)} | {f(_q(cells, 0), 1, '', 0)} | "
                     f"{f(_q(cells, 100), 1, '', 0)} | {f(_q(err, 50), 100)} |")
    lines += ["", "## Failure classes and the parameters that produce them", "", "![failures](failures.png)", "",
              "| outcome | mission | scenario | method | seed | faults | detail |", "|---|---|---|---|---|---|---|"]
    bad = [r for r in rows if r["outcome"] != "done"]
    for r in sorted(bad, key=lambda r: (r["outcome"], r["id"])):
        detail = r["error"] or r["safe_reason"] or r["end_reason"] or ""
        lines.append(f"| {r['outcome']} | {r['id']} | `{r['scenario']}` | {r['method']} | {r['seed']} | "
                     f"{r['fault_set']} | {detail.replace('|', '/')} |")
    if not bad:
        lines.append("| (none) | | | | | | |")
    lines += ["", "## Fault recovery", "", "![fault recovery](fault_recovery.png)", "",
              "| fault set | missions | SAFE entered | recovered (left SAFE) | DONE | recovery rate |",
              "|---|---|---|---|---|---|"]
    for fs, rs in sorted(_by(rows, "fault_set").items()):
        st = _recovery(rs)
        lines.append(f"| {fs} | {st['n']} | {st['safe']} | {st['recovered']} | {st['done']} | "
                     f"{f(st['rate'])} |")
    lines += ["", "Table: `results.parquet` / `results.csv` (a row a mission); per-mission rows in `missions/`.", ""]
    (out / "report.md").write_text("\n".join(lines))
    return h


def _fmt(v: float | None, scale: float = 1.0, unit: str = "", nd: int = 2) -> str:
    return "n/a" if v is None else f"{v * scale:.{nd}f}{(' ' + unit) if unit else ''}"


def _by(rows: list[dict[str, Any]], key: str) -> dict[str, list[dict[str, Any]]]:
    out: dict[str, list[dict[str, Any]]] = defaultdict(list)
    for r in rows:
        out[str(r[key])].append(r)
    return out


def _recovery(rs: list[dict[str, Any]]) -> dict[str, Any]:
    ran = [r for r in rs if r["outcome"] not in FAILED]
    safe = [r for r in ran if r["safe_entries"] > 0]
    rec = [r for r in safe if r["safe_recoveries"] > 0]
    return {"n": len(rs), "safe": len(safe), "recovered": len(rec),
            "done": sum(r["outcome"] == "done" for r in ran),
            "rate": len([r for r in rec if r["outcome"] == "done"]) / len(safe) if safe else None}


def _plots(out: Path, rows: list[dict[str, Any]]) -> None:
    import matplotlib.pyplot as plt

    by_m = sorted(_by([r for r in rows if r["outcome"] not in FAILED], "method").items())
    fig, ax = plt.subplots(figsize=(7, 4.2), constrained_layout=True)
    if by_m:
        ax.boxplot([[r["mapped_cells"] for r in rs] for _, rs in by_m], showmeans=True)
        ax.set_xticks(range(1, len(by_m) + 1), [m for m, _ in by_m])
    ax.set_xlabel("method")
    ax.set_ylabel("mapped cells at the end")
    ax.set_title("coverage distribution per method")
    ax.grid(alpha=0.3)
    fig.savefig(out / "coverage_by_method.png", dpi=90)
    plt.close(fig)

    fig, axes = plt.subplots(1, 2, figsize=(10, 4.2), constrained_layout=True)
    pairs: dict[tuple[str, ...], dict[str, int]] = defaultdict(dict)
    for r in rows:
        if r["outcome"] not in FAILED and r["method"] in ("5", "oracle"):
            pairs[(r["family"], r["params"], str(r["seed"]), r["fault_set"])][r["method"]] = r["mapped_cells"]
    xy = np.array([(p["oracle"], p["5"]) for p in pairs.values() if len(p) == 2], float).reshape(-1, 2)
    axes[0].scatter(xy[:, 0], xy[:, 1], s=14)
    if xy.size:
        lim = float(xy.max()) * 1.05
        axes[0].plot([0, lim], [0, lim], "k--", lw=1, label="Method 5 = oracle")
        axes[0].legend()
    axes[0].set_xlabel("oracle mapped cells")
    axes[0].set_ylabel("Method 5 mapped cells")
    ratios = m5_oracle_ratios(rows)
    axes[1].hist(ratios, bins=max(5, min(30, ratios.size)))
    axes[1].set_xlabel("Method 5 / oracle")
    axes[1].set_ylabel("missions")
    fig.suptitle("Method 5 against the oracle (paired missions)")
    fig.savefig(out / "m5_vs_oracle.png", dpi=90)
    plt.close(fig)

    groups = sorted(_by(rows, "family").items())
    groups += sorted((f"faults: {k}", v) for k, v in _by(rows, "fault_set").items())
    fig, ax = plt.subplots(figsize=(8, 0.5 + 0.45 * max(2, len(groups))), constrained_layout=True)
    left = np.zeros(len(groups))
    for oc in OUTCOMES:
        n = np.array([Counter(r["outcome"] for r in rs)[oc] for _, rs in groups], float)
        if n.any():
            ax.barh([g for g, _ in groups], n, left=left, label=oc)
            left += n
    ax.set_xlabel("missions")
    ax.set_title("outcome classes per family and fault set")
    ax.legend(fontsize=8)
    fig.savefig(out / "failures.png", dpi=90)
    plt.close(fig)

    sets = sorted(_by(rows, "fault_set").items())
    fig, ax = plt.subplots(figsize=(7, 4), constrained_layout=True)
    k = np.arange(len(sets))
    for i, (label, key) in enumerate((("SAFE entered", "safe"), ("recovered", "recovered"), ("DONE", "done"))):
        ax.bar(k + (i - 1) * 0.27, [_recovery(rs)[key] / max(1, len(rs)) for _, rs in sets], 0.27, label=label)
    ax.set_xticks(k, [s for s, _ in sets], rotation=20)
    ax.set_ylabel("fraction of missions")
    ax.set_ylim(0, 1.05)
    ax.set_title("fault recovery per fault set")
    ax.legend()
    fig.savefig(out / "fault_recovery.png", dpi=90)
    plt.close(fig)
