"""``safer-hil experiment ground``: missions on ground nobody tuned the flight software to
(issue 13, "Done when"; docs/experiments.md).

Runs ``--terrains`` seeded members of a generated scenario family (default ``terrain``,
hil_sim/world/terrain.py) and any ``--extra`` scenarios (e.g. a real DEM through ``file:``)
for each method, as full lockstep missions (``hil_sim.mission.mission_run``), ``--jobs`` at a time in
a process pool, and writes ``ground.csv`` / ``ground.json`` (one row per mission) and
``ground.md``: the table per mission (moved?, reachable stations, steps used, why steps went
unused, edge violations, wheels off the world, wheels on unknown ground, mapped cells, map RMS
error against truth, the plane tilt fitted to the error and the RMS around it, the station
seams and the fraction of mapped cells within 2 sigma, ``hil_sim.lab.terrain_eval``) and the
summary (medians and worst cases, and the issue's criteria checked). ``--camera ideal`` runs
the ideal pinhole pair (the map error without the calibrated cameras' share).

The rows are a function of the inputs and seeds (no wall-clock fields), so the table can be
re-run after other changes (e.g. rover attitude) and compared line by line.
"""

from __future__ import annotations

import argparse
import csv
import json
import multiprocessing
import sys
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path
from typing import Any

from hil_sim.lab.ground_report import COLUMNS, report_markdown, row_of
from hil_sim.lab.results import command_line, write_results

HELP = "missions on generated sloped, rocky terrains (and real DEMs): does the rover move, safely?"
METHODS = ("1", "2", "3", "4", "5", "oracle")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--family", default="terrain",
                   help="scenario spec of the generated family, seeded per terrain "
                        "(default terrain; e.g. 'terrain?slope_deg=10&k=0.16')")
    p.add_argument("--terrains", type=int, default=20, help="seeds first..first+N-1 of the family")
    p.add_argument("--first-seed", type=int, default=0, help="first terrain seed")
    p.add_argument("--extra", action="append", default=[], metavar="SPEC",
                   help="another scenario to run with seed 0 (repeatable), e.g. file:dem.npy")
    p.add_argument("--methods", default="5,1", help="comma-separated subset of 1-5, oracle")
    p.add_argument("--steps", type=int, default=10, help="imaging steps after the panorama")
    p.add_argument("--camera", default="config", choices=("config", "ideal", "raw"),
                   help="config: the calibrated cameras; ideal: the ideal pinhole pair (map error "
                        "without calibration effects)")
    p.add_argument("--jobs", type=int, default=2, help="missions run in parallel (processes)")
    p.add_argument("--out", type=Path, default=Path("out/ground"), help="output directory")
    p.add_argument("--reuse", action="store_true",
                   help="take a mission whose run directory under --out already holds the summary of the "
                        "same scenario, seed, method, camera and steps (an interrupted run goes on) instead "
                        "of running it again")


def _one(scenario: str, method: str, steps: int, seed: int, out: str, camera: str) -> dict[str, Any]:
    from hil_sim.mission.mission_run import RunSpec, run_mission
    from hil_sim.world import load_scenario

    s = run_mission(RunSpec(scenario, method, steps, seed, transmit=False, out=Path(out), camera=camera))
    s["drawn"] = dict(load_scenario(scenario, seed).drawn)  # the terrain's slope, edge gap
    return s


def _reused(out: Path, spec: str, method: str, steps: int, seed: int, camera: str) -> dict[str, Any] | None:
    """The summary a run of the same mission left in ``out`` (None: none, unreadable or another mission)."""
    from hil_sim.world import load_scenario

    try:
        s = json.loads((out / "summary.json").read_text())
    except (OSError, ValueError):
        return None
    same = (isinstance(s, dict) and s.get("scenario") == spec and str(s.get("method")) == method
            and s.get("seed") == seed and s.get("camera") == camera
            and isinstance(s.get("steps"), list)
            and len(s["steps"]) - 1 + int(s.get("steps_unused", 0)) == steps)
    if not same:
        return None
    s["drawn"] = dict(load_scenario(spec, seed).drawn)
    return s


def run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from hil_sim.world import load_scenario

    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    bad = [m for m in methods if m not in METHODS]
    if bad or args.terrains < 0 or args.first_seed < 0 or args.steps < 1 or args.jobs < 1:
        why = f"unknown methods {bad}" if bad else "terrains/first-seed >= 0, steps/jobs >= 1"
        print(f"safer-hil experiment ground: bad arguments ({why})", file=sys.stderr)
        return 2
    scenarios = [(spec, 0) for spec in args.extra]
    scenarios += [(args.family, args.first_seed + k) for k in range(args.terrains)]
    if not scenarios:
        print("safer-hil experiment ground: nothing to run (--terrains 0 and no --extra)", file=sys.stderr)
        return 2
    for spec, seed in {(s, d) for s, d in scenarios[:len(args.extra) + 1]}:
        try:  # refuse a bad spec or DEM with one line before starting the pool
            load_scenario(spec, seed)
        except ValueError as err:
            print(f"safer-hil experiment ground: {spec}: {err}", file=sys.stderr)
            return 2
    args.out.mkdir(parents=True, exist_ok=True)
    runs = [(spec, seed, m) for spec, seed in scenarios for m in methods]
    rows: list[dict[str, Any]] = []
    failed: list[str] = []
    with (
        # spawn, not fork: the parent has loaded worlds (thread pools, locks held by other
        # threads); a forked worker could inherit a held lock and wait forever (seen: both
        # workers asleep on a futex, 0 s CPU, for 8 min).
        ProcessPoolExecutor(max_workers=args.jobs, mp_context=multiprocessing.get_context("spawn")) as pool,
        tqdm(total=len(runs), desc="ground", unit="mission") as bar,
    ):
        futs = {}
        for i, (spec, seed, m) in enumerate(runs):
            out = args.out / "runs" / f"{i:03d}_m{m}_seed{seed}"
            done = _reused(out, spec, m, args.steps, seed, args.camera) if args.reuse else None
            if done is not None:
                rows.append(row_of(done, spec, seed, args.steps))
                bar.update()
                continue
            futs[pool.submit(_one, spec, m, args.steps, seed, str(out), args.camera)] = (spec, seed, m)
        for fut in as_completed(futs):
            spec, seed, m = futs[fut]
            try:
                rows.append(row_of(fut.result(), spec, seed, args.steps))
            except Exception as exc:  # noqa: BLE001 - one failed mission is reported, the rest go on
                failed.append(f"{spec} seed {seed} method {m}: {type(exc).__name__}: {exc}")
            bar.update()
    rows.sort(key=lambda r: (r["scenario"] != args.family, r["scenario"], r["seed"], r["method"]))
    with (args.out / "ground.csv").open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=COLUMNS)
        w.writeheader()
        w.writerows({k: r[k] for k in COLUMNS} for r in rows)
    (args.out / "ground.json").write_text(json.dumps({"rows": rows, "failed": failed}, indent=1) + "\n")
    md = report_markdown(rows, failed, vars(args))
    (args.out / "ground.md").write_text(md)
    print(md)
    write_results("ground", command_line("ground"), md)
    return 1 if failed else 0
