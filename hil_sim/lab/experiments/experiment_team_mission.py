"""``safer-hil experiment team-mission``: the real team mission end to end over seeded scenes.

For each seeded ``cliff-team`` scene (``--scenes`` from ``--seed``, in ``--jobs`` processes) the
lockstep team mission of ``safer-hil run --scenario cliff-team`` (``--steps`` imaging steps of
the RECON-bot, method 5; both flight programs on one stepped clock; docs/team.md, "Running a
team mission"), each in ``OUT/seed<S>`` with its ``summary.json`` and ``team.png``. Per scene
the summary's ``team`` section: whether the delivered map let the Cliff-bot leave its start,
targets reachable on the truth and reached (for a missed one the truth reaches, where the flight
planner's way on the true ground first meets ground the mission's map does not know: the
``truth_way`` of the team section), tether violations, hazard and unknown cells
entered, the cells each agent's own views made known (``cells_by_agent``), whether it ended
back at its start (its ``HOME`` event), the end state and reason, the bytes each way, and the
RECON-bot's own safety and map figures (frames with a wheel over the drop, frames it moved with
a wheel on ground its geofence did not know, map RMSE, and its mapped cells within 1 m past the
lip with how many lie more than 20 cm above the truth: docs/perception.md "Occluding lips").
Any edge violation is a failure: the command says so on one line and exits 1. Over all scenes the RECON-bot's fixes
(each FIX against the Cliff-bot's true pose at that instant) by range band: median and worst
position and heading error, and the fraction whose NEES lies within the chi-square 95 % bound
(6 dof), and the RECON-bot's own heading error at each (what a fix from its estimate alone would
carry; docs/algorithm.md §5.2). Writes OUT/team_mission.csv and ``docs/results/team-mission.md`` with the picture
(``team.png``) of the scene that reached the most targets. ``--report-only`` writes them again
from the missions stored in OUT (no mission is run).
"""

from __future__ import annotations

import argparse
import csv
import sys
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path
from typing import Any

HELP = "the team mission end to end (safer-hil run --scenario cliff-team) over seeded scenes"
CHI2_95_6DOF = 12.5916
BANDS = ((0.0, 3.0), (3.0, 4.0), (4.0, 5.0), (5.0, 6.0), (6.0, 8.0), (8.0, 10.0), (10.0, 99.0))
COLUMNS = (
    "seed",
    "start_usable",
    "targets",
    "truth_reachable",
    "reached",
    "reachable_missed",
    "tether_violations",
    "hazard_cells",
    "unknown_cells",
    "fixes",
    "recon_cells",
    "cliffbot_cells",
    "final_state",
    "safe_reason",
    "back_home",
    "bytes_down",
    "bytes_up",
    "map_reasons",
    "looks",
    "reached_after_looks",
    "recon_edge_violations",
    "recon_unknown_ground",
    "recon_map_rmse_cm",
    "recon_past_lip_cells",
    "recon_past_lip_off",
)
PAST_LIP_M = 1.0  # the band past the lip the map figures look at (m, off the plateau)
OFF_M = 0.20  # a cell there "off" when its height is above the truth by more (m)


def add_arguments(p: argparse.ArgumentParser) -> None:
    from fsw.settings import DEFAULT_CONFIG

    p.add_argument("--scenario", default="cliff-team", help="scenario spec (seeded per scene)")
    p.add_argument("--scenes", type=int, default=10, help="number of seeded scenes")
    p.add_argument("--seed", type=int, default=0, help="first seed")
    p.add_argument("--steps", type=int, default=20, help="the RECON-bot's imaging steps (safer-hil run's default)")
    p.add_argument("--jobs", type=int, default=1, help="scenes run in parallel (processes)")
    p.add_argument("--config", default=str(DEFAULT_CONFIG), help="the RECON-bot's flight configuration (TOML)")
    p.add_argument("--out", type=Path, default=Path("out/team-mission"), help="output directory")
    p.add_argument("--report-only", action="store_true", help="write the report from the missions stored in --out")
    p.add_argument("--results-name", default="team-mission",
                   help="results file docs/results/NAME.md (e.g. a held-out run on other seeds)")


def scene(scenario: str, seed: int, steps: int, config: str, out: Path) -> dict[str, Any]:
    """One team mission (a process of its own): its row and its fixes."""
    import shutil

    from hil_sim.mission.mission_run import RunSpec, run_mission

    d = out / f"seed{seed}"
    shutil.rmtree(d, ignore_errors=True)
    got = scene_row(run_mission(RunSpec(scenario, "5", steps, seed, config, True, d), mode="fresh"), seed)
    got["row"] |= past_lip(scenario, seed, d)
    return got


def past_lip(scenario: str, seed: int, d: Path) -> dict[str, int]:
    """The RECON-bot's map just past the lip (docs/perception.md "Occluding lips"): its mapped cells off the
    plateau within ``PAST_LIP_M`` of it (on the truth) and how many of them lie more than ``OFF_M``
    above the truth (``map_error.npy``; -1 each without it)."""
    import numpy as np
    from scipy import ndimage

    from fsw.core.geometry import MapGrid
    from hil_sim.mission.run_spec import RunSpec, mission_config
    from hil_sim.world import load_scenario

    try:
        err = np.load(d / "map_error.npy")
    except (OSError, ValueError):
        return {"recon_past_lip_cells": -1, "recon_past_lip_off": -1}
    world = load_scenario(scenario, seed)
    grid = MapGrid.from_config(mission_config(RunSpec(scenario, seed=seed), world).map)
    x0, y0, yaw = (float(v) for v in world.rover_start)  # the flight map's frame: odometry from the start
    X, Y = grid.centers()
    wx, wy = x0 + np.cos(yaw) * X - np.sin(yaw) * Y, y0 + np.sin(yaw) * X + np.cos(yaw) * Y
    off_plateau = ~world.on_plateau(wx, wy)
    band = off_plateau & (ndimage.distance_transform_edt(off_plateau) * grid.cell <= PAST_LIP_M)
    band &= np.isfinite(err) if err.shape == grid.shape else np.zeros(grid.shape, bool)
    return {"recon_past_lip_cells": int(band.sum()), "recon_past_lip_off": int(np.count_nonzero(err[band] > OFF_M))}


def target_text(t: dict[str, Any], k: int) -> str:
    """What became of target ``k`` and the truth's verdict: ``reached (2 looks)``,
    ``unknown ground (3 looks) / truth: reachable``, ``out of tether reach / truth: out of tether reach``."""
    reasons, reached = list(t.get("map_reasons", [])), list(t.get("reached", []))
    looks, truth = list(t.get("target_looks", [])), list(t.get("truth_reasons", []))
    n = int(looks[k]) if k < len(looks) else 0
    if k < len(reached) and reached[k]:
        return "reached" + (f" ({n} looks)" if n else "")
    why = str(reasons[k]) if k < len(reasons) and reasons[k] else "planned, not reached"
    return why + (f" / truth: {truth[k] or 'reachable'}" if k < len(truth) else "") + way_text(t, k)


def way_text(t: dict[str, Any], k: int) -> str:
    """For a target the truth reaches: where the flight planner's way on the true ground first
    needs ground the mission's map does not know (the team section's ``truth_way``), as
    `` (its way on the truth: unknown from node 13 of 17, 2 of 177 cells, 71 deg)``; empty without it."""
    truth, ways = list(t.get("truth_reasons", [])), list(t.get("truth_way") or [])
    if k >= len(truth) or truth[k] or k >= len(ways) or not ways[k]:
        return ""
    w = ways[k]
    if w.get("first_unknown") is None:
        return f" (its way on the truth: known at all {w['nodes']} nodes)"
    return (f" (its way on the truth: unknown from node {w['first_unknown'] + 1} of {w['nodes']}, "
            f"{w['unknown_cells']} of {w['footprint_cells']} cells, {w['slope_deg']:.0f} deg)")


def scene_row(s: dict[str, Any], seed: int) -> dict[str, Any]:
    """A scene's row and fixes from its mission summary."""
    from hil_sim.team.team_eval import came_home

    t = s.get("team") or {}
    reasons = [str(r) for r in t.get("map_reasons", [])]
    row = {
        "seed": seed,
        "start_usable": int(bool(t.get("map_received")) and not any(r.startswith("start:") for r in reasons)),
        "targets": t.get("targets", 0),
        "truth_reachable": t.get("targets_reachable_by_truth", 0),
        "reached": t.get("targets_reached", 0),
        "reachable_missed": len(t.get("reachable_missed", [])),
        "tether_violations": t.get("tether_violations", 0),
        "hazard_cells": t.get("hazard_cells_entered", 0),
        "unknown_cells": t.get("unknown_cells_entered", 0),
        "fixes": len(t.get("fix_errors_cm", [])),
        "recon_cells": (t.get("cells_by_agent") or {}).get("recon", 0),
        "cliffbot_cells": (t.get("cells_by_agent") or {}).get("cliffbot", 0),
        "final_state": t.get("final_state", "-"),
        "safe_reason": t.get("safe_reason", ""),
        "back_home": int(t.get("back_home", came_home(t.get("events", [])))),
        "bytes_down": t.get("link_bytes_down", 0),
        "bytes_up": t.get("link_bytes_up", 0),
        "map_reasons": "; ".join(target_text(t, k) for k in range(len(reasons))),
        "looks": sum(int(n) for n in t.get("target_looks", [])),
        "reached_after_looks": sum(1 for n, ok in zip(t.get("target_looks", []), t.get("reached", []), strict=False)
                                   if n and ok),
    }
    fixes = list(
        zip(
            t.get("fix_ranges_m", []),
            t.get("fix_errors_cm", []),
            t.get("fix_errors_deg", []),
            t.get("fix_nees", []),
            t.get("fix_recon_yaw_err_deg", [float("nan")] * len(t.get("fix_nees", []))),
            strict=False,
        )
    )
    return {"row": row | recon_row(s), "fixes": fixes, "times": flight_times(s)}


def flight_times(s: dict[str, Any]) -> dict[str, list[float]]:
    """How long each agent's sensing took in the mission's (simulated) flight time: every
    RECON-bot imaging step (motion, view, fusion, planning) and every look of the Cliff-bot (its
    head's scan, ``SENSE_REQUEST`` to ``SENSED``)."""
    t = [float(x["sim_s"]) for x in s.get("steps", []) if isinstance(x, dict) and "sim_s" in x]
    looks: list[float] = []
    asked: float | None = None
    for e in (s.get("team") or {}).get("events", []):
        if len(e) > 1 and e[1] == "SENSE_REQUEST":
            asked = float(e[0])
        elif len(e) > 1 and e[1] == "SENSED" and asked is not None:
            looks.append(round(float(e[0]) - asked, 3))
            asked = None
    return {"recon_step_s": [round(b - a, 3) for a, b in zip(t, t[1:], strict=False)], "cliffbot_look_s": looks}


def recon_row(s: dict[str, Any]) -> dict[str, Any]:
    """The RECON-bot's figures of a scene's row."""
    rmse = s.get("map_rmse_m")
    return {
        "recon_edge_violations": int(s.get("edge_violations", 0)),
        "recon_unknown_ground": int(s.get("wheels_on_unknown_ground", 0)),
        "recon_map_rmse_cm": round(100.0 * float(rmse), 2) if rmse is not None else float("nan"),
    }


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from hil_sim.lab.results import bad_results_name, command_line, write_results
    from hil_sim.world import ScenarioError, load_scenario

    me = "safer-hil experiment team-mission"
    if (bad := bad_results_name(args.results_name)) is not None:
        print(f"{me}: {bad}", file=sys.stderr)
        return 2
    if args.scenes < 1 or args.jobs < 1 or args.steps < 0:
        print(f"{me}: --scenes and --jobs must be >= 1, --steps >= 0", file=sys.stderr)
        return 2
    try:
        w = load_scenario(args.scenario, args.seed)
        if w.team is None:
            raise ScenarioError(f"{args.scenario} has no team (use a cliff-team scenario)")
    except (ScenarioError, ValueError, OSError) as exc:
        print(f"{me}: {exc}", file=sys.stderr)
        return 2
    seeds = list(range(args.seed, args.seed + args.scenes))
    got: list[dict[str, Any]] = []
    if args.report_only:
        import json

        for sd in seeds:
            try:
                got.append(scene_row(json.loads((args.out / f"seed{sd}" / "summary.json").read_text()), sd))
                got[-1]["row"] |= past_lip(args.scenario, sd, args.out / f"seed{sd}")
            except (OSError, ValueError) as exc:
                print(f"seed {sd}: no stored mission ({type(exc).__name__}: {exc})", file=sys.stderr)
    with ProcessPoolExecutor(max_workers=args.jobs) as pool:
        futs = {pool.submit(scene, args.scenario, s, args.steps, args.config, args.out): s
                for s in seeds if not args.report_only}
        for fut in as_completed(futs):
            try:
                got.append(fut.result())
            except Exception as exc:  # noqa: BLE001 - one failed scene is reported, the rest go on
                print(f"seed {futs[fut]}: FAILED {type(exc).__name__}: {exc}", file=sys.stderr)
                continue
            r = got[-1]["row"]
            print(
                f"[{len(got)}/{len(seeds)}] seed {r['seed']}: start {'usable' if r['start_usable'] else 'NOT usable'}, "
                f"reached {r['reached']} of {r['truth_reachable']} the truth reaches, {r['final_state']} "
                f"{'at its start' if r['back_home'] else 'AWAY from its start'} "
                f"{r['safe_reason']}; RECON-bot edge violations {r['recon_edge_violations']}, "
                f"wheels on unknown ground {r['recon_unknown_ground']}, map RMSE {r['recon_map_rmse_cm']:.2f} cm, "
                f"cells past the lip {r['recon_past_lip_cells']} ({r['recon_past_lip_off']} > 20 cm above the truth)",
                flush=True,
            )
    if not got:
        return 1
    rows = sorted((g["row"] for g in got), key=lambda r: r["seed"])
    fixes = [f for g in got for f in g["fixes"]]
    args.out.mkdir(parents=True, exist_ok=True)
    with open(args.out / "team_mission.csv", "w", newline="") as fh:
        wr = csv.DictWriter(fh, fieldnames=COLUMNS)
        wr.writeheader()
        wr.writerows(rows)
    lines = [
        "| seed | start usable | targets | reachable (truth) | reached | tether violations | hazard cells | "
        "unknown cells | fixes | cells RECON-bot / Cliff-bot | end | bytes down / up | "
        "per target (/ the truth's verdict) | RECON-bot edge violations | RECON-bot wheels on unknown ground | "
        "RECON-bot map RMSE (cm) | RECON-bot cells past the lip (> 20 cm above the truth) |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        end = (r["final_state"] + (f" ({r['safe_reason']})" if r["safe_reason"] else "")
               + (", at its start" if r["back_home"] else ", away from its start"))
        lines.append(
            f"| {r['seed']} | {'yes' if r['start_usable'] else 'no'} | {r['targets']} | {r['truth_reachable']} | "
            f"{r['reached']} | {r['tether_violations']} | {r['hazard_cells']} | {r['unknown_cells']} | "
            f"{r['fixes']} | {r['recon_cells']} / {r['cliffbot_cells']} | {end} | "
            f"{r['bytes_down']} / {r['bytes_up']} | {r['map_reasons']} | {r['recon_edge_violations']} | "
            f"{r['recon_unknown_ground']} | {r['recon_map_rmse_cm']:.2f} | "
            f"{r['recon_past_lip_cells']} ({r['recon_past_lip_off']}) |"
        )
    reach = sum(r["truth_reachable"] for r in rows)
    rmse = np.array([r["recon_map_rmse_cm"] for r in rows], float)
    rmse = rmse[np.isfinite(rmse)]
    done = sum(min(r["reached"], r["truth_reachable"]) for r in rows)
    summary = (
        f"{len(rows)} scenes, {args.steps} imaging steps each: the start usable on the delivered map in "
        f"{sum(r['start_usable'] for r in rows)}, the Cliff-bot back at its start at the end in "
        f"{sum(r['back_home'] for r in rows)}; targets reached {sum(r['reached'] for r in rows)} "
        f"(of the {reach} the truth reaches: {done}); tether violations {sum(r['tether_violations'] for r in rows)}, "
        f"hazard cells entered {sum(r['hazard_cells'] for r in rows)}, unknown cells entered "
        f"{sum(r['unknown_cells'] for r in rows)}; looks taken to approach targets on unknown ground "
        f"{sum(r['looks'] for r in rows)}, targets reached after such looks "
        f"{sum(r['reached_after_looks'] for r in rows)}. The RECON-bot: edge violations (frames with a wheel "
        f"over the drop) {sum(r['recon_edge_violations'] for r in rows)}, frames moved with a wheel on unknown "
        f"ground {sum(r['recon_unknown_ground'] for r in rows)}, map RMSE "
        + (f"median {float(np.median(rmse)):.2f} cm, worst {float(np.max(rmse)):.2f} cm" if len(rmse) else "-")
        + f"; its cells within {PAST_LIP_M:g} m past the lip more than {100 * OFF_M:.0f} cm above the truth "
        f"{sum(max(r['recon_past_lip_off'], 0) for r in rows)} (of "
        f"{sum(max(r['recon_past_lip_cells'], 0) for r in rows)} mapped there)."
    )
    steps_s = [x for g in got for x in g.get("times", {}).get("recon_step_s", [])]
    looks_s = [x for g in got for x in g.get("times", {}).get("cliffbot_look_s", [])]
    if steps_s and looks_s:  # what an imaging cycle of the team is (docs/team.md, Team views)
        summary += (
            f" In the flight programs' own (simulated) time a RECON-bot imaging step took median "
            f"{float(np.median(steps_s)):.1f} s (shortest {min(steps_s):.1f} s, {len(steps_s)} steps) and a look "
            "of the Cliff-bot (its head's scan, one pair per pointing of `[cliffbot_sensing] pan_deg`) median "
            f"{float(np.median(looks_s)):.1f} s (longest {max(looks_s):.1f} s, {len(looks_s)} looks)."
        )
    band = [
        "| range (m) | fixes | position error median / worst (cm) | heading error median / worst (deg) | "
        "NEES within chi2 95 % | the RECON-bot's own heading error then, median (deg) |",
        "|---|---|---|---|---|---|",
    ]
    for lo, hi in BANDS:
        sel = [f for f in fixes if lo <= f[0] < hi]
        if not sel:
            continue
        pe, de = np.array([f[1] for f in sel]), np.array([f[2] for f in sel])
        ok = np.mean([f[3] <= CHI2_95_6DOF for f in sel])
        own = np.array([abs(f[4]) if len(f) > 4 and f[4] is not None else np.nan for f in sel], float)
        band.append(
            f"| {lo:g}-{hi:g} | {len(sel)} | {np.median(pe):.2f} / {pe.max():.2f} | "
            f"{np.median(de):.2f} / {de.max():.2f} | {100 * ok:.0f} % | "
            f"{'-' if np.isnan(own).all() else f'{np.nanmedian(own):.2f}'} |"
        )
    within = np.mean([f[3] <= CHI2_95_6DOF for f in fixes]) if fixes else float("nan")
    report = (
        f"Scenario `{args.scenario}`, seeds {seeds[0]}-{seeds[-1]}. {summary}\n\n"
        + "\n".join(lines)
        + f"\n\nThe RECON-bot's fixes during the missions ({len(fixes)}; NEES within the chi2 95 % bound: "
        f"{100 * within:.0f} %):\n\n" + "\n".join(band) + "\n"
    )
    (args.out / "team_mission.md").write_text(f"# The team mission end to end\n\n{report}")
    best = max(rows, key=lambda r: (r["reached"], -r["seed"]))
    write_results(args.results_name, command_line("team-mission"), report,
                  figures=[args.out / f"seed{best['seed']}" / "team.png"])
    print(report)
    over = [r["seed"] for r in rows if r["recon_edge_violations"] > 0]
    if over:
        print(f"{me}: FAILED: the RECON-bot had a wheel over the drop ({sum(r['recon_edge_violations'] for r in rows)} "
              f"frames) in seed(s) {', '.join(map(str, over))}", file=sys.stderr)
        return 1
    return 0
