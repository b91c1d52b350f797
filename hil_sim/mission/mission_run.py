"""One lockstep mission on the bench, and its summary (``safer-hil run``, ``make demo``).

The flight executive with its full schedule (config/fsw.toml) runs against the hardware rig
in lockstep (``hil_sim.bench.LockstepBench``); the radio runs through the seeded channel
model to the Cliff-bot receiver. The runner only watches: it never steers the flight code.
It records, per imaging step, what the mission task recorded, and from the world truth the
map error and any wheel over the drop (an edge violation), over the whole run: in a team run
also after the RECON-bot's mission, while its fixer may turn it in place.

``summary.json`` schema (stable; docs/experiments.md): ``schema`` (1), ``scenario``,
``method``, ``seed``, ``camera`` (config | ideal | raw), ``steps`` (list of ``{step, mapped_cells, expected_new_cells,
obtained_new_cells, pose{x,y,yaw,pan,tilt,lift}, wall_s, sim_s}``), ``map_rmse_m``,
``edge_violations``, ``geofence_refusals``, ``slips``, ``overruns``, ``task_max_ms``
({task: ms}, plus ``frame``: the longest frame, and ``slack_slice``, ``slack_slice.<task>``:
the longest slack-job slice), ``task_ms_per_frame`` ({task: mean foreground ms per frame},
plus ``total``),
``map_error_tilt_deg`` and ``map_rmse_detilted_m`` (the plane
fitted to map minus truth over mapped cells: its tilt, and the RMS error around it),
``wheels_off_terrain`` (rig steps with a wheel off the world's terrain, a bench fault),
``wheels_on_unknown_ground`` (frames the rover moved with a true wheel position on ground the
flight geofence did not know), ``bench_faults`` (``{t_s, kind, detail}``), ``odometer_m``,
``reachable_stations`` (per step boundary: edge-path stations the geofence allowed from the
rover's estimated pose, ``hil_sim.mission.ground_watch``), ``looks`` (views of unknown ground before
a move), ``stays`` (steps whose view was taken without the planned move, and why),
``steps_unused`` and ``steps_unused_reason``,
``end_reason``, ``final_state``, ``mapped_cells``, ``frames``, ``sim_s``,
``start_attitude_deg`` (true roll, pitch at the start), ``registration`` (per view: status,
correction, sigmas; ``fsw.core.registration.registration``), ``map_quality`` (RMS, fitted tilt, station
seams, 2-sigma fraction, all against the truth in the flight map's datum, the true body
height at the start, with the ground-datum figures beside them; ``hil_sim.lab.terrain_eval``),
``calib_2sigma`` (fraction of mapped cells within 2 sigma of the truth, docs/algorithm.md §4; the
same datum), ``map_rmse_m`` and the error plane also in that datum,
``safe_entries``, ``safe_recoveries`` (SAFE left for the mission again), ``safe_recoveries_resumed``
(of those, the ones after which the mission completed a step or ended before any new SAFE),
``off_map`` (frames with a wheel off the world's truth grid), ``tasks_hung`` (health TASK_HUNG
events), ``watchdog_expired_frames`` (frames the watchdog was expired), ``map_transfer``
(delivered | failed | rejected | timeout | none), ``transfer_s`` (bench s from the end of
mapping to the end of the transfer), ``faults`` (the injected
:class:`hil_sim.faults.FaultSpec` rows),
``wall_s``, ``cliffbot`` (the Cliff-bot's report, or null), ``files``. Wall-clock fields:
``wall_s`` (top level and per step; null for a step restored from a checkpoint), ``task_max_ms``,
``task_ms_per_frame``, and ``slips`` and ``overruns`` (both compare measured execution time with the
period and budgets); everything else is a function of the inputs and the seed.

Resuming (docs/hil.md, "Resuming a mission"; the spec, the manifest and the out directory are
``hil_sim.mission.run_spec``): the run writes ``run.json`` (its ``RunSpec``)
and, after each imaging step, a checkpoint with the map, the mission state and the bench's
truth and random generators (``hil_sim.mission.resume_state``). ``mode="resume"`` continues a killed
run from its newest good checkpoint, deterministically: the same seed gives the same map as
an uninterrupted run. ``mode="new"`` refuses an out directory that holds a mission
(``MissionExistsError``); ``mode="fresh"`` deletes it first.

A full or failing disk (docs/hil.md): ``hil_sim.mission.run_dir`` asks for room before a start or a
resume and copies the flight's storage events to stderr; the mission carries on.
"""

from __future__ import annotations

import dataclasses
import json
import shutil
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from fsw.comm.mavlink_telemetry import VEHICLE_NAMES
from fsw.core.geometry import MapGrid
from fsw.drivers.resources import OracleTruth, Resources
from hil_sim.lab.terrain_eval import map_quality
from hil_sim.mission.ground_watch import reachable_stations, wheels_on_unknown
from hil_sim.mission.mission_report import (
    _cliffbot_report,
    error_plane,
    map_transfer,
    prediction_ratios,
    task_max_ms,
    task_ms_per_frame,
    transfer_s,
    write_outputs,
)
from hil_sim.mission.run_dir import echo_storage_events
from hil_sim.mission.run_spec import RunSpec, mission_config, prepare_store


def run_mission(
    spec: RunSpec,
    progress: Callable[[int, int, str], None] | None = None,
    max_sim_s: float | None = None,
    mode: str = "new",
    on_bench: Callable[[Any], None] | None = None,
    live: str | None = None,
) -> dict[str, Any]:
    """Run one mission to DONE (or SAFE, or the time limit) and return its summary.

    ``mode``: "new" (refuse an out directory holding a mission), "fresh" (delete it first) or
    "resume" (continue it from its newest good checkpoint; module docstring)."""
    from hil_sim.bench import LockstepBench
    from hil_sim.cliffbot_receiver import Cliffbot
    from hil_sim.link.radio_channel import ChannelPort, RadioChannel, RadioChannelConfig
    from hil_sim.mission.resume_state import BenchStateError, bench_state, restore_bench
    from hil_sim.rig import load_hardware
    from hil_sim.team.team_bench import CliffbotAgent, FixWatch
    from hil_sim.world import load_scenario

    t_wall = time.perf_counter()
    world = load_scenario(spec.scenario, seed=spec.seed)
    cfg = mission_config(spec, world)
    grid = MapGrid.from_config(cfg.map)
    frame = tuple(float(v) for v in world.rover_start)  # the flight map's frame: odometry from the start
    truth = world.truth_on_grid(grid, frame)
    oracle = OracleTruth(z_m=truth, textured=~world.textureless_on_grid(grid, frame))
    outages = tuple((f.start_s, f.duration_s) for f in spec.faults if f.kind == "radio_outage")
    channel = RadioChannel(RadioChannelConfig(outages=outages), seed=spec.seed)
    clock_box: list[Callable[[], float]] = []

    def now() -> float:
        return clock_box[0]() if clock_box else 0.0

    # a team scenario: the bench notes the fixes the RECON-bot sends (to judge them on the truth)
    port_flight = FixWatch(channel, "a", now) if world.team is not None else ChannelPort(channel, "a", now)
    resources = Resources(radio_port=port_flight, oracle_truth=oracle)
    store, start, saved_bench = prepare_store(spec, cfg, mode)
    counters: dict[str, Any] = {"violations": 0}
    bench_box: list[Any] = []
    team_box: list[Any] = []
    if store is not None:
        resources.map_store = store
        resources.checkpoint_hooks = {
            # a team scenario: the Cliff-bot's checkpoint and hardware with the RECON-bot's
            "bench": lambda: bench_state(bench_box[0], {"channel": channel}, counters)
            | ({"team": team_box[0].state()} if team_box else {}),
        }
    hw = load_hardware(spec.hardware)
    if spec.camera == "ideal":
        hw = dataclasses.replace(hw, camera=dataclasses.replace(hw.camera, model="ideal"))
    with LockstepBench(cfg, world, seed=spec.seed, hw=hw, quiet=True, resources=resources, start=start,
                       faults=spec.faults) as bench:
        bench_box.append(bench)
        bench.exe.ctx.events.listeners.append(echo_storage_events)
        if on_bench is not None:  # an experiment's observer (hil_sim.lab.view_replay records the views)
            on_bench(bench)
        clock_box.append(bench.clock.now)
        if saved_bench is not None:
            try:
                counters.update(restore_bench(bench, saved_bench, {"channel": channel}))
            except BenchStateError as exc:
                raise ValueError(f"checkpoint cannot be resumed: {exc}") from None
        if spec.cpu_timer:  # foreground figures without the preemption of a shared machine
            bench.set_host_timer(time.thread_time)  # slack-job slices too (task_max_ms slack_slice)
        cliffbot = Cliffbot(cfg.link, ChannelPort(channel, "b", now), out_dir=spec.out)
        mission = bench.exe.tasks["mission"]
        perception = bench.exe.tasks["perception"]
        recorder, tap = _recorder(spec.out, bench.exe, live,
                                  ("recon", "cliffbot") if world.team is not None else ("recon",))
        recording_error = ""
        limit_s = max_sim_s if max_sim_s is not None else 120.0 + 90.0 * (spec.steps + 1) + 1200.0
        counters.setdefault("unknown_frames", 0)
        counters.setdefault("reachable", [])  # stations the geofence allowed, at each step boundary
        last_step = -1
        views: list[Any] = []  # (camera xyz, cell index, z) per merged view, for the seams
        start_att = (round(bench.rig.truth()["roll_deg"], 3), round(bench.rig.truth()["pitch_deg"], 3))
        mount_truth = mount_bias_truth(bench.rig)
        # the flight map's height origin: the true body height at the start (hil_sim.lab.terrain_eval);
        # kept in the counters so a resumed run keeps the start's, not the resume point's
        datum_m = float(counters.setdefault("datum_m", float(bench.rig.rover.z)))
        team = None
        if world.team is not None and isinstance(port_flight, FixWatch):  # the Cliff-bot's executive, from now
            resumed_team = saved_bench.get("team") if saved_bench is not None else None
            try:
                team = CliffbotAgent(bench, world, channel, port_flight, spec.seed, datum_m, spec.out, spec.faults,
                                     recon_done=lambda: mission.state in ("DONE", "SAFE"), resume=resumed_team)
            except BenchStateError as exc:
                raise ValueError(f"checkpoint cannot be resumed: {exc}") from None
            team_box.append(team)
        taps = [] if tap is None or recorder is None else [tap]
        if taps and team is not None:  # the Cliff-bot is the recording's second source
            from ground.recording import CliffbotTap

            sid = team.cfg.mavlink.system_id
            name = VEHICLE_NAMES.get(sid, f"sys{sid}")
            mirrors: tuple[Any, ...] = ()
            if len(tap.sinks) > 1:  # the live view, too
                from ground.rerun_cli import LiveSource

                mirrors = tuple(LiveSource(m.rec, name) for m in tap.sinks[1:])
            taps.append(CliffbotTap(team.exe, recorder.source(name), mirrors=mirrors))
        watchdog = bench.exe.ctx.res.watchdog
        for key in ("off_map", "recoveries", "recoveries_resumed", "watchdog_frames"):
            counters.setdefault(key, 0)
        was_safe = False
        left_safe_at: int | None = None  # the step a recovery left SAFE at, until it proves itself
        wheel_watch = _WheelWatch(world, cfg.edge.step_m)

        def frame() -> None:
            """One frame of the run, the RECON-bot's wheels watched (over the drop, off the map, on
            ground its geofence does not know) during its mission and after it (the fixer's turns)."""
            nonlocal recording_error
            odo = bench.rig.rover.odometer_m
            bench.run(1)
            recording_error = _poll_taps(taps, recording_error)
            counters["unknown_frames"] += wheels_on_unknown(bench.rig, mission, odo)
            over_drop, off_map = wheel_watch(bench.rig)
            counters["violations"] += over_drop
            counters["off_map"] += off_map

        bench.exe.freeze_heap()  # as the flight start-up does (safer-fsw run)
        try:
            while bench.clock.now() < limit_s:
                frame()
                if mission.state == "TRANSMIT" and 1 not in cliffbot.originals:
                    cliffbot.originals[1] = perception.map.z.astype(np.float32)
                if team is None:  # (a team's Cliff-bot receives the map in its own flight code)
                    cliffbot.step(bench.clock.now())
                if was_safe and mission.state != "SAFE":
                    counters["recoveries"] += 1
                    left_safe_at = mission.step
                elif mission.state == "SAFE":
                    left_safe_at = None  # SAFE again before the mission got further
                elif left_safe_at is not None and (mission.step > left_safe_at or mission.state == "DONE"):
                    counters["recoveries_resumed"] += 1  # a step completed (or the mission ended) since
                    left_safe_at = None
                counters["watchdog_frames"] += int(bool(getattr(watchdog, "expired", lambda: False)()))
                was_safe = mission.state == "SAFE"
                up = perception.last_update
                fresh = up is not None and (not views or views[-1][3] is not up)
                if fresh and up is not None and up.camera_xyz is not None and up.view_cells is not None:
                    views.append((up.camera_xyz, *up.view_cells, up))
                if mission.step != last_step:
                    last_step = mission.step
                    counters["reachable"].append(reachable_stations(mission, cfg))
                    if progress is not None:
                        progress(mission.step, spec.steps, mission.state)
                if mission.state == "DONE" or (mission.state == "SAFE" and (
                        cfg.mission.safe_recover_s <= 0 or mission.safe.final)):
                    break
            if team is not None and mission.state in ("DONE", "SAFE"):  # the Cliff-bot's goes on after it
                team_end = bench.clock.now() + TEAM_MAX_S
                while not team.finished() and bench.clock.now() < team_end:
                    frame()
                settle_end = bench.clock.now() + SYNC_SETTLE_S  # the last look's tiles cross the radio
                while not team.sync_settled() and bench.clock.now() < settle_end:
                    frame()
        finally:
            bench.exe.thaw_heap()
            for tp in taps:
                tp.close()
            if recorder is not None:
                try:
                    recorder.close()
                except Exception as exc:  # noqa: BLE001 - as above: the mission's own results come first
                    recording_error = recording_error or f"mission recording not closed: {type(exc).__name__}: {exc}"
        exe = bench.exe
        if "mavlink" in exe.tasks:
            exe.tasks["mavlink"].close()  # flush and close the .tlog
        emap = perception.map
        mapped = emap.mapped & np.isfinite(truth)
        truth_f = truth - datum_m  # the truth in the flight map's datum (hil_sim.lab.terrain_eval)
        rmse = float(np.sqrt(np.mean((emap.z[mapped] - truth_f[mapped]) ** 2))) if mapped.any() else None
        tilt_deg, rmse_plane = error_plane(grid, emap.z - truth_f, mapped)
        quality = map_quality(emap, truth, [v[:3] for v in views], datum_m)
        summary: dict[str, Any] = {
            "schema": 1,
            "scenario": spec.scenario,
            "method": spec.method,
            "seed": spec.seed,
            "camera": spec.camera,
            "steps": [dataclasses.asdict(r) for r in mission.records],
            "prediction": prediction_ratios([dataclasses.asdict(r) for r in mission.records]),
            "map_rmse_m": rmse,
            "map_error_tilt_deg": tilt_deg,
            "map_rmse_detilted_m": rmse_plane,
            "edge_violations": counters["violations"],
            "calib_2sigma": quality["within_2sigma"],
            "geofence_refusals": mission.ground.edge_violations,
            "wheels_off_terrain": bench.rig.wheels_off_terrain_steps,
            "wheels_on_unknown_ground": counters["unknown_frames"],
            "bench_faults": bench.rig.faults_seen,
            "odometer_m": round(bench.rig.rover.odometer_m, 3),
            "reachable_stations": counters["reachable"],
            "looks": mission.ground.looks,
            "stays": mission.ground.stays,
            "steps_unused": max(0, spec.steps - (len(mission.records) - 1)),
            "steps_unused_reason": None if len(mission.records) - 1 >= spec.steps else (
                mission.end or mission.safe.reason or f"stopped in {mission.state}"),
            "slips": exe.host_slips,
            "overruns": sum(t.host.overruns for t in exe.tasks.values()),
            "task_max_ms": task_max_ms(exe),
            "task_ms_per_frame": task_ms_per_frame(exe),
            "end_reason": mission.end,
            "safe_reason": mission.safe.reason,
            "safe_entries": mission.safe.entries,
            "safe_recoveries": counters["recoveries"],
            "safe_recoveries_resumed": counters["recoveries_resumed"],
            "off_map": counters["off_map"],
            "tasks_hung": exe.events.count("health.TASK_HUNG") if "health" in exe.tasks else 0,
            "watchdog_expired_frames": counters["watchdog_frames"],
            "map_transfer": map_transfer(mission),
            "map_delivered": {"delivered": True, "none": None}.get(map_transfer(mission), False),
            "transfer_s": transfer_s(mission),
            "faults": [dataclasses.asdict(f) for f in spec.faults],
            "final_state": mission.state,
            "mapped_cells": int(emap.mapped.sum()),
            "frames": exe.frame,
            "sim_s": round(bench.clock.now(), 3),
            "wall_s": round(time.perf_counter() - t_wall, 3),
            "cliffbot": _cliffbot_report(cliffbot, spec.out),
            "start_attitude_deg": list(start_att),
            "registration": list(perception.registrations),
            "mount_bias": perception.pipeline.bias.summary(perception.ctx.cfg.registration.bias_estimate),
            "mount_bias_truth_deg": mount_truth,
            "map_quality": quality,
            "files": {},
        }
        if team is not None:
            summary["team"] = team.section(spec.out, 0.0)
            team.close()
        summary = json.loads(json.dumps(summary))  # exactly what summary.json holds
        if spec.out is not None:
            extra = {"recording": recorder.path.name} if recorder is not None and not recording_error else {}
            if recording_error:
                summary["recording_error"] = recording_error
            summary["files"] = write_outputs(spec.out, summary, emap, truth_f, grid, extra)
    return summary


def mount_bias_truth(rig: Any) -> dict[str, float]:
    """The bench's constant mounting errors (what the flight's ``mount_bias`` estimates, deg):
    the mast's tilt and pan calibration offsets and the attitude sensor's roll and pitch biases."""
    off = np.degrees(rig.mast.offset[:2])
    return {"mast_tilt": round(float(off[1]), 5), "imu_roll": round(float(rig.imu.bias_deg[0]), 5),
            "imu_pitch": round(float(rig.imu.bias_deg[1]), 5), "mast_pan": round(float(off[0]), 5)}


def _poll_taps(taps: list[Any], error: str) -> str:
    """Poll the recording's taps; a recording that fails (full disk) stops (``taps`` emptied) and
    says why, and must not end the mission."""
    try:
        for t in taps:
            t.poll()
    except Exception as exc:  # noqa: BLE001 - see above
        error = f"mission recording stopped: {type(exc).__name__}: {exc}"
        print(error, file=sys.stderr)
        taps.clear()
    return error


RECORDING_MIN_FREE = 512 * 2**20
SYNC_SETTLE_S = 120.0  # then the map sync may go on this long until both replicas are equal (bench s)
TEAM_MAX_S = 1800.0  # the Cliff-bot's mission may go on this long after the RECON-bot's (bench s)


def _recorder(out: Path | None, exe: Any, live: str | None = None,
              vehicles: tuple[str, ...] = ("recon",)) -> tuple[Any, Any]:
    """The mission's Foxglove recording (``ground.recording``) in ``out`` and the bus tap feeding
    it; a resumed mission starts a new file (``mission.1.mcap``, ...), never overwrites one.
    ``live``: also stream the mission to a live view (``safer-ground rerun --live``) at this URL,
    laid out for ``vehicles`` (a team's Cliff-bot joins it through its own tap, ``CliffbotTap``).

    No recording where ``out`` has less than ``RECORDING_MIN_FREE`` bytes free: a recording
    (camera pairs) runs to tens of MB and must not take the room the checkpoints, the .tlog
    and the summary need (one line says so)."""
    if out is None:
        return None, None
    try:
        out.mkdir(parents=True, exist_ok=True)
        free = shutil.disk_usage(out).free
    except OSError as exc:
        print(f"safer-hil run: no mission recording: {exc}", file=sys.stderr)
        return None, None
    if free < RECORDING_MIN_FREE:
        print(f"safer-hil run: no mission recording: {free / 2**20:.0f} MiB free in {out} "
              f"(it needs {RECORDING_MIN_FREE / 2**20:.0f} MiB)", file=sys.stderr)
        return None, None
    from ground.recording import BusTap, MissionRecorder

    path, k = out / "mission.mcap", 0
    while path.exists():
        k += 1
        path = out / f"mission.{k}.mcap"
    recorder = MissionRecorder(path)
    mirrors: tuple[Any, ...] = ()
    if live:
        from ground.rerun_cli import LiveSource, live_stream

        mirrors = (LiveSource(live_stream(live, vehicles, recording_id=path.parent.name), "recon"),)
    return recorder, BusTap(exe, recorder.source("recon"), mirrors=mirrors)


class _WheelWatch:
    """The truth's verdict on the wheels' contact points, each frame: ``(over_drop, off_map)``,
    1 if any wheel is over the drop (true terrain below the nearest plateau ground by more than
    the edge step: ``World.over_drop``), 1 if any is off the world's truth grid (no ground known
    there). The same contact points give the same verdict: a rover standing still is judged once."""

    def __init__(self, world: Any, step_m: float) -> None:
        self.world, self.step_m = world, step_m
        self._key = b""
        self._verdict = (0, 0)

    def __call__(self, rig: Any) -> tuple[int, int]:
        xs, ys = (np.asarray(v, float) for v in rig.rover.world_wheel_xy())
        key = xs.tobytes() + ys.tobytes()
        if key != self._key:
            over = bool(self.world.over_drop(xs, ys, self.step_m).any())
            off = bool(np.isnan(np.asarray(self.world.height_at(xs, ys))).any())
            self._key, self._verdict = key, (int(over), int(off))
        return self._verdict
