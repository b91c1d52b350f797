"""``safer-hil bench cycle``: the sensing cycle, the foreground and memory against the target
budget (issue 15; config/budget.toml; docs/architecture.md "Target budget")."""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path
from typing import Any

HELP = "sensing-cycle breakdown, foreground per task, peak RSS, projected onto the target"
DESCRIPTION = (
    "Measures one sensing cycle of the flown pipeline (fsw.core.pipeline, the perception "
    "task's slack job) stage by stage: rectify when [camera] names a calibration file, "
    "stereo, register, merge (P_V, points with covariance, fusion), edge; then the next-view "
    "search; capture (the bench renderer) apart; on the map state after a start panorama "
    "(three views merged by the same pipeline; the bench's true cameras when [camera] names a "
    "calibration file) "
    "of each --grids size over the configured area; the foreground cost per task per frame "
    "and the longest slack-job slice (thread CPU, per submitting task, against the 20 ms "
    "bound) from a short lockstep mission; "
    "and this process's peak RSS, with the flight process's allocator settings ([executive] "
    "malloc_*) applied first. Times are CPU seconds of this process (one core): min and "
    "median of --repeats runs. In the same run it times a fixed yardstick workload "
    "(hil_sim/lab/bench/yardstick.py) and scales every figure to the reference machine "
    "(x yardstick_ref_s / the yardstick here, config/budget.toml), so figures from different "
    "machines compare; each is projected onto the flight computer as that x cpu_factor and "
    "compared with the budget table there; between grid sizes each stage's growth is checked "
    "against stage_growth_max x the cells' growth. --baseline REV runs the bench of another "
    "commit in child processes (its code exported from git), a repeat at a time interleaved with "
    "this commit's, and --results writes "
    "both to docs/results/cycle.md. "
    "CAVEAT: on a shared, loaded machine even CPU times inflate (caches, frequency); the "
    "yardstick absorbs part of it: compare figures measured back to back. Capture is the bench "
    "renderer (not flight work) and is left out of the cycle total. Exit 2 on a bad option or "
    "config file."
)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--scenario", default="lab", help="world (hil_sim.world.load_scenario spec)")
    p.add_argument("--seed", type=int, default=0, help="world, camera-noise and mission seed")
    p.add_argument("--config", type=Path, default=None,
                   help="flight config (default config/fsw.toml)")
    p.add_argument("--budget", type=Path, default=None,
                   help="budget table (default config/budget.toml)")
    p.add_argument("--cpu-factor", type=float, default=None,
                   help="override the budget's cpu_factor (target time / time on the reference machine)")
    p.add_argument("--grids", type=int, nargs="+", default=[256, 512], metavar="N",
                   help="map sizes N x N over the configured map area")
    p.add_argument("--repeats", type=int, default=3, help="timed runs per stage")
    p.add_argument("--mission-steps", type=int, default=1,
                   help="imaging steps of the lockstep mission timed for the foreground and "
                        "the slack slices (0: skip the mission)")
    p.add_argument("--baseline", metavar="REV", default=None,
                   help="also run this commit's bench cycle (its fsw, hil_sim and config exported "
                        "from git) in a child process, a repeat at a time interleaved with this "
                        "commit's, for a before/after table")
    p.add_argument("--results", action="store_true",
                   help="write the cycle table (and the baseline's) to docs/results/cycle.md")


def _cpu(fn: Any, repeats: int) -> tuple[float, float, Any]:
    """(min, median) CPU seconds of ``repeats`` calls, and the last result."""
    import statistics

    times, out = [], None
    for _ in range(repeats):
        c0 = time.process_time()
        out = fn()
        times.append(time.process_time() - c0)
    return min(times), statistics.median(times), out


def _search(planner: Any, state: Any) -> tuple[Any, float]:
    """A full search driven step by step: the choice and the longest step (CPU s)."""
    gen, longest = planner.search(state), 0.0
    while True:
        c0 = time.process_time()
        try:
            next(gen)
        except StopIteration as stop:
            return stop.value, max(longest, time.process_time() - c0)
        longest = max(longest, time.process_time() - c0)


# The pose prior of the bench's view (6x6: rotation vector rad, translation m): roughly what
# the flight's pose chain reports after a short drive; the registration starts from it.
BENCH_PRIOR_SIGMA = (math.radians(0.3), math.radians(0.3), math.radians(1.0), 0.02, 0.02, 0.01)
# The map state: a start panorama merged by the pipeline from the rover's start. The timed view
# looks between two of its views (half on the map: the registration aligns it there).
PANORAMA_PANS_DEG = (-130.0, -90.0, -50.0)
PANORAMA_TILT_DEG = -35.0
TIMED_PAN_DEG = -70.0


class StageClock:
    """The ``stage`` callback of ``fsw.core.pipeline.SensingPipeline.view_steps``: CPU seconds
    of this process per stage, from one stage's start to the next's (or :meth:`stop`)."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = {}
        self._stage: str | None = None
        self._t0 = 0.0

    def __call__(self, name: str) -> None:
        self.stop()
        self._stage, self._t0 = name, time.process_time()

    def stop(self) -> None:
        if self._stage is not None:
            self.seconds[self._stage] = self.seconds.get(self._stage, 0.0) + time.process_time() - self._t0
        self._stage = None


def _cycle(cfg: Any, world: Any, n: int, repeats: int, seed: int) -> dict[str, Any]:
    """One sensing cycle of the flown pipeline on the start-panorama state of an ``n`` x ``n``
    map, ``repeats`` times from the same state: (min, median) CPU s per stage."""
    import dataclasses
    import statistics

    import numpy as np

    from fsw.core.geometry import camera_pose_from_rover
    from fsw.core.pipeline import STAGES, SensingPipeline
    from fsw.core.planning.info_planners import InformationPlanner
    from fsw.core.planning.planners import PlannerState
    from fsw.settings import load_stereo_calibration
    from fsw.tasks.messages import CameraFrame
    from hil_sim.camera_model import TrueCameras
    from hil_sim.lab import nbv_scene
    from hil_sim.render import StereoRenderer
    from hil_sim.rig import load_hardware

    mg = dataclasses.replace(world.map_grid, nx=n, ny=n, cell_m=world.map_grid.cell_m * world.map_grid.nx / n)
    cfg = dataclasses.replace(cfg, map=mg)
    cal = load_stereo_calibration(cfg)  # as the perception task: rectify when calibrated
    rover = tuple(float(v) for v in world.rover_start)
    # the bench's cameras (config/hil_hardware.toml) when the flight rectifies, as in a mission
    cams = None if cal is None else TrueCameras.from_config(cfg.camera, load_hardware().camera)
    rend = StereoRenderer(world, cfg.camera, world.noise_sigma, seed=seed, cameras=cams)
    prior = np.diag(np.square(BENCH_PRIOR_SIGMA))

    def frame(k: int, pan_deg: float) -> Any:
        pose = camera_pose_from_rover(rover, (math.radians(pan_deg), math.radians(PANORAMA_TILT_DEG),
                                              cfg.mast.lift_max_m), cfg.mast, float(world.plateau_z))
        return CameraFrame(k, 0.0, *rend.render(pose), pose, prior, ground_z_m=float(world.plateau_z))

    # the start panorama, merged by the pipeline (the first view is the map's reference)
    start = SensingPipeline(cfg, cal)
    for k, pan in enumerate(PANORAMA_PANS_DEG):
        start.merge_view(frame(k, pan))
    fig: dict[str, Any] = {"grid": n, "cell_m": start.map.grid.cell}
    timed = frame(len(PANORAMA_PANS_DEG), TIMED_PAN_DEG)
    fig["capture"] = _cpu(lambda: rend.render(timed.pose), repeats)[:2]
    runs: list[dict[str, float]] = []
    sensed: Any = None
    for _ in range(repeats):
        pipeline = SensingPipeline(cfg, cal, start.map.copy())  # the same state each time
        pipeline.chain.restore(start.chain.state())
        pipeline.sources.restore(start.sources.state())
        pipeline.lips.restore(start.lips.state())
        clock = StageClock()
        steps = pipeline.view_steps(timed, clock)
        while True:
            try:
                next(steps)
            except StopIteration as stop:
                sensed = stop.value
                break
        clock.stop()
        runs.append(clock.seconds)
    for stage in STAGES:
        times = [r[stage] for r in runs]
        fig[stage] = (min(times), statistics.median(times))
    if cal is None:
        fig["rectify"] = None
    reg = sensed.placed.registration
    fig["registration"] = reg.status + (f" ({reg.reason})" if reg.reason else "")
    path = nbv_scene.edge_offset_path(np.asarray(world.edge_xy, float), cfg.edge.setback_m)
    planner = InformationPlanner("5", cfg.nbv, cfg.camera, cfg.mast, use_interest=True)
    state = PlannerState(pipeline.map, rover, (0.0, 0.0, cfg.mast.lift_max_m), path, lambda a, b: True,
                         edge_xy=np.asarray(world.edge_xy, float))
    *fig["next_view"], (choice, longest) = _cpu(lambda: _search(planner, state), repeats)
    if choice is None:
        raise ValueError("no candidate view on this map state")
    fig["step_max_s"] = longest
    fig["poses"] = planner.last_stations * len(cfg.nbv.lifts_m) * int(
        np.arange(cfg.mast.pan_min_deg, cfg.mast.pan_max_deg + 1e-9, cfg.nbv.pan_step_deg).size
        * len(cfg.nbv.tilts_deg))
    return fig


def _pooled(runs: list[dict[str, Any]]) -> dict[str, Any]:
    """Single-repeat figures of :func:`_cycle` pooled: (min, median) of every timed item."""
    import statistics

    out = dict(runs[-1])
    for key, value in runs[-1].items():
        if isinstance(value, (tuple, list)) and len(value) == 2 and all(isinstance(v, float) for v in value):
            times = [float(r[key][0]) for r in runs]
            out[key] = (min(times), statistics.median(times))
    out["step_max_s"] = max(float(r["step_max_s"]) for r in runs)
    return out


def run(args: argparse.Namespace) -> int:
    import contextlib
    import resource

    from fsw.executive.executive import fix_malloc_thresholds, pad_malloc_heap
    from fsw.framework.params import ConfigError
    from fsw.settings import DEFAULT_CONFIG, load_settings
    from hil_sim.lab.bench.cycle_compare import (
        Baseline,
        BaselineError,
        BaselineRunner,
        min_stages,
        write_cycle_results,
    )
    from hil_sim.lab.bench.yardstick import yardstick_s
    from hil_sim.lab.cycle_budget import CYCLE_GOALS_S, CYCLE_STAGES, DEFAULT_BUDGET, load_budget, verdict
    from hil_sim.world import load_scenario

    if args.repeats < 1 or args.mission_steps < 0 or any(not 16 <= g <= 4096 for g in args.grids):
        print("safer-hil bench cycle: --repeats >= 1, --mission-steps >= 0, --grids within "
              "16..4096", file=sys.stderr)
        return 2
    if args.cpu_factor is not None and not 1.0 <= args.cpu_factor <= 1000.0:
        print("safer-hil bench cycle: --cpu-factor must be within 1..1000", file=sys.stderr)
        return 2
    try:
        cfg = load_settings(args.config or DEFAULT_CONFIG)
        budget = load_budget(args.budget or DEFAULT_BUDGET)
        world = load_scenario(args.scenario, args.seed)
    except (ConfigError, ValueError) as err:
        print(f"safer-hil bench cycle: {err}", file=sys.stderr)
        return 2
    # The flight process's allocator settings (its executive sets them at start-up) before anything is timed.
    fix_malloc_thresholds(cfg.executive.malloc_mmap_threshold_kib * 1024)
    pad_malloc_heap(cfg.executive.malloc_top_pad_kib * 1024)
    grids = sorted(set(args.grids))
    k = args.cpu_factor or budget.cpu_factor
    runner = None
    if args.baseline:
        try:
            runner = BaselineRunner(args.baseline, args)
        except BaselineError as err:
            print(f"safer-hil bench cycle: {err}", file=sys.stderr)
            return 2
    print(f"CPU s of this process, min (median) of {args.repeats}; ref = on the reference machine "
          f"(x yardstick_ref_s / the yardstick here); target = ref x {k:g} (cpu_factor); budget: "
          f"{args.budget or DEFAULT_BUDGET}. Caveat: on a shared, loaded machine CPU times inflate "
          "too; compare runs made back to back.", flush=True)
    figs: dict[int, dict[str, Any]] = {}
    base: dict[int, dict[str, float | None]] = {}
    yard: dict[int, float] = {}
    try:
        with runner or contextlib.nullcontext():
            for n in grids:
                samples = [yardstick_s(2)]
                if runner is None:
                    figs[n] = _cycle(cfg, world, n, args.repeats, args.seed)
                    samples.append(yardstick_s(2))
                else:  # one repeat of each commit at a time: the same load for both
                    runs, base_runs = [], []
                    for _ in range(args.repeats):
                        base_runs.append(runner.stages(n))
                        samples.append(yardstick_s(2))
                        runs.append(_cycle(cfg, world, n, 1, args.seed))
                        samples.append(yardstick_s(2))
                    figs[n], base[n] = _pooled(runs), min_stages(base_runs)
                yard[n] = min(samples)
                print(f"  measured {n}x{n}", file=sys.stderr, flush=True)
    except (ValueError, BaselineError) as err:
        print(f"safer-hil bench cycle: {err}", file=sys.stderr)
        return 2
    before = None if runner is None else Baseline(runner.commit, base)
    after: dict[int, dict[str, float | None]] = {}
    for n in grids:
        f = figs[n]
        after[n] = {}
        scale = budget.yardstick_ref_s / yard[n]
        print(f"\nyardstick {1e3 * yard[n]:.1f} ms here (between the {n}x{n} runs), "
              f"{1e3 * budget.yardstick_ref_s:.1f} ms on the reference machine: ref = here x {scale:.3f}")
        print(f"sensing cycle (the flown pipeline, fsw.core.pipeline), {args.scenario} after the "
              f"start panorama, map {n}x{n} cells of {100 * f['cell_m']:.2f} cm; the view {f['registration']}:")
        print(f"  {'stage':<10} {'here min (median)':>20} {'ref':>9} {'target':>8} {'budget':>8}")
        c_min, c_med = f["capture"]
        print(f"  {'capture':<10} {1e3 * c_min:9.1f} ({1e3 * c_med:7.1f}) ms   (bench renderer, "
              "not flight work: not in the total)")
        total = 0.0
        for stage in CYCLE_STAGES:
            b = getattr(budget.cycle, f"{stage}_s")
            if f[stage] is None:
                after[n][stage] = None
                print(f"  {stage:<10} {'n/a (no calibration)':>20} {'':>9} {'':>8} {b:7.1f}s")
                continue
            lo, med = f[stage]
            total += lo
            after[n][stage] = lo
            print(f"  {stage:<10} {1e3 * lo:9.1f} ({1e3 * med:7.1f}) ms {1e3 * lo * scale:6.1f} ms "
                  f"{lo * scale * k:7.2f}s {b:7.1f}s {verdict(lo * scale * k, b)}")
        goal = CYCLE_GOALS_S.get(n)
        print(f"  {'cycle':<10} {1e3 * total:9.1f} (sum of min) ms {1e3 * total * scale:6.1f} ms "
              f"{total * scale * k:7.2f}s {budget.cycle.total_s:7.1f}s "
              f"{verdict(total * scale * k, budget.cycle.total_s)}"
              + ("" if goal is None else f"; goal {goal:g} s on the reference machine: "
                 f"{verdict(total * scale, goal)}"))
        print(f"  next view: {f['poses']} poses, longest search step {1e3 * f['step_max_s']:.1f} "
              f"ms here ({1e3 * f['step_max_s'] * scale * k:.0f} ms on the target)")
    for n1, n2 in zip(grids, grids[1:], strict=False):
        cells = (n2 / n1) ** 2
        bound = budget.stage_growth_max * cells
        parts = []
        for stage in CYCLE_STAGES:
            t1, t2 = after[n1][stage], after[n2][stage]
            if t1 is not None and t2 is not None and t1 > 0:
                parts.append(f"{stage} {t2 / t1:.1f}x {verdict(t2 / t1, bound)}")
        print(f"\ngrowth {n1}x{n1} -> {n2}x{n2} ({cells:g}x the cells; bound {bound:.1f}x): " + ", ".join(parts))
    if args.mission_steps:  # after the cycles (timed after a mission in this process, they measured up to 2x slower)
        from hil_sim.mission.mission_run import RunSpec, run_mission

        s = run_mission(RunSpec(scenario=args.scenario, method="5", steps=args.mission_steps,
                                seed=args.seed, config=str(args.config or DEFAULT_CONFIG),
                                out=None, transmit=False, cpu_timer=True))
        per = s["task_ms_per_frame"]
        fg = per.pop("total")
        print(f"\nforeground, lockstep {args.scenario} mission ({args.mission_steps} steps, "
              f"{s['frames']} frames; thread CPU time per task, mean ms per frame, here):")
        for name, ms in sorted(per.items(), key=lambda kv: -kv[1]):
            print(f"  {name:<12} {ms:8.3f} ms  target {ms * k:7.2f} ms")
        print(f"  {'total':<12} {fg:8.3f} ms  target {fg * k:7.2f} ms, budget "
              f"{budget.foreground_ms_per_frame:g} ms of a {1e3 * budget.frame_period_s:g} ms "
              f"frame: {verdict(fg * k, budget.foreground_ms_per_frame)}")
        mx = s["task_max_ms"]
        owners = ", ".join(f"{k.split('.', 1)[1]} {v:.1f}" for k, v in sorted(mx.items())
                           if k.startswith("slack_slice."))
        print(f"  longest slack-job slice {mx['slack_slice']:.1f} ms (thread CPU; by task: {owners or 'none'}), "
              f"bound {budget.slack_slice_ms:g} ms here: {verdict(mx['slack_slice'], budget.slack_slice_ms)}")
        rss_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
        print(f"  peak RSS after the mission {rss_mb:.0f} MB (flight software and the HIL bench "
              f"in one process: an upper bound on the flight process), budget "
              f"{budget.peak_rss_mb:g} MB: {verdict(rss_mb, budget.peak_rss_mb)}")
    rss_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    print(f"\npeak RSS at the end {rss_mb:.0f} MB (this process, after every stage above)")
    if args.results:
        write_cycle_results(args, budget, after, yard, before)
    return 0
