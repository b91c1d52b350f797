"""``safer-hil experiment close-edge``: does the rover leave a start boxed in by a close edge
(issue 30 item 1; docs/experiments.md)?

Generated starts (the ``terrain`` family, hil_sim/world/terrain.py) with the edge
``--distances`` from the rover's footprint (its bumper when ahead, its wheels when right, a front
corner when diagonal) at each of ``--bearings`` (deg from the heading: 0 ahead, -45 ahead-right,
-90 right), for each ``--seeds``, each run as a full lockstep mission (``hil_sim.mission.mission_run``)
per method, ``--jobs`` at a time in a process pool. ``--near-edge SPEC`` adds starts on a scenario
with its own edge (a real DEM through ``file:``): at each bearing and distance, and each of
``--along`` positions along its edge, the start is placed beside the edge
(``hil_sim.world.scenarios.start_near_edge``) and run with seed 0. With ``--raster-when-stuck``
the raster methods run only from the starts an information method stayed at. It writes ``close_edge.json`` and
``close_edge.md``: per start, each method's odometer and the first reason it stayed; per method,
the starts it left; the criteria: no start where an information method (3, 4, 5) never moved
while a raster method (1, 2) moved from it, every stuck mission with a reason in its summary,
no edge violation, no wheel on unknown ground. Rows depend on the inputs and seeds only.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import sys
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path
from typing import Any

from hil_sim.lab.ground_report import row_of
from hil_sim.lab.results import command_line, markdown_table, write_results

HELP = "starts boxed in by a close edge (ahead, diagonal, right): does every method move off them, safely?"
METHODS = ("1", "2", "3", "4", "5")
RASTER = ("1", "2")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--bearings", default="0,-45,-90", help="edge directions, deg from the heading (0: ahead)")
    p.add_argument("--distances", default="0.2,0.3,0.4,0.5", help="edge distances from the footprint, m (0.15-2)")
    p.add_argument("--seeds", default="0,1", help="terrain seeds")
    p.add_argument("--family", default="terrain", help="generated family spec, e.g. 'terrain?slope_deg=4'")
    p.add_argument("--methods", default="5,1", help="comma-separated subset of 1-5")
    p.add_argument("--steps", type=int, default=4, help="imaging steps after the panorama")
    p.add_argument("--jobs", type=int, default=2, help="missions run in parallel (processes)")
    p.add_argument("--out", type=Path, default=Path("out/close_edge"), help="output directory")
    p.add_argument("--near-edge", action="append", default=[], metavar="SPEC",
                   help="a scenario with its own edge (e.g. a real DEM, file:dem.npy?cell_m=0.03) whose start "
                        "is placed beside the edge at each bearing and distance (repeatable)")
    p.add_argument("--along", default="0", help="with --near-edge: positions along the edge, m from the point "
                                                "nearest the scenario's own start")
    p.add_argument("--raster-when-stuck", action="store_true",
                   help="run the raster methods (1, 2) only from the starts an information method stayed at "
                        "(the comparison the criterion needs; the table shows '-' elsewhere)")
    p.add_argument("--reuse", action="store_true",
                   help="take a mission whose run directory under --out already holds its summary.json "
                        "(an interrupted run goes on) instead of running it again")


def _one(scenario: str, method: str, steps: int, seed: int, out: str) -> dict[str, Any]:
    """One mission, afresh: a run directory left by an interrupted run is cleared, not refused."""
    from hil_sim.mission.mission_run import RunSpec, run_mission
    from hil_sim.world import load_scenario

    s = run_mission(RunSpec(scenario, method, steps, seed, transmit=False, out=Path(out)), mode="fresh")
    s["drawn"] = dict(load_scenario(scenario, seed).drawn)
    return s


def start_spec(family: str, bearing_deg: float, distance_m: float) -> str:
    """The scenario spec of one start: the family with the edge's bearing and distance set."""
    sep = "&" if "?" in family else "?"
    return f"{family}{sep}edge_bearing_deg={bearing_deg:g}&edge_distance_m={distance_m:g}"


def _reused(out: Path, spec: str, seed: int) -> dict[str, Any] | None:
    """The summary of a mission run before into ``out`` (None: none, or not readable)."""
    from hil_sim.world import load_scenario

    try:
        s = json.loads((out / "summary.json").read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(s, dict) or "steps" not in s:
        return None
    s["drawn"] = dict(load_scenario(spec, seed).drawn)
    return s


def _floats(text: str) -> list[float]:
    return [float(v) for v in text.split(",") if v.strip()]


def run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from hil_sim.world import load_scenario
    from hil_sim.world.config import load_scenario_config
    from hil_sim.world.scenarios import start_near_edge

    try:
        bearings, distances, along = _floats(args.bearings), _floats(args.distances), _floats(args.along)
        seeds = [int(v) for v in args.seeds.split(",") if v.strip()]
    except ValueError as err:
        print(f"safer-hil experiment close-edge: bad list ({err})", file=sys.stderr)
        return 2
    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    if (not methods or any(m not in METHODS for m in methods) or not bearings or not distances or not seeds
            or min(seeds) < 0 or args.steps < 1 or args.jobs < 1 or not all(0.15 <= d <= 2.0 for d in distances)
            or (args.near_edge and not along)):
        print("safer-hil experiment close-edge: bad arguments (methods from 1-5; lists not empty; seeds >= 0; "
              "distances 0.15-2 m; steps, jobs >= 1)", file=sys.stderr)
        return 2
    # (start label, scenario spec, bearing, distance, seed, measured gap or None, run directory name)
    Start = tuple[str, str, float, float, int, float | None, str]
    starts: list[Start] = [(args.family, start_spec(args.family, b, d), b, d, s, None, f"b{b:g}_d{d:g}_seed{s}")
              for s in seeds for b in bearings for d in distances]  # seed by seed: a cut-short run has whole seeds
    try:  # a bad DEM, family, bearing or distance: one line before any mission
        placed: list[Start] = []
        for k, base in enumerate(args.near_edge):
            for a in along:
                for b in bearings:
                    for d in distances:
                        near_spec, near_gap = start_near_edge(base, b, d, a)
                        placed.append((f"{base} at {a:g} m", near_spec, b, d, 0, round(near_gap, 3),
                                       f"near{k}_a{a:g}_b{b:g}_d{d:g}_seed0"))
        load_scenario(starts[0][1], seeds[0])
        for st in starts:
            load_scenario_config(st[1])
        starts = placed + starts  # the few starts beside a real edge first
    except ValueError as err:
        print(f"safer-hil experiment close-edge: {err}", file=sys.stderr)
        return 2
    args.out.mkdir(parents=True, exist_ok=True)
    rows: list[dict[str, Any]] = []
    failed: list[str] = []
    phases = [methods]
    if args.raster_when_stuck:  # the information methods first, then the raster ones where they stayed
        phases = [[m for m in methods if m not in RASTER], [m for m in methods if m in RASTER]]
    with (
        ProcessPoolExecutor(max_workers=args.jobs, mp_context=multiprocessing.get_context("spawn")) as pool,
        tqdm(total=len(starts) * len(methods), desc="close-edge", unit="mission") as bar,
    ):
        for phase, phase_methods in enumerate(phases):
            stayed = {(r["start"], r["bearing_deg"], r["distance_m"], r["seed"]) for r in rows if not r["moved"]}
            futs = {}
            for label, spec, b, d, seed, gap, name in starts:
                tags: dict[str, Any] = {"start": label, "bearing_deg": b, "distance_m": d, "gap_m": gap}
                for m in phase_methods:
                    if phase > 0 and (label, b, d, seed) not in stayed:
                        bar.update()  # every information method left this start: nothing to compare
                        continue
                    out = args.out / "runs" / f"{name}_m{m}"
                    done = _reused(out, spec, seed) if args.reuse else None
                    if done is not None:
                        rows.append({**row_of(done, spec, seed, args.steps), **tags})
                        bar.update()
                        continue
                    futs[pool.submit(_one, spec, m, args.steps, seed, str(out))] = (spec, seed, m, tags)
            for fut in as_completed(futs):
                spec, seed, m, tags = futs[fut]
                try:
                    rows.append({**row_of(fut.result(), spec, seed, args.steps), **tags})
                except Exception as exc:  # noqa: BLE001 - one failed mission is reported, the rest go on
                    failed.append(f"{spec} seed {seed} method {m}: {type(exc).__name__}: {exc}")
                bar.update()
    rows.sort(key=lambda r: (r["start"] != args.family, r["start"], r["bearing_deg"], r["distance_m"], r["seed"],
                             r["method"]))
    (args.out / "close_edge.json").write_text(json.dumps({"rows": rows, "failed": failed}, indent=1) + "\n")
    md = report(rows, failed, methods)
    (args.out / "close_edge.md").write_text(md)
    print(md)
    write_results("close-edge", command_line("close-edge"), md)
    return 1 if failed else 0


def why_stayed(row: dict[str, Any]) -> str:
    """The first reason in a mission's summary that it stayed: a step the planner found no move
    for, or (none such) the stations it could reach and left for views from where it stood."""
    if row["stay_reasons"]:
        return str(row["stay_reasons"][0])
    if int(row.get("reachable_max", 0)) > 0:
        return f"chose views from where it stood ({row['reachable_max']} stations reachable)"
    return ""


def report(rows: list[dict[str, Any]], failed: list[str], methods: list[str]) -> str:
    """The markdown report: one row per start, the summary per method, the criteria."""
    by_start: dict[tuple[str, float, float, int], dict[str, dict[str, Any]]] = {}
    for r in rows:
        by_start.setdefault((r.get("start", "terrain"), r["bearing_deg"], r["distance_m"], r["seed"]), {})[
            r["method"]] = r
    table = []
    for (label, b, d, seed), per in by_start.items():
        gap = next((r.get("gap_m") for r in per.values()), None)
        line: dict[str, Any] = {"start": label, "bearing deg": b, "edge m": d if gap is None else f"{d:g} ({gap:g})",
                                "seed": seed}
        for m in methods:
            line[f"M{m} moved m"] = round(float(per[m]["odometer_m"]), 2) if m in per else None
        reasons = [f"M{m}: {why_stayed(per[m])}" for m in methods
                   if m in per and not per[m]["moved"] and why_stayed(per[m])]
        line["why a method stayed"] = "; ".join(reasons)
        table.append(line)
    out = ["## Starts (odometer per method, m)", "", markdown_table(table), "", "## Per method", ""]
    summary = []
    for placed, m in ((p, m) for p in (False, True) for m in methods):
        kind = "placed beside an edge" if placed else "generated"
        rs = [r for r in rows if r["method"] == m and (r.get("gap_m") is not None) == placed]
        if not rs:
            continue
        summary.append({"starts": kind, "method": m, "missions": len(rs), "moved": sum(r["moved"] for r in rs),
                        "edge violations": sum(r["edge_violations"] for r in rs),
                        "wheels on unknown ground": sum(r["wheels_on_unknown_ground"] for r in rs),
                        "wheels off terrain": sum(r["wheels_off_terrain"] for r in rs)})
    out += [markdown_table(summary), "", "## Criteria (issue 30 item 1)", ""]
    frozen = [(k, m) for k, per in by_start.items() for m in methods
              if m not in RASTER and m in per and not per[m]["moved"]
              and any(per[x]["moved"] for x in RASTER if x in per)]
    silent = [(k, m) for k, per in by_start.items() for m, r in per.items()
              if m not in RASTER and not r["moved"] and not why_stayed(r)]
    viol = sum(r["edge_violations"] for r in rows)
    unknown = sum(r["wheels_on_unknown_ground"] for r in rows)
    met = {True: "met", False: "NOT MET"}
    if not rows:
        return "\n".join(out + ["- no mission finished: nothing to judge"] +
                         ["", "## Failed missions", ""] + [f"- {f}" for f in failed]) + "\n"
    out.append(f"- starts where an information method never moved while a raster method moved: **{len(frozen)}** "
               f"(target 0) {met[not frozen]}"
               + "".join(f"\n  - {k[0]}, bearing {k[1]:g}, edge {k[2]:g} m, seed {k[3]}: method {m}"
                         for k, m in frozen))
    out.append(f"- information-method missions that never moved without a reason in their summary: "
               f"**{len(silent)}** (target 0) {met[not silent]}")
    out.append(f"- edge violations: **{viol}** (target 0) {met[viol == 0]}")
    out.append(f"- frames moving with a wheel on unknown ground: **{unknown}** (target 0) {met[unknown == 0]}")
    if failed:
        out += ["", "## Failed missions", ""] + [f"- {f}" for f in failed]
    return "\n".join(out) + "\n"
