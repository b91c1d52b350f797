"""``safer-hil experiment team-sensing``: views chosen for the team against the RECON-bot alone.

For each seeded ``cliff-team`` scene (``--scenes`` from ``--seed``, in ``--jobs`` processes) two
runs of ``--cycles`` imaging cycles on the same scene: the team (both agents' views chosen by
``fsw.core.planning.team_views``, sequential greedy) and the RECON-bot alone (the same planner with
one agent: the same interest, the same corridor weighting). Both run in the team-views harness
(``hil_sim.team.team_views_run``: views sensed on the truth with a stereo error model and fused
with the flight's fusion), not in lockstep missions: a lockstep mission renders and matches
every view and takes minutes of CPU per imaging step.

Figures per scene: new cells per imaging cycle (team / RECON-bot alone; over every cycle, and over
the first quarter and half of them: on a scene the team uses up, the cells left in the RECON-bot's
reach, ``TeamViewsRun.recon_reach_left``, team and alone, the later cycles map little for want of
ground, not of views), the overlap of the two
views of a cycle (cells both measured / cells either measured; and / cells the smaller measured; summarised
over every cycle of every scene, each scene's worst cycle and each scene's mean; and on the cells with
information left, measured fewer than ``info_n_max`` times before the cycle), the cycles until the
Cliff-bot's corridor (its plan on the true ground, path +- 1 m) is mapped to 95 % (team, alone,
their ratio), the face (true slope > 45 deg) and corridor mapped after ``--cycles``, and the
RMS error on cells both agents mapped: each agent's own map and the fused one, with the share of
cells within 2 sigma of the truth (each map's own variance) on those cells and on all of each
map's cells; and why the
Cliff-bot's views add what they add: whether its corridor leads to a target (else toward the
nearest, as far as the tethers hold it), its candidate views per cycle, its expected and obtained
new cells, its share of the team's new cells and its farthest place from its start; where the
cycles go (the team's RECON-bot's new cells per cycle against the RECON-bot's alone, and each
agent's views that mapped fewer than ``EMPTY_VIEW_CELLS`` new cells); and what bounds the
corridor (its cells still unmapped, and how many of them some candidate camera centre has in
range and line of sight on the truth, ``TeamViewsRun.corridor_left``). Every figure but the
cycles to 95 % of the corridor is taken after ``--cycles`` cycles; for that one each run goes on
past ``--cycles`` until the corridor is mapped to 95 % or ``--corridor-cap`` cycles have run
(``TeamViewsRun.cycles_to_corridor``), so the ratio team / alone has a measured denominator;
a run that does not get there within the cap is reported as not within it (and where only the
RECON-bot alone does not, the ratio is bounded from above by counting its cycles as the cap + 1).
Writes OUT/team_sensing.csv, OUT/coverage.png (face and corridor coverage per cycle over the
first ``--cycles``: team, each of its agents, the RECON-bot alone; medians over the scenes) and
``docs/results/team-sensing.md`` (``--results-name`` names another, e.g. a held-out run on other
seeds).
"""

from __future__ import annotations

import argparse
import csv
import sys
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path
from typing import Any

HELP = "team views (both agents) against the RECON-bot alone: cells per cycle, overlap, corridor, fusion"
COLUMNS = ("seed", "cycles", "team_cells_per_cycle", "recon_cells_per_cycle", "cells_ratio", "cells_ratio_quarter",
           "cells_ratio_half", "reach_left_team", "reach_left_alone", "overlap_mean",
           "overlap_median", "overlap_max", "overlap_open_max", "overlap_of_smaller_max", "corridor_cycles_team",
           "corridor_cycles_recon", "corridor_ratio", "corridor_recon_at_stop", "corridor_team", "corridor_recon",
           "face_team", "face_recon", "both_cells",
           "rmse_recon_m", "rmse_cliffbot_m", "rmse_fused_m", "in2sig_recon", "in2sig_cliffbot", "in2sig_fused",
           "in2sig_recon_own", "in2sig_cliffbot_own", "in2sig_fused_own", "blind_views", "reachable",
           "cliffbot_candidates", "cliffbot_views_per_cycle",
           "cliffbot_expected_new", "cliffbot_obtained_new", "cliffbot_new_share", "cliffbot_travel_m",
           "recon_team_new_per_cycle", "empty_views_recon_team", "empty_views_cliffbot", "empty_views_recon_alone",
           "corridor_left_cells", "corridor_left_seeable")
EMPTY_VIEW_CELLS = 10  # a view that maps fewer new cells than this is counted as empty
GOAL = 0.95


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--scenario", default="cliff-team", help="scenario spec (seeded per scene)")
    p.add_argument("--scenes", type=int, default=30, help="number of seeded scenes")
    p.add_argument("--seed", type=int, default=0, help="first seed")
    p.add_argument("--jobs", type=int, default=1, help="scenes run in parallel (processes)")
    p.add_argument("--cycles", type=int, default=12, help="imaging cycles per run")
    p.add_argument("--corridor-cap", type=int, default=40,
                   help="each run goes on past --cycles until the corridor is mapped to 95 %% or this many cycles")
    p.add_argument("--cell", type=float, default=0.08, help="map cell of the harness (m)")
    p.add_argument("--corridor-weight", type=float, default=None,
                   help="both agents' weight of the bits on the Cliff-bot's corridor, 1-100 "
                        "(default: TeamViewConfig's, docs/team.md \"Team views\")")
    p.add_argument("--out", type=Path, default=Path("out/team-sensing"), help="output directory")
    p.add_argument("--results-name", default="team-sensing",
                   help="results file docs/results/NAME.md (e.g. a held-out run on other seeds)")


def run(args: argparse.Namespace) -> int:
    from hil_sim.lab.results import bad_results_name, command_line, markdown_table, write_results
    from hil_sim.world import ScenarioError, load_scenario

    me = "safer-hil experiment team-sensing"
    if args.scenes < 1 or args.jobs < 1 or args.cycles < 1 or not 0.01 <= args.cell <= 0.5:
        print(f"{me}: --scenes, --jobs and --cycles must be >= 1, --cell within 0.01-0.5 m", file=sys.stderr)
        return 2
    if args.corridor_cap < args.cycles:
        print(f"{me}: --corridor-cap must be >= --cycles, got {args.corridor_cap} < {args.cycles}", file=sys.stderr)
        return 2
    if args.corridor_weight is not None and not 1.0 <= args.corridor_weight <= 100.0:
        print(f"{me}: --corridor-weight must be within 1-100, got {args.corridor_weight:g}", file=sys.stderr)
        return 2
    if (bad := bad_results_name(args.results_name)) is not None:
        print(f"{me}: {bad}", file=sys.stderr)
        return 2
    try:
        if load_scenario(args.scenario, args.seed).team is None:
            raise ScenarioError(f"{args.scenario} has no team (use a cliff-team scenario)")
    except (ScenarioError, ValueError, OSError) as exc:
        print(f"{me}: {exc}", file=sys.stderr)
        return 2
    seeds = list(range(args.seed, args.seed + args.scenes))
    rows: list[dict[str, Any]] = []
    curves: dict[int, dict[str, list[float]]] = {}
    with ProcessPoolExecutor(max_workers=args.jobs) as pool:
        futs = {pool.submit(scene, args.scenario, s, args.cycles, args.cell, args.corridor_cap,
                            args.corridor_weight): s for s in seeds}
        for fut in as_completed(futs):
            try:
                row, curve = fut.result()
            except Exception as exc:  # noqa: BLE001 - one failed scene is reported, the rest go on
                print(f"seed {futs[fut]}: FAILED {type(exc).__name__}: {exc}", file=sys.stderr)
                continue
            rows.append(row)
            curves[row["seed"]] = curve
            print(f"[{len(rows)}/{len(seeds)}] seed {row['seed']}: cells/cycle x{_f(row['cells_ratio'])}, overlap "
                  f"{_f(row['overlap_max'])}, corridor {row['corridor_cycles_team']} vs "
                  f"{row['corridor_cycles_recon']} cycles", flush=True)
    rows.sort(key=lambda r: r["seed"])
    if not rows:
        return 1
    args.out.mkdir(parents=True, exist_ok=True)
    with (args.out / "team_sensing.csv").open("w", newline="") as f:
        wr = csv.DictWriter(f, fieldnames=list(COLUMNS), extrasaction="ignore")
        wr.writeheader()
        wr.writerows(rows)
    png = plot(curves, args.out / "coverage.png")
    md = report(rows, markdown_table, args.cycles, args.corridor_cap)
    print(md)
    write_results(args.results_name, command_line("team-sensing"), md, [png])
    return 0 if len(rows) == len(seeds) else 1


def _f(v: Any) -> str:
    return "-" if v is None else f"{v:.2f}"


def scene(spec: str, seed: int, cycles: int, cell_m: float, cap: int, corridor_weight: float | None = None,
          ) -> tuple[dict[str, Any], dict[str, list[float]]]:
    """One scene's row and coverage curves (module docstring): every figure after ``cycles``
    cycles, then both runs go on for the cycles to 95 % of the corridor (up to ``cap``);
    deterministic per seed. ``corridor_weight``: the team views' (None: ``TeamViewConfig``'s)."""
    import numpy as np

    from fsw.core.planning.team_views import TeamViewConfig
    from hil_sim.team.team_views_run import run_scene

    tv = TeamViewConfig() if corridor_weight is None else TeamViewConfig(corridor_weight=corridor_weight)
    team = run_scene(spec, seed, team=True, cycles=cycles, cell_m=cell_m, tv=tv)
    alone = run_scene(spec, seed, team=False, cycles=cycles, cell_m=cell_m, tv=tv)
    tc = [r.new_cells for r in team.records]
    rc = [r.new_cells for r in alone.records]
    overlaps = [r.overlap for r in team.records if r.overlap is not None]
    row: dict[str, Any] = {
        "seed": seed, "cycles": cycles,
        "team_cells_per_cycle": float(np.mean(tc)), "recon_cells_per_cycle": float(np.mean(rc)),
        "cells_ratio": float(np.mean(tc) / np.mean(rc)) if np.mean(rc) > 0 else None,
        "cells_ratio_quarter": _ratio_first(tc, rc, max(1, cycles // 4)),
        "cells_ratio_half": _ratio_first(tc, rc, max(1, cycles // 2)),
        "reach_left_team": team.recon_reach_left(), "reach_left_alone": alone.recon_reach_left(),
        "overlap_mean": float(np.mean(overlaps)) if overlaps else None,
        "overlap_median": float(np.median(overlaps)) if overlaps else None,
        "overlaps": overlaps,  # every cycle's, for the summary over all cycles (not a column)
        "overlap_max": float(np.max(overlaps)) if overlaps else None,
        "overlap_open_max": max((r.overlap_open for r in team.records if r.overlap_open is not None), default=None),
        "overlaps_open": [r.overlap_open for r in team.records if r.overlap_open is not None],
        "overlap_of_smaller_max": max((r.overlap_of_smaller for r in team.records
                                       if r.overlap_of_smaller is not None), default=None),
        "corridor_team": team.records[-1].corridor_frac, "corridor_recon": alone.records[-1].corridor_frac,
        "face_team": team.records[-1].face_frac, "face_recon": alone.records[-1].face_frac,
        **team.fused_vs_better(),
        "blind_views": sum(1 for r in team.records for v in r.views if "no view is expected" in v["why"]),
        **_cliffbot_figures(team),
        **_empty_views(team, alone),
        **team.corridor_left(),
    }
    curve = {
        "face_team": [r.face_frac for r in team.records], "corridor_team": [r.corridor_frac for r in team.records],
        "face_recon_alone": [r.face_frac for r in alone.records],
        "corridor_recon_alone": [r.corridor_frac for r in alone.records],
    }
    for agent in ("recon", "cliffbot"):
        curve[f"face_{agent}"] = [r.agent_face_frac[agent] for r in team.records]
        curve[f"corridor_{agent}"] = [r.agent_corridor_frac[agent] for r in team.records]
    # the figures above are the first `cycles` cycles'; now each run goes on to 95 % of the corridor
    ct, cr = team.cycles_to_corridor(GOAL, cap), alone.cycles_to_corridor(GOAL, cap)
    row.update(corridor_cycles_team=ct, corridor_cycles_recon=cr,
               corridor_ratio=ct / cr if ct is not None and cr is not None else None,
               corridor_recon_at_stop=alone.records[-1].corridor_frac)
    return row, curve


def _ratio_first(team: list[int], alone: list[int], k: int) -> float | None:
    """New cells per cycle over the first ``k`` cycles, team / RECON-bot alone: the rate before a
    scene is used up (the ratio over every cycle falls once the team has mapped what its agents
    reach and maps little more per cycle, ``TeamViewsRun.recon_reach_left``)."""
    a = sum(alone[:k])
    return sum(team[:k]) / a if a > 0 else None


def _cliffbot_figures(team: Any) -> dict[str, Any]:
    """Why the Cliff-bot's views add what they add: whether its corridor leads to a target, its
    candidate views per cycle (median), its expected and obtained new cells (sums over the
    cycles), its share of the team's new cells and its farthest place from its start."""
    import numpy as np

    views = [v for r in team.records for v in r.views if v["agent"] == "cliffbot"]
    new = sum(r.new_cells for r in team.records)
    got = sum(v["added_cells"] for v in views)  # its scan's views overlap: what each added
    return {
        "reachable": team.reachable,
        "cliffbot_candidates": float(np.median([v["candidates"] for v in views])) if views else 0.0,
        "cliffbot_views_per_cycle": len(views) / max(len(team.records), 1),
        "cliffbot_expected_new": float(sum(v["expected_new_cells"] for v in views)),
        "cliffbot_obtained_new": got,
        "cliffbot_new_share": got / new if new else None,
        "cliffbot_travel_m": max((v["travel_m"] for v in views), default=0.0),
    }


def _empty_views(team: Any, alone: Any) -> dict[str, Any]:
    """Where the cycles go: the team's RECON-bot's new cells per cycle (new to the map before the
    cycle) and the views of each agent that mapped fewer than ``EMPTY_VIEW_CELLS`` new cells."""
    import numpy as np

    def views(run: Any, agent: str) -> list[dict[str, Any]]:
        return [v for r in run.records for v in r.views if v["agent"] == agent]

    recon = views(team, "recon")
    return {
        "recon_team_new_per_cycle": float(np.mean([v["obtained_new_cells"] for v in recon])) if recon else 0.0,
        "empty_views_recon_team": sum(v["obtained_new_cells"] < EMPTY_VIEW_CELLS for v in recon),
        "empty_views_cliffbot": sum(v["added_cells"] < EMPTY_VIEW_CELLS for v in views(team, "cliffbot")),
        "empty_views_recon_alone": sum(v["obtained_new_cells"] < EMPTY_VIEW_CELLS for v in views(alone, "recon")),
    }


def plot(curves: dict[int, dict[str, list[float]]], path: Path) -> Path:
    """Face and corridor mapped per imaging cycle, medians over the scenes."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    fig, axes = plt.subplots(1, 2, figsize=(10, 4), sharey=True)
    labels = {"team": "team", "recon": "team: RECON-bot's views", "cliffbot": "team: Cliff-bot's views",
              "recon_alone": "RECON-bot alone"}
    for ax, what in zip(axes, ("face", "corridor"), strict=True):
        for key, label in labels.items():
            ys = np.array([c[f"{what}_{key}"] for c in curves.values()], float)
            x = np.arange(1, ys.shape[1] + 1)
            ax.plot(x, np.median(ys, axis=0), marker="o", ms=3, label=label)
        ax.axhline(GOAL, color="grey", lw=0.8, ls="--")
        ax.set_title(f"{what} mapped (median of {len(curves)} scenes)")
        ax.set_xlabel("imaging cycle")
    axes[0].set_ylabel("fraction mapped")
    axes[1].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def report(rows: list[dict[str, Any]], table: Any, cycles: int, cap: int) -> str:
    """The summary (medians, worst cases, goals) and the per-scene table; ``cap``: the cycles the
    runs went on to for the corridor (``scene``)."""
    import numpy as np

    from fsw.core.planning.team_views import TeamViewConfig

    def col(k: str) -> Any:
        return np.array([r[k] for r in rows if r[k] is not None], float)

    summary: list[dict[str, Any]] = []

    def add(name: str, v: Any, worst: Any, goal: str) -> None:
        summary.append({"figure": name, "median": v, "worst": worst, "goal": goal})

    ratio = col("cells_ratio")
    add("new cells per imaging cycle, team / RECON-bot alone", float(np.median(ratio)) if ratio.size else None,
        float(ratio.min()) if ratio.size else None, ">= 1.6")
    for k, part in (("cells_ratio_quarter", max(1, cycles // 4)), ("cells_ratio_half", max(1, cycles // 2))):
        v = col(k)
        add(f"the same over the first {part} cycles", float(np.median(v)) if v.size else None,
            float(v.min()) if v.size else None, "")
    for k, who in (("reach_left_team", "team"), ("reach_left_alone", "RECON-bot alone")):
        v = col(k)
        add(f"cells left unmapped after cycle {cycles} in range and line of sight of a RECON-bot station anywhere "
            f"behind the edge (truth, any pointing): {who}", float(np.median(v)), float(v.max()), "")
    # the overlap of a cycle's two views (cells both measured / cells either measured), three ways:
    # every cycle of every scene, each scene's worst cycle, each scene's mean
    every = np.array([o for r in rows for o in r.get("overlaps", [])], float)
    if every.size:
        add("overlap of a cycle's two views, every cycle of every scene (median of the cycles; worst: the worst "
            "single cycle)",
            float(np.median(every)), float(every.max()), "<= 0.15")
        add("cycles whose two views overlap more than 0.15 (of every cycle of every scene)",
            int((every > 0.15).sum()), f"of {every.size}", "")
    every_open = np.array([o for r in rows for o in r.get("overlaps_open", [])], float)
    if every_open.size:
        add("the same on the cells with information left (measured fewer than info_n_max times before the "
            "cycle; the rest are worth nothing to either view's rating)", float(np.median(every_open)),
            float(every_open.max()), "")
    ov = col("overlap_max")
    add("overlap of a cycle's two views, each scene's worst cycle (median and worst of the scenes)",
        float(np.median(ov)) if ov.size else None, float(ov.max()) if ov.size else None, "<= 0.15")
    ovs = col("overlap_of_smaller_max")
    add("overlap as a fraction of the smaller view, each scene's worst cycle (median and worst of the scenes)",
        float(np.median(ovs)) if ovs.size else None, float(ovs.max()) if ovs.size else None, "")
    ovm = col("overlap_mean")
    add("overlap of a cycle's two views, each scene's mean over its cycles (median and worst of the scenes)",
        float(np.median(ovm)) if ovm.size else None, float(ovm.max()) if ovm.size else None, "<= 0.15")
    # the cycles to 95 % of the corridor: each run went on past `cycles` until it got there or `cap`
    for k, who in (("corridor_cycles_team", "team"), ("corridor_cycles_recon", "RECON-bot alone")):
        got = [r[k] for r in rows if r[k] is not None]
        add(f"scenes with the corridor mapped to 95 % within {cycles} cycles: {who}",
            sum(v <= cycles for v in got), f"of {len(rows)}", "")
        add(f"scenes with the corridor mapped to 95 % within {cap} cycles: {who}", len(got), f"of {len(rows)}", "")
        add(f"cycles to 95 % of the corridor: {who} (scenes reaching it within {cap})",
            float(np.median(got)) if got else None, max(got) if got else None, "")
    at_stop = col("corridor_recon_at_stop")
    add(f"corridor mapped when the RECON-bot alone stopped ({cycles} cycles, or on to 95 % or {cap} cycles)",
        float(np.median(at_stop)), float(at_stop.min()), "")
    cratio = col("corridor_ratio")
    add(f"cycles to 95 % of the corridor, team / alone (scenes where both reach it within {cap})",
        float(np.median(cratio)) if cratio.size else None, float(cratio.max()) if cratio.size else None, "<= 0.6")
    # where the team reaches it and the RECON-bot alone does not within the cap, alone needs more
    # than `cap`: team / (cap + 1) bounds the ratio from above
    bound = np.array([r["corridor_cycles_team"] / (r["corridor_cycles_recon"] or cap + 1) for r in rows
                      if r["corridor_cycles_team"] is not None], float)
    add(f"cycles to 95 % of the corridor, team / alone (alone not within {cap}: counted as {cap + 1}, "
        "an upper bound of the ratio; scenes where the team reaches it)",
        float(np.median(bound)) if bound.size else None, float(bound.max()) if bound.size else None, "<= 0.6")
    for k, name in (("corridor_team", f"corridor mapped after cycle {cycles}: team"),
                    ("corridor_recon", f"corridor mapped after cycle {cycles}: RECON-bot alone"),
                    ("face_team", f"face mapped after cycle {cycles}: team"),
                    ("face_recon", f"face mapped after cycle {cycles}: RECON-bot alone")):
        v = col(k)
        add(name, float(np.median(v)), float(v.min()), "")
    ok = [r for r in rows if None not in (r["rmse_recon_m"], r["rmse_cliffbot_m"], r["rmse_fused_m"])]
    if ok:
        d = np.array([r["rmse_fused_m"] - min(r["rmse_recon_m"], r["rmse_cliffbot_m"]) for r in ok])
        add("fused RMS - better agent's RMS on cells both mapped (m)", float(np.median(d)), float(d.max()), "<= 0")
    for k, what in (("in2sig_recon", "the RECON-bot's map, cells both mapped"),
                    ("in2sig_cliffbot", "the Cliff-bot's map, cells both mapped"),
                    ("in2sig_fused", "the fused map, cells both mapped"),
                    ("in2sig_recon_own", "the RECON-bot's map, all its cells"),
                    ("in2sig_cliffbot_own", "the Cliff-bot's map, all its cells"),
                    ("in2sig_fused_own", "the fused map, all its cells")):
        v = col(k)
        if v.size:
            add(f"cells within 2 sigma of the truth: {what} (median; worst: lowest / highest scene)",
                float(np.median(v)), f"{v.min():.3f} / {v.max():.3f}", "0.90-0.99")
    add("views chosen blind (no view expected to map anything)", sum(r["blind_views"] for r in rows), "", "")
    add("scenes where the Cliff-bot reaches no target (corridor: toward the nearest, as far as the tethers hold)",
        sum(not r["reachable"] for r in rows), f"of {len(rows)}", "")
    for k, name in (("cliffbot_candidates", "the Cliff-bot's candidate views per cycle"),
                    ("cliffbot_views_per_cycle", "the Cliff-bot's views per cycle (its scan, "
                                                 f"up to {TeamViewConfig().cliffbot_views}; mean over the cycles)"),
                    ("cliffbot_new_share", "the Cliff-bot's share of the team's new cells"),
                    ("cliffbot_travel_m", "the Cliff-bot's farthest place from its start (m)")):
        v = col(k)
        add(name, float(np.median(v)) if v.size else None, float(v.min()) if v.size else None, "")
    tr, ar = col("recon_team_new_per_cycle"), col("recon_cells_per_cycle")
    add("the team's RECON-bot's new cells per cycle / the RECON-bot's alone", float(np.median(tr / ar)),
        float(np.min(tr / ar)), "")
    scan = TeamViewConfig().cliffbot_views
    for k, name in (("empty_views_recon_team", f"team: RECON-bot (of {cycles})"),
                    ("empty_views_cliffbot", f"team: Cliff-bot (of up to {cycles * scan}; what each view added)"),
                    ("empty_views_recon_alone", f"RECON-bot alone (of {cycles})")):
        v = col(k)
        add(f"views mapping < {EMPTY_VIEW_CELLS} new cells per scene, {name}", float(np.median(v)),
            float(v.max()), "")
    left, seeable = col("corridor_left_cells"), col("corridor_left_seeable")
    add(f"corridor cells unmapped after cycle {cycles} (team)", float(np.median(left)), float(left.max()), "")
    add("of them in range and line of sight of a candidate camera centre (truth, any pointing)",
        float(np.sum(seeable) / max(np.sum(left), 1.0)), "", "")
    e, o = col("cliffbot_expected_new"), col("cliffbot_obtained_new")
    add("the Cliff-bot's obtained / expected new cells (sum over a scene's cycles)",
        float(np.median(o / np.maximum(e, 1.0))), float(np.min(o / np.maximum(e, 1.0))), "")
    return ("## Summary\n\n" + table(summary, ["figure", "median", "worst", "goal"])
            + "\n\n## Scenes\n\n" + table(rows, list(COLUMNS)) + "\n")
