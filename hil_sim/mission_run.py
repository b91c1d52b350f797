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
the longest slack-job slice),
``end_reason``, ``final_state``, ``mapped_cells``, ``frames``, ``sim_s``, ``calib_2sigma`` (fraction
of mapped cells within 2 sigma of the truth, ALGORITHM.md §4), ``safe_entries``, ``safe_recoveries``
(SAFE left for the mission again), ``off_map`` (frames with a wheel off the world's truth grid),
``faults`` (the injected :class:`hil_sim.faults.FaultSpec` rows),
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
from fsw.drivers.resources import OracleTruth, Resources
from fsw.settings import DEFAULT_CONFIG, FswConfig, load_settings
from hil_sim.faults import FaultSpec

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
    faults: tuple[FaultSpec, ...] = ()  # injected through the bench's fault backdoor
    safe_recover_s: float | None = None  # override of mission.safe_recover_s (None: the file's)


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
        mission=dataclasses.replace(
            cfg.mission,
            method=spec.method,
            transmit=spec.transmit,
            auto_start=True,
            safe_recover_s=cfg.mission.safe_recover_s if spec.safe_recover_s is None else spec.safe_recover_s,
        ),
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
    oracle = OracleTruth(z_m=truth, textured=~world.textureless_on_grid(grid))
    channel = RadioChannel(RadioChannelConfig(), seed=spec.seed)
    clock_box: list[Callable[[], float]] = []

    def now() -> float:
        return clock_box[0]() if clock_box else 0.0

    port_flight = ChannelPort(channel, "a", now)
    resources = Resources(radio_port=port_flight, oracle_truth=oracle)
    if spec.out is not None:
        spec.out.mkdir(parents=True, exist_ok=True)
        shutil.rmtree(spec.out / "checkpoints", ignore_errors=True)  # a new mission starts a new map
        resources.map_store = MapStore(cfg.checkpoint, cfg.fusion)
    with LockstepBench(cfg, world, seed=spec.seed, quiet=True, resources=resources, faults=spec.faults) as bench:
        clock_box.append(bench.clock.now)
        cliffbot = Cliffbot(cfg.link, ChannelPort(channel, "b", now), out_dir=spec.out)
        mission = bench.exe.tasks["mission"]
        perception = bench.exe.tasks["perception"]
        limit_s = max_sim_s if max_sim_s is not None else 120.0 + 90.0 * (spec.steps + 1) + 1200.0
        violations = off_map = recoveries = 0
        last_step = -1
        was_safe = False
        bench.exe.freeze_heap()  # as the flight start-up does (safer-fsw run)
        try:
            while bench.clock.now() < limit_s:
                bench.run(1)
                if mission.state == "TRANSMIT" and 1 not in cliffbot.originals:
                    cliffbot.originals[1] = perception.map.z.astype(np.float32)
                cliffbot.step(bench.clock.now())
                over_drop, off_world = _wheel_checks(bench.rig, world, cfg)
                violations += over_drop
                off_map += off_world
                recoveries += int(was_safe and mission.state != "SAFE")
                was_safe = mission.state == "SAFE"
                if progress is not None and mission.step != last_step:
                    last_step = mission.step
                    progress(mission.step, spec.steps, mission.state)
                if mission.state == "DONE" or (mission.state == "SAFE" and cfg.mission.safe_recover_s <= 0):
                    break
        finally:
            bench.exe.thaw_heap()
        exe = bench.exe
        if "mavlink" in exe.tasks:
            exe.tasks["mavlink"].close()  # flush and close the .tlog
        emap = perception.map
        mapped = emap.mapped & np.isfinite(truth)
        rmse = float(np.sqrt(np.mean((emap.z[mapped] - truth[mapped]) ** 2))) if mapped.any() else None
        within = np.abs(emap.z[mapped] - truth[mapped]) <= 2.0 * np.sqrt(emap.var[mapped])
        calib = float(within.mean()) if mapped.any() else None
        summary: dict[str, Any] = {
            "schema": 1,
            "scenario": spec.scenario,
            "method": spec.method,
            "seed": spec.seed,
            "steps": [dataclasses.asdict(r) for r in mission.records],
            "map_rmse_m": rmse,
            "calib_2sigma": calib,
            "edge_violations": violations,
            "geofence_refusals": mission.edge_violations,
            "slips": exe.slips,
            "overruns": sum(t.overruns for t in exe.tasks.values()),
            "task_max_ms": task_max_ms(exe),
            "end_reason": mission.end,
            "safe_reason": mission.safe_reason,
            "safe_entries": mission.safe_entries,
            "safe_recoveries": recoveries,
            "off_map": off_map,
            "faults": [dataclasses.asdict(f) for f in spec.faults],
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


def _wheel_checks(rig: Any, world: Any, cfg: FswConfig) -> tuple[int, int]:
    """(1 if any wheel's contact point is over the drop (true terrain below the plateau),
    1 if any is off the world's truth grid (no ground known there))."""
    xs, ys = rig.rover.world_wheel_xy()
    z = np.asarray(world.height_at(np.asarray(xs), np.asarray(ys)))
    return int(bool((z < world.plateau_z - cfg.edge.step_m).any())), int(bool(np.isnan(z).any()))


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
