"""``safer-hil experiment team``: is the received map enough for the Cliff-bot's task?

For each seeded ``cliff-team`` scene (``--scenes``, from ``--seed``): the targets are
planned from the Cliff-bot's start by the same planner (``fsw.core.team.face_planner``) on

* the TRUE ground on the flight map grid (the brute-force reference: what is reachable at all),
* the full-resolution map (the truth on the grid; the RECON-bot's perfect map), and
* that map after the link's quadtree reduction (``fsw.core.codec.mapcodec``: encoded at the
  flight configuration's error bound and decoded, as the Cliff-bot receives it),

and compared: targets reachable on each, targets whose verdict differs between the full and
the reduced map, path length ratio reduced/full, hazard cells of the full map lost by the
reduction, and the container's bytes and its time on the 9600 bit/s link. With
``--missions K`` the first K scenes also run the Cliff-bot's mission on the bench on the
reduced map (``hil_sim.team.team_run``, fixes from ``TruthFixer``): targets reached, tether
violations, hazard and unknown cells entered; the first one's picture is OUT/team.png.
Writes OUT/team.csv, the result file ``docs/results/team.md`` (``hil_sim.lab.results``: date,
commit, command, table, the picture) and prints the table.
"""

from __future__ import annotations

import argparse
import csv
import math
import sys
from pathlib import Path

HELP = "the Cliff-bot's task on the received (reduced) map vs the full map and the truth"


def add_arguments(p: argparse.ArgumentParser) -> None:
    from fsw.settings import DEFAULT_CONFIG

    p.add_argument("--scenario", default="cliff-team", help="scenario spec (seeded per scene)")
    p.add_argument("--scenes", type=int, default=30, help="number of seeded scenes")
    p.add_argument("--seed", type=int, default=0, help="first seed")
    p.add_argument("--missions", type=int, default=0, help="run the bench mission on the first K scenes")
    p.add_argument("--config", default=str(DEFAULT_CONFIG), help="flight configuration (TOML)")
    p.add_argument("--out", type=Path, default=Path("out/team"), help="output directory")


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from fsw.core.codec.mapcodec import MapCodecError, decode_map, encode_map
    from fsw.core.geometry import MapGrid
    from fsw.core.team.face_planner import ClimberConfig, ground_layers, plan_targets
    from fsw.core.team.tether import TetherConfig, anchor_points
    from fsw.framework.params import ConfigError
    from fsw.settings import load_settings
    from hil_sim.lab.results import command_line, markdown_table, write_results
    from hil_sim.link.radio_channel import RadioChannel
    from hil_sim.team.team_run import TruthFixer, run_team
    from hil_sim.world import ScenarioError, load_scenario

    me = "safer-hil experiment team"
    if args.scenes < 1 or args.missions < 0:
        print(f"{me}: --scenes must be >= 1 and --missions >= 0", file=sys.stderr)
        return 2
    try:
        cfg = load_settings(args.config)
    except (ConfigError, ValueError) as exc:
        print(f"{me}: {exc}", file=sys.stderr)
        return 2
    tcfg, ccfg = TetherConfig(), ClimberConfig()
    rows = []
    for k in range(args.scenes):
        seed = args.seed + k
        try:
            world = load_scenario(args.scenario, seed)
        except (ScenarioError, ValueError) as exc:
            print(f"{me}: {exc}", file=sys.stderr)
            return 2
        if world.team is None:
            print(f"{me}: scenario {args.scenario!r} has no team", file=sys.stderr)
            return 2
        grid = MapGrid.from_config(world.map_grid)
        full = world.ground_on_grid(grid)
        try:
            enc = encode_map(full, cell_m=grid.cell, wheel_diameter_m=cfg.rover.wheel_diameter_m, cfg=cfg.codec)
            reduced = np.asarray(decode_map(enc.data).z, np.float64)
        except (MapCodecError, ValueError) as exc:
            print(f"{me}: seed {seed}: {exc}", file=sys.stderr)
            return 1
        anchors = anchor_points(full, grid, world.team.anchors_xy, tcfg)
        start, targets = world.team.cliffbot_start_xy, world.team.targets_xyz[:, :2]
        p_full = plan_targets(full, grid, anchors, start, targets, tcfg, ccfg)
        p_red = plan_targets(reduced, grid, anchors, start, targets, tcfg, ccfg)
        h_full = ground_layers(full, grid, ccfg).hazard
        h_red = ground_layers(reduced, grid, ccfg).hazard
        both = [i for i in range(len(targets)) if not p_full.reasons[i] and not p_red.reasons[i]]
        ratio = max((p_red.lengths_m[i] / p_full.lengths_m[i] for i in both), default=math.nan)
        row = {"seed": seed, "slope_deg": round(world.team.face_slope_deg, 1), "drop_m": round(world.team.drop_m, 2),
               "targets": len(targets),
               "reachable_truth_full": sum(1 for r in p_full.reasons if not r),
               "reachable_reduced": sum(1 for r in p_red.reasons if not r),
               "verdicts_differ": sum(1 for a, b in zip(p_full.reasons, p_red.reasons, strict=True)
                                      if bool(a) != bool(b)),
               "path_ratio_max": round(ratio, 4) if math.isfinite(ratio) else "",
               "hazard_cells_lost": int((h_full & ~h_red).sum()),
               "map_bytes": len(enc.data), "link_s_9600": round(8 * len(enc.data) / 9600.0, 1)}
        if k < args.missions:
            args.out.mkdir(parents=True, exist_ok=True)
            sec = run_team(world, grid, reduced, RadioChannel(seed=seed), seed, fixer=TruthFixer(seed),
                           out=args.out if k == 0 else None)  # the first mission's picture: team.png
            row.update({"mission_reached": sec["targets_reached"], "mission_state": sec["final_state"],
                        "tether_violations": sec["tether_violations"],
                        "hazard_cells_entered": sec["hazard_cells_entered"],
                        "unknown_cells_entered": sec["unknown_cells_entered"],
                        "fix_bytes_down": sec["link_bytes_down"], "fix_bytes_up": sec["link_bytes_up"]})
        rows.append(row)
        print(row, file=sys.stderr)
    args.out.mkdir(parents=True, exist_ok=True)
    keys = sorted({key for r in rows for key in r}, key=lambda x: list(rows[-1]).index(x) if x in rows[-1] else 99)
    with open(args.out / "team.csv", "w", newline="") as fh:
        wr = csv.DictWriter(fh, fieldnames=keys)
        wr.writeheader()
        wr.writerows(rows)
    n_t = sum(r["targets"] for r in rows)
    ratios = [r["path_ratio_max"] for r in rows if r["path_ratio_max"] != ""]
    lines = ["| measure | value |", "|---|---|",
             f"| scenes | {len(rows)} |", f"| targets | {n_t} |",
             f"| reachable on the truth / full map | {sum(r['reachable_truth_full'] for r in rows)} |",
             f"| reachable on the reduced map | {sum(r['reachable_reduced'] for r in rows)} |",
             f"| targets whose verdict differs (full vs reduced) | {sum(r['verdicts_differ'] for r in rows)} |",
             "| path length reduced / full, median / worst | "
             + (f"{np.median(ratios):.3f} / {max(ratios):.3f} |" if ratios else "- |"),
             f"| full-map hazard cells lost by the reduction, median / worst | "
             f"{np.median([r['hazard_cells_lost'] for r in rows]):.0f} / {max(r['hazard_cells_lost'] for r in rows)} |",
             f"| map bytes, median / worst (s at 9600 bit/s) | {np.median([r['map_bytes'] for r in rows]):.0f} / "
             f"{max(r['map_bytes'] for r in rows)} ({max(r['link_s_9600'] for r in rows)} s) |"]
    ms = [r for r in rows if "mission_reached" in r]
    if ms:
        lines += [f"| bench missions | {len(ms)} |",
                  f"| targets reached / reachable on the truth | {sum(r['mission_reached'] for r in ms)} / "
                  f"{sum(r['reachable_truth_full'] for r in ms)} |",
                  f"| tether violations (steps), total / worst | {sum(r['tether_violations'] for r in ms)} / "
                  f"{max(r['tether_violations'] for r in ms)} |",
                  f"| hazard cells entered, total | {sum(r['hazard_cells_entered'] for r in ms)} |",
                  f"| unknown cells entered, total | {sum(r['unknown_cells_entered'] for r in ms)} |",
                  f"| fix bytes down / up, worst | {max(r['fix_bytes_down'] for r in ms)} / "
                  f"{max(r['fix_bytes_up'] for r in ms)} |"]
    table = "\n".join(lines) + "\n\nPer scene:\n\n" + markdown_table(rows)
    write_results("team", command_line("team"), table, [args.out / "team.png"])
    print(table)
    return 0
