"""``report.md`` of a campaign and its plots, from the results rows (:mod:`hil_sim.lab.campaign.table`).

Headline figures: missions run and lost (a lost mission is one without a row: always 0 here,
since a crash is a recorded ``error``/``killed`` row), outcome classes, edge violations,
off-map events, median and worst map RMS error, variance calibration, Method 5 against the
oracle (mapped cells, docs/algorithm.md §7: paired on family, parameters, seed and fault set; median
and 10th percentile of the ratio), and SAFE recoveries that resumed the mission. Plots:
``coverage_by_method.png`` (mapped cells per method), ``m5_vs_oracle.png``,
``failures.png`` (outcome classes per family and fault set), ``failure_params.png`` (failure
classes against every numeric scenario parameter) and ``fault_recovery.png``. Failure classes
(:func:`classes`: the outcome, a final SAFE, off-map frames, a rover that never moved, a map
not delivered) are listed with the parameters of the missions that produced them.
"""

from __future__ import annotations

import json
from collections import Counter, defaultdict
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from hil_sim.lab.campaign.table import OUTCOMES

FAILED = ("error", "killed")


def table(rows: list[dict[str, Any]]) -> pd.DataFrame:
    """The rows as a DataFrame, with every column the report reads (absent: null)."""
    df = pd.DataFrame(rows)
    for col in _OPTIONAL:
        if col not in df:
            df[col] = None
    return df


_OPTIONAL = ("safe_recoveries_resumed", "safe_final", "map_transfer", "odometer_m", "fault_in_mission",
             "tasks_hung", "watchdog_expired_frames")


def _ran(df: pd.DataFrame) -> pd.DataFrame:
    return df[~df["outcome"].isin(FAILED)]


def _total(col: pd.Series) -> int:
    return int(pd.to_numeric(col, errors="coerce").fillna(0).sum())


def _count(mask: pd.Series) -> int:
    return int(mask.fillna(False).astype(bool).sum())


def _undelivered(df: pd.DataFrame) -> pd.Series:
    """A map transfer that ended otherwise than delivered (none tried: not counted)."""
    t = df["map_transfer"]
    return t.notna() & ~t.isin(["", "none", "delivered"])


def headline(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """The campaign's figures (also written as ``report.json``)."""
    df = table(rows)
    ran = _ran(df)
    rmse = ran["map_rmse_m"].dropna().astype(float)
    calib = ran["calib_2sigma"].dropna().astype(float)
    ratios = m5_oracle_ratios(rows)
    return {
        "missions": len(df),
        "outcomes": {k: int((df["outcome"] == k).sum()) for k in OUTCOMES},
        "crashed_lost": 0,
        "edge_violations": _total(ran["edge_violations"]),
        "off_map_events": _total(ran["off_map"]),
        "geofence_refusals": _total(ran["geofence_refusals"]),
        "map_rmse_median_m": _q(rmse, 50),
        "map_rmse_worst_m": float(rmse.max()) if len(rmse) else None,
        "calib_2sigma_median": _q(calib, 50),
        "m5_oracle_pairs": len(ratios),
        "m5_oracle_median": _q(ratios, 50),
        "m5_oracle_p10": _q(ratios, 10),
        "faulted_missions": int((ran["fault_set"] != "none").sum()),
        "safe_entries": _total(ran["safe_entries"]),
        "safe_recoveries": _total(ran["safe_recoveries"]),
        "safe_recoveries_resumed": _total(ran["safe_recoveries_resumed"]),
        "missions_with_safe": _count(ran["safe_entries"] > 0),
        "missions_safe_final": _count(ran["safe_final"]),
        "missions_never_moved": _count(_never_moved(ran)),
        "maps_not_delivered": _count(_undelivered(ran)),
    }


NEVER_MOVED_M = 0.05  # odometer below this: the rover never left its start


def _never_moved(df: pd.DataFrame) -> pd.Series:
    return pd.to_numeric(df["odometer_m"], errors="coerce") < NEVER_MOVED_M


def classes(r: dict[str, Any]) -> list[str]:
    """Failure classes of one row (several may apply; none for a clean mission): its outcome if
    not done, and the troubles a done mission can still have."""
    out = [] if r["outcome"] == "done" else [r["outcome"]]
    if r["outcome"] in FAILED:
        return out
    if r.get("safe_final"):
        out.append("safe_final")
    if r["off_map"]:
        out.append("off_map")
    odo = r.get("odometer_m")
    if odo is not None and odo < NEVER_MOVED_M:
        out.append("never_moved")
    if r.get("map_transfer") not in (None, "", "none", "delivered"):
        out.append(f"map_{r['map_transfer']}")
    return out


def _q(a: pd.Series, pct: float) -> float | None:
    """The ``pct``-th percentile (linear between order statistics, as ``numpy.percentile``)."""
    return float(a.quantile(pct / 100.0)) if len(a) else None


def _pairs(rows: list[dict[str, Any]]) -> pd.DataFrame:
    """Method 5's and the oracle's mapped cells side by side, a row per paired
    (family, params, seed, fault set); the last row wins where a pair repeats."""
    df = _ran(table(rows))
    df = df[df["method"].isin(["5", "oracle"])].assign(seed=lambda d: d["seed"].astype(str))
    if df.empty:
        return pd.DataFrame(columns=["5", "oracle"], dtype=float)
    wide = df.pivot_table(index=["family", "params", "seed", "fault_set"], columns="method",
                          values="mapped_cells", aggfunc="last", sort=False)
    return wide.reindex(columns=["5", "oracle"]).dropna().astype(float)


def m5_oracle_ratios(rows: list[dict[str, Any]]) -> pd.Series:
    """Method 5 mapped cells / oracle mapped cells, per paired (family, params, seed, faults)."""
    p = _pairs(rows)
    p = p[p["oracle"] > 0]
    return (p["5"] / p["oracle"]).reset_index(drop=True)


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
        f"| missions with faults / with SAFE entries / ended in a final SAFE | {h['faulted_missions']} / "
        f"{h['missions_with_safe']} / {h['missions_safe_final']} |",
        f"| SAFE entries / recoveries (left SAFE) / recoveries that resumed the mission | {h['safe_entries']} / "
        f"{h['safe_recoveries']} / {h['safe_recoveries_resumed']} |",
        f"| missions where the rover never moved (odometer < {NEVER_MOVED_M} m) | {h['missions_never_moved']} |",
        f"| maps not delivered to the Cliff-bot (failed, rejected, timeout) | {h['maps_not_delivered']} |",
        "",
        "## Coverage per method",
        "",
        "![coverage](coverage_by_method.png) ![m5 vs oracle](m5_vs_oracle.png)",
        "",
        "| method | missions | mapped cells median | min | max | map RMSE median (cm) |",
        "|---|---|---|---|---|---|",
    ]
    for m, st in per_method(rows).iterrows():
        lines.append(f"| {m} | {st['missions']} | {f(st['cells_median'], 1, '', 0)} | {f(st['cells_min'], 1, '', 0)} | "
                     f"{f(st['cells_max'], 1, '', 0)} | {f(st['rmse_median'], 100)} |")
    lines += ["", "## Failure classes and the parameters that produce them", "",
              "![failures](failures.png) ![failure parameters](failure_params.png)", "",
              "| class | missions | methods | fault sets |", "|---|---|---|---|"]
    by_class: dict[str, list[dict[str, Any]]] = defaultdict(list)
    for r in rows:
        for c in classes(r):
            by_class[c].append(r)
    for c, rs in sorted(by_class.items()):
        lines.append(f"| {c} | {len(rs)} | {_counts(rs, 'method')} | {_counts(rs, 'fault_set')} |")
    lines += ["", "| classes | mission | scenario | method | seed | faults | detail |", "|---|---|---|---|---|---|---|"]
    bad = [r for r in rows if classes(r)]
    for r in sorted(bad, key=lambda r: (classes(r), r["id"])):
        detail = r["error"] or r["safe_reason"] or r["end_reason"] or ""
        lines.append(f"| {', '.join(classes(r))} | {r['id']} | `{r['scenario']}` | {r['method']} | {r['seed']} | "
                     f"{r['fault_set']} | {detail.replace('|', '/')} |")
    if not bad:
        lines.append("| (none) | | | | | | |")
    lines += ["", "## Fault recovery", "", "![fault recovery](fault_recovery.png)", "",
              "| fault set | missions | fault began before the end | with SAFE | SAFE entries | recoveries (left SAFE) "
              "| recoveries that resumed the mission | final SAFE | DONE | map delivered | hung-task reports "
              "| watchdog-expired frames |",
              "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for fs, st in recovery(rows).iterrows():
        hit = "" if fs == "none" else st["hit"]
        lines.append(f"| {fs} | {st['n']} | {hit} | {st['safe']} | {st['entries']} | {st['recovered']} | "
                     f"{st['resumed']} | {st['final']} | {st['done']} | {st['delivered']} | {st['hung']} | "
                     f"{st['watchdog']} |")
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


def _counts(rs: list[dict[str, Any]], key: str) -> str:
    counts = pd.Series([str(r[key]) for r in rs]).value_counts().sort_index()
    return ", ".join(f"{k} {n}" for k, n in counts.items())


def per_method(rows: list[dict[str, Any]]) -> pd.DataFrame:
    """Per method (by name): missions, mapped cells of those that ran (median, min, max) and the
    median map RMS error (m); None where there is no value."""
    df = table(rows).assign(method=lambda d: d["method"].astype(str),
                            mapped_cells=lambda d: pd.to_numeric(d["mapped_cells"], errors="coerce"),
                            map_rmse_m=lambda d: pd.to_numeric(d["map_rmse_m"], errors="coerce"))
    cells = _ran(df).groupby("method")["mapped_cells"]
    out = pd.DataFrame({"missions": df.groupby("method").size(), "cells_median": cells.quantile(0.5),
                        "cells_min": cells.min(), "cells_max": cells.max(),
                        "rmse_median": df.groupby("method")["map_rmse_m"].median()})
    return out.astype(object).where(out.notna(), None).sort_index()


def recovery(rows: list[dict[str, Any]]) -> pd.DataFrame:
    """Per fault set (by name): missions, faults that began before the end, missions with SAFE,
    SAFE entries, recoveries (left SAFE), recoveries that resumed the mission, final SAFEs, DONE,
    maps delivered, hung-task reports, watchdog-expired frames (sums over the missions that ran)."""
    df = table(rows).assign(fault_set=lambda d: d["fault_set"].astype(str))
    ran = _ran(df)

    def num(col: str) -> pd.Series:
        return pd.to_numeric(ran[col], errors="coerce").fillna(0)

    per_mission = pd.DataFrame({
        "fault_set": ran["fault_set"], "hit": ran["fault_in_mission"].eq(True), "safe": num("safe_entries") > 0,
        "entries": num("safe_entries"), "recovered": num("safe_recoveries"), "resumed": num("safe_recoveries_resumed"),
        "final": ran["safe_final"].fillna(False).astype(bool), "done": ran["outcome"] == "done",
        "delivered": ran["map_transfer"] == "delivered", "hung": num("tasks_hung"),
        "watchdog": num("watchdog_expired_frames")})
    out = pd.DataFrame({"n": df.groupby("fault_set").size()}).join(per_mission.groupby("fault_set").sum())
    return out.fillna(0).astype(int).sort_index()


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
    p = _pairs(rows)
    xy = p[["oracle", "5"]].to_numpy(float).reshape(-1, 2)
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

    sets = recovery(rows)
    fig, ax = plt.subplots(figsize=(7, 4), constrained_layout=True)
    k = np.arange(len(sets))
    for i, (label, key) in enumerate((("SAFE entries", "entries"), ("recoveries (left SAFE)", "recovered"),
                                      ("recoveries that resumed the mission", "resumed"), ("final SAFE", "final"))):
        ax.bar(k + (i - 1.5) * 0.2, sets[key] / sets["n"].clip(lower=1), 0.2, label=label)
    ax.set_xticks(k, list(sets.index), rotation=20)
    ax.set_ylabel("per mission of the fault set")
    ax.set_title("SAFE and its recovery per fault set")
    ax.legend()
    fig.savefig(out / "fault_recovery.png", dpi=90)
    plt.close(fig)
    _param_plot(out, rows)


def _param_plot(out: Path, rows: list[dict[str, Any]]) -> None:
    """``failure_params.png``: every numeric scenario parameter against the failure classes
    (one panel a parameter; a dot a mission, jittered within its class; clean missions too)."""
    import matplotlib.pyplot as plt

    params = [json.loads(r["params"]) for r in rows]
    keys = sorted({k for p in params for k, v in p.items() if isinstance(v, (int, float)) and not isinstance(v, bool)})
    labels = sorted({c for r in rows for c in classes(r)}) + ["clean"]
    fig, axes = plt.subplots(1, max(1, len(keys)), figsize=(3.2 * max(1, len(keys)), 0.6 + 0.4 * len(labels)),
                             constrained_layout=True, sharey=True, squeeze=False)
    rng = np.random.default_rng(0)
    for ax, key in zip(axes[0], keys, strict=False):
        for r, p in zip(rows, params, strict=True):
            if key not in p:
                continue
            for c in classes(r) or ["clean"]:
                y = labels.index(c) + rng.uniform(-0.2, 0.2)
                ax.scatter(p[key], y, s=12, color="tab:gray" if c == "clean" else "tab:red", alpha=0.7)
        ax.set_xlabel(key)
        ax.grid(alpha=0.3)
    axes[0][0].set_yticks(range(len(labels)), labels)
    fig.suptitle("failure classes against the scenario parameters")
    fig.savefig(out / "failure_params.png", dpi=90)
    plt.close(fig)
