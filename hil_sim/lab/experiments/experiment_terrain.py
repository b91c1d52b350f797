"""``safer-hil experiment terrain``: map quality on tilted ground (issue 13: attitude and
registration, docs/algorithm.md §5.1).

For every scenario, seed and slope it runs one full lockstep mission (``hil_sim.mission.mission_run``)
and prints, per mission and as medians and worst cases: the true start attitude, the map's
RMS error against truth over mapped cells, the tilt of the plane fitted to map minus truth,
the station seams (mean height difference between overlapping cells mapped from different
stations, ``hil_sim.lab.terrain_eval``), the fraction of mapped cells within 2 sigma, the views
registered / not registered, the stations and the edge violations.

A slope is made through the ``file:`` scenario: the scenario's ground at that seed, plus a
plane of ``--slopes`` degrees falling toward ``--azimuth-deg`` (0: +x; -90: -y, toward the
built-in scenes' cliff), zero at the rover start, written as ``.npy`` under ``DIR/dems``.
Slope 0 runs the scenario itself. Any ``file:`` or generator spec can be given directly.
``--baseline`` also runs each mission without the attitude sensor and registration (the
level-rover pose chain of before issue 13) for comparison.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import sys
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path
from typing import Any

import numpy as np

from hil_sim.lab.results import command_line, write_results

HELP = "map error, tilt, station seams and 2-sigma calibration on tilted terrain (issue 13)"
COLUMNS = ("rms_m", "tilt_err_deg", "seam_m", "within_2sigma")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--scenario", action="append",
                   help="scenario spec: mars, cliff, lab, file:PATH?... (repeatable; default: mars)")
    p.add_argument("--seeds", default="0", help="comma-separated seeds")
    p.add_argument("--slopes", default="0", help="comma-separated slopes in degrees added to the ground")
    p.add_argument("--azimuth-deg", type=float, default=-120.0, help="direction the added slope falls toward")
    p.add_argument("--method", default="5", choices=("1", "2", "3", "4", "5", "oracle"))
    p.add_argument("--steps", type=int, default=6, help="imaging steps after the panorama")
    p.add_argument("--jobs", type=int, default=1, help="missions run in parallel (processes)")
    p.add_argument("--baseline", action="store_true", help="also run without attitude sensor and registration")
    p.add_argument("--out", type=Path, default=Path("out/terrain"), help="output directory")


def tilted_spec(scenario: str, seed: int, slope_deg: float, azimuth_deg: float, out: Path) -> str:
    """A ``file:`` spec of the scenario's ground (at ``seed``) tilted by ``slope_deg``."""
    from hil_sim.world import load_scenario

    w = load_scenario(scenario, seed=seed)
    ny, nx = w.shape
    x = w.x0 + (np.arange(nx) + 0.5) * w.cell_m
    y = w.y0 + (np.arange(ny) + 0.5) * w.cell_m
    x0, y0, _ = w.rover_start
    g = math.tan(math.radians(slope_deg))
    az = math.radians(azimuth_deg)
    plane = -g * (math.cos(az) * (x[None, :] - x0) + math.sin(az) * (y[:, None] - y0))
    dem = np.asarray(w.ground, np.float64) + plane
    dem -= float(w.ground_at(x0, y0))
    out.mkdir(parents=True, exist_ok=True)
    name = f"{scenario.replace(':', '_').replace('/', '_').replace('?', '_')}_s{seed}_slope{slope_deg:g}.npy"
    np.save(out / name, dem.astype(np.float32))
    cb = w.config.cliffbot
    return (f"file:{out / name}?x_min_m={w.x0}&y_min_m={w.y0}&cell_m={w.cell_m}&plateau_tol_m=0.5"
            f"&rover_start.x_m={x0}&rover_start.y_m={y0}&cliffbot.x_m={cb.x_m}&cliffbot.y_m={cb.y_m}")


def baseline_config(out: Path) -> str:
    """The flight config with the attitude sensor off, no registration, and the attitude
    taken as level with no sigma of its own (the pose chain before issue 13)."""
    from fsw.settings import DEFAULT_CONFIG

    text = DEFAULT_CONFIG.read_text()
    text = text.replace("imu = true ", "imu = false").replace("enabled = true\nref_max", "enabled = false\nref_max")
    text = text.replace("unknown_attitude_sigma_deg = 5.0", "unknown_attitude_sigma_deg = 0.1")
    path = out / "fsw_baseline.toml"
    out.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return str(path)


def _one(spec: str, method: str, steps: int, seed: int, config: str, out: str) -> dict[str, Any]:
    from hil_sim.mission.mission_run import RunSpec, run_mission

    s = run_mission(RunSpec(spec, method, steps, seed, config=config, transmit=False, out=Path(out)))
    s["_dir"] = out
    return s


def row(label: str, s: dict[str, Any]) -> dict[str, Any]:
    q, reg = s["map_quality"], s.get("registration", [])
    return {"_dir": s.get("_dir", ""),
        "run": label, "start_roll_deg": s["start_attitude_deg"][0], "start_pitch_deg": s["start_attitude_deg"][1],
        "cells": q["cells"], **{k: q[k] for k in COLUMNS}, "seam_max_m": q["seam_max_m"],
        "stations": q["stations"], "registered": sum(r["status"] == "registered" for r in reg),
        "unregistered": sum(r["status"] == "unregistered" for r in reg),
        "edge_violations": s["edge_violations"], "end": s["end_reason"],
    }


def _fmt(v: Any) -> str:
    if v is None:
        return "-"
    if isinstance(v, float):
        return f"{v:.4g}"
    return str(v)


def run(args: argparse.Namespace) -> int:
    try:
        seeds = [int(v) for v in args.seeds.split(",") if v.strip()]
        slopes = [float(v) for v in args.slopes.split(",") if v.strip()]
    except ValueError as exc:
        print(f"safer-hil experiment terrain: bad --seeds/--slopes ({exc})", file=sys.stderr)
        return 2
    if not seeds or not slopes or args.steps < 1 or args.jobs < 1 or any(not 0 <= s <= 30 for s in slopes):
        print("safer-hil experiment terrain: need seeds, slopes in 0..30 deg, steps and jobs >= 1", file=sys.stderr)
        return 2
    from fsw.settings import DEFAULT_CONFIG
    from hil_sim.world import load_scenario

    scenarios = args.scenario or ["mars"]
    args.out.mkdir(parents=True, exist_ok=True)
    frozen = args.out / "fsw.toml"  # the flight config as it was at the start, for every mission
    frozen.write_text(DEFAULT_CONFIG.read_text())
    configs = {"new": str(frozen)}
    if args.baseline:
        configs["before"] = baseline_config(args.out)
    runs = []
    try:
        for sc in scenarios:
            load_scenario(sc, seed=seeds[0])  # a bad spec: one line and exit 2, before any mission
            for seed in seeds:
                for slope in slopes:
                    spec = sc if slope == 0 else tilted_spec(sc, seed, slope, args.azimuth_deg, args.out / "dems")
                    for tag, cfg in configs.items():
                        label = f"{sc}|slope{slope:g}|seed{seed}|{tag}"
                        runs.append((label, spec, seed, cfg, label.replace("|", "_").replace(":", "_")))
    except ValueError as exc:  # ScenarioError, ConfigError: bad spec or DEM
        print(f"safer-hil experiment terrain: {exc}", file=sys.stderr)
        return 2
    rows: list[dict[str, Any]] = []
    with ProcessPoolExecutor(max_workers=args.jobs) as pool:
        futs = {pool.submit(_one, spec, args.method, args.steps, seed, cfg, str(args.out / "runs" / d)): label
                for label, spec, seed, cfg, d in runs}
        for fut in as_completed(futs):
            label = futs[fut]
            try:
                rows.append(row(label, fut.result()))
            except Exception as exc:  # noqa: BLE001 - one failed mission is reported, the rest go on
                print(f"{label}: FAILED {type(exc).__name__}: {exc}", file=sys.stderr)
                continue
            print("  ".join(f"{k}={_fmt(v)}" for k, v in rows[-1].items() if k != "_dir"), flush=True)
    rows.sort(key=lambda r: r["run"])
    dirs = {r["run"]: r.pop("_dir") for r in rows}
    _report(rows, args.out)
    if args.baseline:
        error_figure(rows, dirs, args.out / "terrain_error_maps.png")
    if rows:
        write_results("terrain", command_line("terrain"), (args.out / "terrain.md").read_text(),
                      [args.out / "terrain_error_maps.png"])
    return 0 if len(rows) == len(runs) else 1


def _report(rows: list[dict[str, Any]], out: Path) -> None:
    if not rows:
        return
    out.mkdir(parents=True, exist_ok=True)
    with (out / "terrain.csv").open("w", newline="") as f:
        wr = csv.DictWriter(f, fieldnames=list(rows[0]))
        wr.writeheader()
        wr.writerows(rows)
    lines = ["| " + " | ".join(rows[0]) + " |", "|" + "---|" * len(rows[0])]
    lines += ["| " + " | ".join(_fmt(v) for v in r.values()) + " |" for r in rows]
    for tag in sorted({r["run"].rsplit("|", 1)[1] for r in rows}):
        sel = [r for r in rows if r["run"].endswith("|" + tag)]
        lines.append(f"\n**{tag}** ({len(sel)} missions): " + ", ".join(
            f"{k} median {_fmt(_stat(sel, k, np.median))} worst {_fmt(_stat(sel, k, _worst(k)))}" for k in COLUMNS))
    text = "\n".join(lines) + "\n"
    (out / "terrain.md").write_text(text)
    (out / "terrain.json").write_text(json.dumps(rows, indent=1) + "\n")
    print(text)


def error_figure(rows: list[dict[str, Any]], dirs: dict[str, str], path: Path) -> None:
    """PNG: map minus truth before (level pose chain) and after (attitude + registration),
    one row per mission that ran both, on one colour scale."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    by = {r["run"]: r for r in rows}
    pairs = [(k.rsplit("|", 1)[0]) for k in by if k.endswith("|before") and k[:-7] + "|new" in by]
    if not pairs:
        return
    fig, axes = plt.subplots(len(pairs), 2, figsize=(10, 4.4 * len(pairs)), squeeze=False, constrained_layout=True)
    for i, base in enumerate(pairs):
        for j, tag in enumerate(("before", "new")):
            r, ax = by[f"{base}|{tag}"], axes[i, j]
            err = np.load(Path(dirs[f"{base}|{tag}"]) / "map_error.npy")
            im = ax.imshow(err, origin="lower", cmap="coolwarm", vmin=-0.1, vmax=0.1)
            ax.set_title(f"{base} {'before: level rover' if tag == 'before' else 'attitude + registration'}\n"
                         f"RMS {100 * r['rms_m']:.2f} cm, tilt {r['tilt_err_deg']:.2f} deg, "
                         f"seam {_fmt(None if r['seam_m'] is None else 100 * r['seam_m'])} cm, "
                         f"2-sigma {100 * r['within_2sigma']:.1f} %", fontsize=9)
            ax.set_xticks([])
            ax.set_yticks([])
        fig.colorbar(im, ax=axes[i, :].tolist(), shrink=0.8, label="map - truth (m)")
    fig.savefig(path, dpi=80)
    plt.close(fig)


def _worst(key: str) -> Any:
    return np.min if key == "within_2sigma" else np.max


def _stat(rows: list[dict[str, Any]], key: str, fn: Any) -> float | None:
    vals = [r[key] for r in rows if r[key] is not None]
    return float(fn(vals)) if vals else None
