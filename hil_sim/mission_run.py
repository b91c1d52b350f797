"""One lockstep mission on the bench, and its summary (``safer-hil run``, ``make demo``).

The flight executive with its full schedule (config/fsw.toml) runs against the hardware rig
in lockstep (``hil_sim.bench.LockstepBench``); the radio runs through the seeded channel
model to the Cliff-bot receiver. The runner only watches: it never steers the flight code.
It records, per imaging step, what the mission task recorded, and from the world truth the
map error and any wheel over the drop (an edge violation).

``summary.json`` schema (stable; docs/experiments.md): ``schema`` (1), ``scenario``,
``method``, ``seed``, ``steps`` (list of ``{step, mapped_cells, expected_new_cells,
obtained_new_cells, pose{x,y,yaw,pan,tilt,lift}, wall_s, sim_s}``), ``map_rmse_m``,
``edge_violations``, ``geofence_refusals``, ``slips``, ``overruns``, ``task_max_ms``
({task: ms}, plus ``frame``: the longest frame, and ``slack_slice``, ``slack_slice.<task>``:
the longest slack-job slice), ``map_error_tilt_deg`` and ``map_rmse_detilted_m`` (the plane
fitted to map minus truth over mapped cells: its tilt, and the RMS error around it),
``wheels_off_terrain`` (rig steps with a wheel off the world's terrain, a bench fault),
``wheels_on_unknown_ground`` (frames the rover moved with a true wheel position on ground the
flight geofence did not know), ``bench_faults`` (``{t_s, kind, detail}``), ``odometer_m``,
``reachable_stations`` (per step boundary: edge-path stations the geofence allowed from the
rover's estimated pose, ``hil_sim.ground_watch``), ``looks`` (views of unknown ground before
a move), ``stays`` (steps whose view was taken without the planned move, and why),
``steps_unused`` and ``steps_unused_reason``,
``end_reason``, ``final_state``, ``mapped_cells``, ``frames``, ``sim_s``,
``wall_s``, ``cliffbot`` (the Cliff-bot's report, or null), ``files``. Wall-clock fields:
``wall_s`` (top level and per step), ``task_max_ms``, and ``slips`` and ``overruns`` (both
compare measured execution time with the period and budgets); everything else is a
function of the inputs and the seed.
"""

from __future__ import annotations

import dataclasses
import json
import shutil
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from fsw.core.geometry import MapGrid
from fsw.drivers.map_store import MapStore
from fsw.settings import DEFAULT_CONFIG, FswConfig, load_settings
from hil_sim.ground_watch import reachable_stations, wheels_on_unknown

WALL_CLOCK_FIELDS = ("wall_s", "task_max_ms", "slips", "overruns")


@dataclass(frozen=True)
class RunSpec:
    scenario: str = "lab"
    method: str = "5"
    steps: int = 20
    seed: int = 0
    config: str = str(DEFAULT_CONFIG)
    transmit: bool = True
    out: Path | None = None


def mission_config(spec: RunSpec, world: Any) -> FswConfig:
    """The flight configuration of the run: the file, with the scenario's map and the method."""
    cfg = load_settings(spec.config)
    mav = cfg.mavlink
    if spec.out is not None:
        mav = dataclasses.replace(mav, tlog_path=str(spec.out / "fsw.tlog"))
    ckpt = cfg.checkpoint
    if spec.out is not None:
        ckpt = dataclasses.replace(ckpt, directory=str(spec.out / "checkpoints"))
    return dataclasses.replace(
        cfg,
        map=world.map_grid,
        mavlink=mav,
        checkpoint=ckpt,
        mission=dataclasses.replace(cfg.mission, method=spec.method, transmit=spec.transmit, auto_start=True),
        nbv=dataclasses.replace(cfg.nbv, max_steps=spec.steps),
    )


def run_mission(
    spec: RunSpec, progress: Callable[[int, int, str], None] | None = None, max_sim_s: float | None = None
) -> dict[str, Any]:
    """Run one mission to DONE (or SAFE, or the time limit) and return its summary."""
    from hil_sim.bench import LockstepBench
    from hil_sim.cliffbot_receiver import Cliffbot
    from hil_sim.radio_channel import ChannelPort, RadioChannel, RadioChannelConfig
    from hil_sim.world import load_scenario

    t_wall = time.perf_counter()
    world = load_scenario(spec.scenario, seed=spec.seed)
    cfg = mission_config(spec, world)
    grid = MapGrid.from_config(cfg.map)
    truth = world.truth_on_grid(grid)
    oracle = {"z": truth, "textured": ~world.textureless_on_grid(grid)}
    channel = RadioChannel(RadioChannelConfig(), seed=spec.seed)
    clock_box: list[Callable[[], float]] = []

    def now() -> float:
        return clock_box[0]() if clock_box else 0.0

    port_flight = ChannelPort(channel, "a", now)
    resources: dict[str, Any] = {"radio_port": port_flight, "oracle_truth": oracle}
    if spec.out is not None:
        spec.out.mkdir(parents=True, exist_ok=True)
        shutil.rmtree(spec.out / "checkpoints", ignore_errors=True)  # a new mission starts a new map
        resources["map_store"] = MapStore(cfg.checkpoint, cfg.fusion)
    with LockstepBench(cfg, world, seed=spec.seed, quiet=True, resources=resources) as bench:
        clock_box.append(bench.clock.now)
        cliffbot = Cliffbot(cfg.link, ChannelPort(channel, "b", now), out_dir=spec.out)
        mission = bench.exe.tasks["mission"]
        perception = bench.exe.tasks["perception"]
        limit_s = max_sim_s if max_sim_s is not None else 120.0 + 90.0 * (spec.steps + 1) + 1200.0
        violations = unknown_frames = 0
        reachable: list[int] = []  # stations the geofence allowed, at each step boundary
        last_step = -1
        bench.exe.freeze_heap()  # as the flight start-up does (safer-fsw run)
        try:
            while bench.clock.now() < limit_s:
                odo = bench.rig.rover.odometer_m
                bench.run(1)
                unknown_frames += wheels_on_unknown(bench.rig, mission, odo)
                if mission.state == "TRANSMIT" and 1 not in cliffbot.originals:
                    cliffbot.originals[1] = perception.map.z.astype(np.float32)
                cliffbot.step(bench.clock.now())
                violations += _wheels_over_drop(bench.rig, world, cfg)
                if mission.step != last_step:
                    last_step = mission.step
                    reachable.append(reachable_stations(mission, cfg))
                    if progress is not None:
                        progress(mission.step, spec.steps, mission.state)
                if mission.state in ("DONE", "SAFE"):
                    break
        finally:
            bench.exe.thaw_heap()
        exe = bench.exe
        if "mavlink" in exe.tasks:
            exe.tasks["mavlink"].close()  # flush and close the .tlog
        emap = perception.map
        mapped = emap.mapped & np.isfinite(truth)
        rmse = float(np.sqrt(np.mean((emap.z[mapped] - truth[mapped]) ** 2))) if mapped.any() else None
        tilt_deg, rmse_plane = error_plane(grid, emap.z - truth, mapped)
        summary: dict[str, Any] = {
            "schema": 1,
            "scenario": spec.scenario,
            "method": spec.method,
            "seed": spec.seed,
            "steps": [dataclasses.asdict(r) for r in mission.records],
            "map_rmse_m": rmse,
            "map_error_tilt_deg": tilt_deg,
            "map_rmse_detilted_m": rmse_plane,
            "edge_violations": violations,
            "geofence_refusals": mission.edge_violations,
            "wheels_off_terrain": bench.rig.wheels_off_terrain_steps,
            "wheels_on_unknown_ground": unknown_frames,
            "bench_faults": bench.rig.faults_seen,
            "odometer_m": round(bench.rig.rover.odometer_m, 3),
            "reachable_stations": reachable,
            "looks": mission.looks,
            "stays": mission.stays,
            "steps_unused": max(0, spec.steps - (len(mission.records) - 1)),
            "steps_unused_reason": None if len(mission.records) - 1 >= spec.steps else (
                mission.end or mission.safe_reason or f"stopped in {mission.state}"),
            "slips": exe.slips,
            "overruns": sum(t.overruns for t in exe.tasks.values()),
            "task_max_ms": task_max_ms(exe),
            "end_reason": mission.end,
            "safe_reason": mission.safe_reason,
            "final_state": mission.state,
            "mapped_cells": int(emap.mapped.sum()),
            "frames": exe.frame,
            "sim_s": round(bench.clock.now(), 3),
            "wall_s": round(time.perf_counter() - t_wall, 3),
            "cliffbot": _cliffbot_report(cliffbot, spec.out),
            "files": {},
        }
        summary = json.loads(json.dumps(summary))  # exactly what summary.json holds
        if spec.out is not None:
            summary["files"] = write_outputs(spec.out, summary, emap, truth, grid)
    return summary


def error_plane(grid: MapGrid, err: Any, mapped: Any) -> tuple[float | None, float | None]:
    """The plane fitted (least squares) to the map's error over mapped cells: its tilt (deg,
    the part of the error a tilted map explains) and the RMS error left around it (m)."""
    if int(mapped.sum()) < 10:
        return None, None
    xs, ys = grid.centers()
    a = np.column_stack([xs[mapped], ys[mapped], np.ones(int(mapped.sum()))])
    coef, *_ = np.linalg.lstsq(a, err[mapped], rcond=None)
    resid = err[mapped] - a @ coef
    return (round(float(np.degrees(np.arctan(np.hypot(coef[0], coef[1])))), 4),
            round(float(np.sqrt(np.mean(resid**2))), 5))


def task_max_ms(exe: Any) -> dict[str, float]:
    """Max execution time per task and rate group, plus the longest frame (``frame``:
    foreground and slack) and the longest slack-job slice overall (``slack_slice``) and per
    submitting task (``slack_slice.<task>``), ms."""
    out = {n: round(t.max_s * 1e3, 3) for n, t in exe.tasks.items()}
    out["frame"] = round(exe.frame_max_s * 1e3, 3)
    out["slack_slice"] = round(exe.jobs.max_slice_s * 1e3, 3)
    for owner, s in sorted(exe.jobs.max_slice_by_owner.items()):
        out[f"slack_slice.{owner}"] = round(s * 1e3, 3)
    return out


def _cliffbot_report(cliffbot: Any, out: Path | None) -> dict[str, Any] | None:
    """The Cliff-bot's last report, its figure named relative to the run directory."""
    if not cliffbot.reports:
        return None
    rep = dataclasses.asdict(cliffbot.reports[-1])
    if rep.get("png") and out is not None:
        rep["png"] = Path(rep["png"]).name
    return rep


def _wheels_over_drop(rig: Any, world: Any, cfg: FswConfig) -> int:
    """1 if any wheel's contact point is over the drop (true terrain below the nearest
    plateau ground by more than the edge step: ``World.over_drop``)."""
    xs, ys = rig.rover.world_wheel_xy()
    return int(bool(world.over_drop(np.asarray(xs), np.asarray(ys), cfg.edge.step_m).any()))


def write_outputs(out: Path, summary: dict[str, Any], emap: Any, truth: Any, grid: MapGrid) -> dict[str, str]:
    """summary.json and the PNGs: map, variance, error, coverage over steps."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    files = {"summary": "summary.json", "map": "map.png", "coverage": "coverage.png"}
    ext = grid.extent
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.6), constrained_layout=True)
    for ax, data, title, cmap in (
        (axes[0], emap.z, "elevation (m)", "terrain"),
        (axes[1], np.sqrt(emap.var), "sigma (m)", "magma"),
        (axes[2], emap.z - truth, "error vs truth (m)", "coolwarm"),
    ):
        kw = {"vmin": -0.05, "vmax": 0.05} if "error" in title else {}
        if "sigma" in title:
            kw = {"vmin": 0.0, "vmax": 0.03}
        im = ax.imshow(np.where(emap.mapped, data, np.nan), origin="lower", extent=ext, cmap=cmap, **kw)
        ax.set_title(title)
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
        fig.colorbar(im, ax=ax, shrink=0.8)
    for r in summary["steps"]:
        axes[0].plot(r["pose"]["x"], r["pose"]["y"], "k^", ms=5)
    fig.suptitle(
        f"{summary['scenario']} method {summary['method']} seed {summary['seed']}: "
        f"{summary['mapped_cells']} cells mapped"
    )
    fig.savefig(out / files["map"], dpi=90)
    plt.close(fig)
    fig, ax = plt.subplots(figsize=(6, 4), constrained_layout=True)
    st = summary["steps"]
    ax.plot([r["step"] for r in st], [r["mapped_cells"] for r in st], "o-", label="mapped cells")
    ax.bar([r["step"] for r in st], [r["obtained_new_cells"] for r in st], alpha=0.3, label="obtained new")
    ax.plot([r["step"] for r in st], [r["expected_new_cells"] for r in st], "x--", label="expected new (H)")
    ax.set_xlabel("stereo imaging step")
    ax.set_ylabel("cells")
    ax.legend()
    ax.grid(alpha=0.3)
    fig.savefig(out / files["coverage"], dpi=90)
    plt.close(fig)
    summary["files"] = files
    (out / files["summary"]).write_text(json.dumps(summary, indent=2) + "\n")
    return files


def strip_wall_clock(summary: dict[str, Any]) -> dict[str, Any]:
    """The summary without its wall-clock fields (for determinism checks)."""
    out = {k: v for k, v in summary.items() if k not in WALL_CLOCK_FIELDS}
    out["steps"] = [{k: v for k, v in s.items() if k not in WALL_CLOCK_FIELDS} for s in summary["steps"]]
    return out
