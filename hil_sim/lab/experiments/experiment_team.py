"""``safer-hil experiment team``: the team's done-when figures over seeded ``cliff-team`` scenes.

Each scene (``--scenes`` seeds from ``--seed``, ``--jobs`` processes, seeded: the same
command gives the same table) is judged by :mod:`hil_sim.team.team_eval`:

* **the truth's verdict**: the brute-force planner on the TRUE ground (every lattice node
  judged, Dijkstra over all of them, the way along each edge of a path found judged as the
  mission drives it) says which targets are reachable under the tether limits, the winches'
  length tolerance among them (``team_eval.winch_errors``: the tethers hold the body wherever
  the winches may stop); the same search at the exact lengths is reported beside it, so the
  table shows what the tolerance takes away. The mission is judged against the first;
* **the map was enough**: the legs the Cliff-bot's mission plans from its start to each target
  (its margins, its ways judged as it drives them) on the full-resolution map (the truth on
  the flight map grid: a perfect RECON-bot map) and on that map after the link's reduction
  (``fsw.core.codec.mapcodec`` at the flight configuration, its critical length the
  receiver's wheel, ``--wheel``, default the Cliff-bot's ``ClimberConfig.wheel_d_m``): targets
  reached on each, path length ratio, full-map hazard and rock cells the reduced map shows as
  safe;
* **the mission**: the Cliff-bot's mission on the bench on the reduced map
  (:func:`hil_sim.team.team_run.run_team`) with fixes from the RECON-bot standing at the
  scenario's start (rendered stereo pair, flight ``CliffbotLocalizer``; ``--fixer truth``: the
  true pose plus noise, no rendering): targets reached against the truth's, tether
  violations, hazard and unknown cells entered, fix errors against range with their NEES;
* **the link**: map bytes, fix bytes down and up, and their seconds on the 9600 bit/s radio.

A seed the scenario refuses to build (``ScenarioError``) is named under the table and the other
scenes are reported; any other failure of a scene writes no report (exit 1).

Writes OUT/team.csv, OUT/team.png (the first scene's mission), the result file
``docs/results/team.md`` (``hil_sim.lab.results``; ``--results-name`` names another, e.g. a
held-out run on other seeds) and prints the table.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import sys
from pathlib import Path
from typing import Any

HELP = "the team's done-when figures: truth's verdict, map enough, mission, fixes, link bytes"
LINK_BPS = 9600.0
RANGE_BINS = ((0.0, 3.0), (3.0, 4.0), (4.0, 5.0), (5.0, 7.0), (7.0, 10.0))


def add_arguments(p: argparse.ArgumentParser) -> None:
    from fsw.settings import DEFAULT_CONFIG

    p.add_argument("--scenario", default="cliff-team", help="scenario spec (seeded per scene)")
    p.add_argument("--scenes", type=int, default=30, help="number of seeded scenes")
    p.add_argument("--seed", type=int, default=0, help="first seed")
    p.add_argument("--jobs", type=int, default=1, help="scenes run in this many processes")
    p.add_argument("--missions", type=int, default=-1, help="run the bench mission on the first K scenes (-1: all)")
    p.add_argument("--fixer", choices=("recon", "truth"), default="recon",
                   help="fixes: the RECON-bot's rendered fiducials (recon) or the truth plus noise (truth)")
    p.add_argument("--wheel", type=float, default=-1.0,
                   help="the reduction's critical length (m); -1: the Cliff-bot's wheel diameter")
    p.add_argument("--max-s", type=float, default=900.0, help="a mission's simulated time limit (s)")
    p.add_argument("--config", default=str(DEFAULT_CONFIG), help="flight configuration (TOML)")
    p.add_argument("--cliffbot-config", default=str(DEFAULT_CONFIG.parent / "cliffbot.toml"),
                   help="the Cliff-bot's flight file (TOML): its tether, ground, navigation and mission sections")
    p.add_argument("--out", type=Path, default=Path("out/team"), help="output directory")
    p.add_argument("--rows", type=Path, default=None,
                   help="report the scenes a run already finished (its OUT/team_rows.jsonl) instead of running")
    p.add_argument("--results-name", default="team",
                   help="results file docs/results/NAME.md (e.g. a held-out run on other seeds)")


def scene(scenario: str, seed: int, config: str, wheel_m: float, mission: bool, fixer: str, max_s: float,
          picture: Path | None, cliffbot_config: str | None = None) -> dict[str, Any]:
    """One scene's row (and its fixes as ``_fixes``: range, cm, deg, NEES)."""
    import numpy as np

    from fsw.core.codec.mapcodec import decode_map, encode_map
    from fsw.core.geometry import MapGrid
    from fsw.core.team.tether import anchor_points
    from fsw.settings import load_settings
    from hil_sim.lab.map_enough import compare_maps
    from hil_sim.link.radio_channel import RadioChannel
    from hil_sim.team.team_eval import truth_verdict, winch_errors
    from hil_sim.team.team_run import ReconFixer, TeamSetup, TruthFixer, run_team
    from hil_sim.world import load_scenario

    cfg = load_settings(config)
    world = load_scenario(scenario, seed)
    if world.team is None:
        raise ValueError(f"scenario {scenario!r} has no team")
    setup = (TeamSetup(max_s=max_s) if cliffbot_config is None
             else TeamSetup.from_settings(load_settings(cliffbot_config), max_s=max_s))
    wheel = wheel_m if wheel_m > 0 else setup.climber.wheel_d_m
    grid = MapGrid.from_config(world.map_grid)
    full = world.ground_on_grid(grid)
    enc = encode_map(full, cell_m=grid.cell, wheel_diameter_m=wheel, cfg=cfg.codec)
    decoded = decode_map(enc.data)
    reduced = np.asarray(decoded.z, np.float64)
    anchors = anchor_points(full, grid, world.team.anchors_xy, setup.tether)
    start, targets = world.team.cliffbot_start_xy, world.team.targets_xyz[:, :2]
    exact = truth_verdict(world, grid, anchors, setup.tether, setup.climber)
    truth = truth_verdict(world, grid, anchors, setup.tether, setup.climber,
                          winch_errors(setup.mission.length_tol_m, setup.mission.margin_sigmas))
    cmp = compare_maps(full, reduced, grid, anchors, start, targets, setup.tether, setup.climber,
                       mission=setup.mission, error_bound_m=float(decoded.header.error_bound_m))
    ratio = cmp.path_ratio_max
    row: dict[str, Any] = {
        "seed": seed, "slope_deg": round(world.team.face_slope_deg, 1), "drop_m": round(world.team.drop_m, 2),
        "targets": len(targets), "reachable_truth": sum(1 for r in truth.reasons if not r),
        "reachable_truth_exact": sum(1 for r in exact.reasons if not r),
        "reachable_full": sum(1 for r in cmp.reasons_full if not r),
        "reachable_reduced": sum(1 for r in cmp.reasons_received if not r),
        "verdicts_differ": cmp.verdicts_differ,
        "path_ratio_max": round(ratio, 4) if math.isfinite(ratio) else "",
        "hazard_cells_lost": cmp.hazard_cells_lost, "map_bytes": len(enc.data),
        "truth_reasons": "; ".join(r or "-" for r in truth.reasons),
        "truth_reasons_exact": "; ".join(r or "-" for r in exact.reasons)}
    fixes: list[tuple[float, float, float, float]] = []
    if mission:
        fx: ReconFixer | TruthFixer = (ReconFixer(world, world.rover_start, seed) if fixer == "recon"
                                       else TruthFixer(seed))
        sec = run_team(world, grid, reduced, RadioChannel(seed=seed), seed, setup, fixer=fx, out=picture,
                       error_bound_m=float(decoded.header.error_bound_m))
        row.update({"reached": sec["targets_reached"], "missed": len(sec["reachable_missed"]),
                    "missed_why": "; ".join(sec["map_reasons"][k] or "not reached" for k in sec["reachable_missed"]),
                    "off_the_way": sum(1 for e in sec["events"] if e[1] == "OFF_THE_WAY"),
                    "fix_requests": sum(1 for e in sec["events"] if e[1] == "FIX_REQUEST"),
                    "unconfirmed": sum(1 for a, b in zip(sec["map_reasons"], sec["truth_reasons"], strict=True)
                                       if a and not b),
                    "state": sec["final_state"], "back_home": int(sec["back_home"]),
                    "home_off_m": sec["home_off_m"], "tether_violations": sec["tether_violations"],
                    "hazard_cells_entered": sec["hazard_cells_entered"],
                    "unknown_cells_entered": sec["unknown_cells_entered"],
                    "fixes": len(fx.errors), "fix_bytes_down": sec["link_bytes_down"],
                    "fix_bytes_up": sec["link_bytes_up"], "path_m": sec["path_m"], "sim_s": sec["sim_s"],
                    "safe_reason": sec["safe_reason"]})
        fixes = [(f.range_m, f.err_cm, f.err_deg, f.nees) for f in fx.errors]
    row["_fixes"] = fixes
    return row


def run(args: argparse.Namespace) -> int:
    from concurrent.futures import ProcessPoolExecutor, as_completed

    from tqdm import tqdm

    from fsw.framework.params import ConfigError
    from fsw.settings import load_settings
    from hil_sim.lab.results import bad_results_name
    from hil_sim.world import ScenarioError, load_scenario

    me = "safer-hil experiment team"
    if (bad := bad_results_name(args.results_name)) is not None:
        print(f"{me}: {bad}", file=sys.stderr)
        return 2
    if args.rows is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        return _report_rows(args)
    if args.scenes < 1 or args.jobs < 1 or not (args.max_s > 0):
        print(f"{me}: --scenes and --jobs must be >= 1, --max-s > 0", file=sys.stderr)
        return 2
    try:
        load_settings(args.config)
        load_settings(args.cliffbot_config)
        world = load_scenario(args.scenario, args.seed)
    except (ConfigError, ScenarioError, ValueError) as exc:
        print(f"{me}: {exc}", file=sys.stderr)
        return 2
    if world.team is None:
        print(f"{me}: scenario {args.scenario!r} has no team (use cliff-team)", file=sys.stderr)
        return 2
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "team_rows.jsonl").unlink(missing_ok=True)
    missions = args.scenes if args.missions < 0 else args.missions
    rows: dict[int, dict[str, Any]] = {}
    failed: list[str] = []
    refused: dict[int, str] = {}  # seeds whose scene the scenario refuses to build: no scene, not a failure
    with ProcessPoolExecutor(max_workers=args.jobs) as pool, \
            tqdm(total=args.scenes, desc="team scenes", unit="scene") as bar:
        futs = {pool.submit(scene, args.scenario, args.seed + k, args.config, args.wheel, k < missions,
                            args.fixer, args.max_s, args.out if k == 0 else None, args.cliffbot_config): args.seed + k
                for k in range(args.scenes)}
        for fut in as_completed(futs):
            seed = futs[fut]
            try:
                rows[seed] = fut.result()
            except ScenarioError as exc:
                refused[seed] = str(exc)
                bar.set_postfix_str(f"seed {seed}: refused by the scenario")
            except Exception as exc:  # noqa: BLE001 - one failed scene is reported, the rest go on
                failed.append(f"seed {seed}: {type(exc).__name__}: {exc}")
                bar.set_postfix_str(f"seed {seed}: FAILED")
            else:
                r = rows[seed]
                with open(args.out / "team_rows.jsonl", "a") as fh:  # each scene as it ends
                    fh.write(json.dumps(r) + "\n")
                bar.set_postfix_str(f"seed {seed}: {r.get('reached', '-')}/{r['reachable_truth']} reached")
            bar.update()
    if failed:
        print(f"{me}: scenes failed, no report written:\n  " + "\n  ".join(failed), file=sys.stderr)
        return 1
    if not rows:
        print(f"{me}: the scenario refuses every seed:\n  "
              + "\n  ".join(f"seed {k}: {v}" for k, v in sorted(refused.items())), file=sys.stderr)
        return 1
    for k, v in sorted(refused.items()):
        print(f"{me}: seed {k} not run, the scenario refuses it: {v}", file=sys.stderr)
    return _write([rows[s] for s in sorted(rows)], args, refused)


def _report_rows(args: argparse.Namespace) -> int:
    """The report of the rows a run wrote as its scenes ended (an interrupted run's subset)."""
    try:
        rows = [json.loads(line) for line in args.rows.read_text().splitlines() if line.strip()]
    except (OSError, ValueError) as exc:
        print(f"safer-hil experiment team: --rows {args.rows}: {exc}", file=sys.stderr)
        return 2
    if not rows or not all(isinstance(r, dict) and "seed" in r for r in rows):
        print(f"safer-hil experiment team: --rows {args.rows}: no scene rows", file=sys.stderr)
        return 2
    return _write(sorted(rows, key=lambda r: r["seed"]), args)


def _write(ordered: list[dict[str, Any]], args: argparse.Namespace, refused: dict[int, str] | None = None) -> int:
    from hil_sim.lab.results import command_line, write_results

    table = report(ordered, args, refused)
    with open(args.out / "team.csv", "w", newline="") as fh:
        keys = [k for k in ordered[-1] if k != "_fixes"]
        wr = csv.DictWriter(fh, fieldnames=keys, extrasaction="ignore")
        wr.writeheader()
        wr.writerows(ordered)
    pics = [args.out / "team.png"] if (args.out / "team.png").exists() else []
    write_results(args.results_name, command_line("team"), table, pics)
    print(table)
    return 0


def _seeds(seeds: list[int]) -> str:
    """``0-9, 12`` for a sorted list of seeds."""
    out: list[str] = []
    for s in sorted(seeds):
        if out and s == int(out[-1].split("-")[-1]) + 1:
            out[-1] = f"{out[-1].split('-')[0]}-{s}"
        else:
            out.append(str(s))
    return ", ".join(out)


def _mw(values: list[float], worst: str = "max", fmt: str = "{:.3g}") -> str:
    """``median / worst`` of a list ("-" when empty)."""
    import numpy as np

    v = [x for x in values if isinstance(x, (int, float)) and math.isfinite(x)]
    if not v:
        return "-"
    w = max(v) if worst == "max" else min(v)
    return f"{fmt.format(float(np.median(v)))} / {fmt.format(w)}"


def _total(rows: list[dict[str, Any]], key: str) -> str:
    """The sum of ``key`` over the rows ("-" when a row has none: rows of a run before it)."""
    return str(sum(r[key] for r in rows)) if all(key in r for r in rows) else "-"


def _why(ms: list[dict[str, Any]]) -> str:
    """``reason: count, ...`` over the scenes' missed targets ("-" when none)."""
    from collections import Counter

    got = Counter(w.strip() for r in ms for w in str(r.get("missed_why", "")).split(";") if w.strip())
    return ", ".join(f"{k}: {v}" for k, v in got.most_common()) or "-"


def report(rows: list[dict[str, Any]], args: argparse.Namespace, refused: dict[int, str] | None = None) -> str:
    """The done-when table, the fixes against range and the per-scene table; ``refused``: the
    seeds the scenario refused to build (named under the table, with why)."""
    import numpy as np

    from hil_sim.lab.results import markdown_table
    from hil_sim.team.team_eval import CHI2_95_6DOF

    ms = [r for r in rows if "reached" in r]
    n_t = sum(r["targets"] for r in rows)
    ratios = [r["path_ratio_max"] for r in rows if r["path_ratio_max"] != ""]
    lines = ["| done-when figure | value (median / worst per scene, or total) |", "|---|---|",
             f"| scenes (seeds) / targets | {len(rows)} ({_seeds([r['seed'] for r in rows])}) / {n_t} |",
             f"| targets reachable on the truth (brute force): with the winches' length tolerance / at the "
             f"exact lengths | {sum(r['reachable_truth'] for r in rows)} / {_total(rows, 'reachable_truth_exact')} |",
             f"| reachable on the full map / on the reduced map | {sum(r['reachable_full'] for r in rows)} / "
             f"{sum(r['reachable_reduced'] for r in rows)} |",
             f"| targets whose verdict differs, full vs reduced (total; scenes with any) | "
             f"{sum(r['verdicts_differ'] for r in rows)}; {sum(1 for r in rows if r['verdicts_differ'])} |",
             f"| path length reduced / full | {_mw(ratios, fmt='{:.3f}')} |",
             f"| scenes with a path over 10 % longer on the reduced map | {sum(1 for x in ratios if x > 1.1)} |",
             f"| full-map hazard or rock cells the reduced map shows as safe | "
             f"{_mw([r['hazard_cells_lost'] for r in rows], fmt='{:.0f}')} |",
             f"| map bytes (s at 9600 bit/s, worst) | {_mw([r['map_bytes'] for r in rows], fmt='{:.0f}')} "
             f"({max(r['map_bytes'] for r in rows) * 8 / LINK_BPS:.1f} s) |"]
    if ms:
        lines += [
            f"| bench missions (fixes: {args.fixer}) | {len(ms)} |",
            f"| targets reached / reachable on the truth with the tolerance / at the exact lengths (total) | "
            f"{sum(r['reached'] for r in ms)} / {sum(r['reachable_truth'] for r in ms)} / "
            f"{_total(ms, 'reachable_truth_exact')} |",
            f"| truth-reachable targets not reached (total; scenes) | {sum(r['missed'] for r in ms)}; "
            f"{sum(1 for r in ms if r['missed'])} |",
            f"| why the truth-reachable targets were missed (mission's reason: count) | {_why(ms)} |",
            f"| re-plans because the lengths held it elsewhere (OFF_THE_WAY; median / worst) | "
            f"{_mw([r.get('off_the_way', 0) for r in ms], fmt='{:.0f}')} |",
            f"| fixes answered / fix requests (total) | {sum(r['fixes'] for r in ms)} / "
            f"{sum(r.get('fix_requests', 0) for r in ms)} |",
            f"| targets the mission called unreachable that the truth reaches | {sum(r['unconfirmed'] for r in ms)} |",
            f"| tether violations (steps) | {_mw([r['tether_violations'] for r in ms], fmt='{:.0f}')} |",
            f"| hazard cells entered | {_mw([r['hazard_cells_entered'] for r in ms], fmt='{:.0f}')} |",
            f"| unknown cells entered | {_mw([r['unknown_cells_entered'] for r in ms], fmt='{:.0f}')} |",
            f"| missions ending DONE | {sum(1 for r in ms if r['state'] == 'DONE')} |",
            f"| missions back at the start (HOME) / its true distance from the start at the end, m | "
            f"{_total(ms, 'back_home')} / {_mw([r.get('home_off_m', '') for r in ms], fmt='{:.3f}')} |",
            f"| fix bytes down / up | {_mw([r['fix_bytes_down'] for r in ms], fmt='{:.0f}')} / "
            f"{_mw([r['fix_bytes_up'] for r in ms], fmt='{:.0f}')} |",
            f"| bytes down per mission, map + fixes (s at 9600 bit/s, worst) | "
            f"{_mw([r['map_bytes'] + r['fix_bytes_down'] for r in ms], fmt='{:.0f}')} "
            f"({max(r['map_bytes'] + r['fix_bytes_down'] for r in ms) * 8 / LINK_BPS:.1f} s) |"]
    fixes = [f for r in rows for f in r["_fixes"]]
    out = "\n".join(lines)
    if fixes:
        fl = ["| range (m) | fixes | position error cm, median / worst | heading error deg, median / worst | "
              "NEES within chi2 95 % (6 dof) |", "|---|---|---|---|---|"]
        for lo, hi in RANGE_BINS:
            sel = [f for f in fixes if lo <= f[0] < hi] if args.fixer == "recon" else (fixes if lo == 0.0 else [])
            if not sel:
                continue
            within = np.mean([f[3] <= CHI2_95_6DOF for f in sel])
            label = f"{lo:g}-{hi:g}" if args.fixer == "recon" else "(truth plus noise)"
            fl.append(f"| {label} | {len(sel)} | {_mw([f[1] for f in sel], fmt='{:.2f}')} | "
                      f"{_mw([f[2] for f in sel], fmt='{:.2f}')} | {100 * within:.0f} % |")
        out += "\n\nFixes against range (all missions):\n\n" + "\n".join(fl)
    if refused:
        out += "\n\nSeeds the scenario refuses (no scene to run):\n\n" + "\n".join(
            f"- {k}: {v}" for k, v in sorted(refused.items()))
    per = [{k: v for k, v in r.items() if k != "_fixes"} for r in rows]
    return out + "\n\nPer scene:\n\n" + markdown_table(per)
