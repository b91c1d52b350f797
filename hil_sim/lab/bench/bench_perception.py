"""``safer-hil bench perception``: speed of the perception chain, and with ``--plot`` the
variance calibration of the map (docs/algorithm.md §1, §2, §4; docs/perception.md).

Prints, from real runs on rendered pairs of the scenario:
  * stereo ms per pair (SGBM, filters, triangulation with covariance; 640x480), and the
    median and longest slice of the slack-job matcher (``match_steps``);
  * rectification ms per pair (two ``cv2.remap`` with the fixed-point maps of the configured
    calibration file; target <= 5 ms);
  * points merged per second (one view's world points fused into a fresh map, and a
    300 000-point batch into the default 256x256 map; target <= 50 ms);
  * edge fit ms (edge points, polygon and straight-line fits, the set-back path) on the map
    of a pass along the edge;
  * checkpoint ms (encode, atomic write with fsync and rename, load and verify).
Timings are medians of ``--repeats`` runs after a warm-up; on a shared machine they are
noisy. ``--plot PNG`` also renders ten views of one pit patch and writes the calibration
figure of predicted sigma against actual error (one view and ten fused), printing the
calibration figures.
"""

from __future__ import annotations

import argparse

from hil_sim.lab.perception_eval import PERCEPTION_LAB

HELP = "stereo ms per pair, points merged per second, edge fit ms, checkpoint ms (--plot: PNG)"
MERGE_TARGET_MS = 50.0
RECTIFY_TARGET_MS = 5.0
BATCH_POINTS = 300_000


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--scenario", default=PERCEPTION_LAB,
                   help="world (hil_sim.world.load_scenario spec; default: the lab with a 1 m "
                        "textureless patch, as tests/perception)")
    p.add_argument("--seed", type=int, default=0, help="world and camera-noise seed")
    p.add_argument("--repeats", type=int, default=5, help="timed runs per figure")
    p.add_argument("--config", default=None, help="flight config (default config/fsw.toml)")
    p.add_argument("--range-m", type=float, nargs=2, default=(2.0, 4.0), metavar=("MIN", "MAX"),
                   help="calibration over cells at this range from the camera, m")
    p.add_argument("--plot", default=None, metavar="PNG",
                   help="also write the variance calibration figure here (e.g. "
                        "docs/img/perception_calibration.png)")


def _median_ms(fn, repeats: int) -> float:  # type: ignore[no-untyped-def]
    import statistics
    import time

    fn()  # warm-up
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(1e3 * (time.perf_counter() - t0))
    return statistics.median(times)


def run(args: argparse.Namespace) -> int:
    import sys
    import tempfile

    import numpy as np

    from fsw.core.edge.edge import edge_cells, edge_path, fit_line, fit_polygon
    from fsw.core.geometry import MapGrid
    from fsw.core.map import checkpoint
    from fsw.core.map.elevation_map import ElevationMap
    from fsw.core.stereo.rectify import Rectifier
    from fsw.drivers.map_store import MapStore
    from fsw.framework.params import ConfigError
    from fsw.settings import DEFAULT_CONFIG, load_settings, load_stereo_calibration
    from hil_sim.lab.perception_eval import edge_pass_poses, pit_view_poses
    from hil_sim.render import StereoRenderer
    from hil_sim.world import load_scenario

    if args.repeats < 1 or not 0.0 <= args.range_m[0] < args.range_m[1]:
        print("safer-hil bench perception: --repeats must be >= 1 and --range-m MIN < MAX",
              file=sys.stderr)
        return 2
    try:
        cfg = load_settings(args.config or DEFAULT_CONFIG)
        world = load_scenario(args.scenario, args.seed)
    except (ConfigError, ValueError) as err:
        print(f"safer-hil bench perception: {err}", file=sys.stderr)
        return 2
    grid = MapGrid.from_config(world.map_grid)
    rend = StereoRenderer(world, cfg.camera, world.noise_sigma, seed=args.seed)
    bench = _bench_config(cfg, world)
    matcher = _pipeline(bench).matcher
    pose = pit_view_poses(world, cfg.mast, 1)[0]
    left, right = rend.render(pose)
    cam = cfg.camera
    print(f"scenario {world.name} seed {world.seed}, camera {cam.width_px}x{cam.height_px}, "
          f"SGBM {cfg.stereo.mode} {cfg.stereo.num_disparities_px} disparities, "
          f"map {grid.nx}x{grid.ny} cells of {100 * grid.cell:g} cm; medians of {args.repeats}")

    stages = _stage_ms(bench, _frame(left, right, pose), args.repeats)
    points = _pipeline(bench).merge_view(_frame(left, right, pose)).merge.points_in
    print(f"stereo                {stages['stereo']:8.1f} ms per pair  ({points} points; the pipeline's "
          "stereo stage: SGBM in bands, filters, triangulation with covariance)")
    cal = load_stereo_calibration(cfg)
    if cal is None:
        print("rectification         (no [camera] calibration_file configured)")
    else:
        rect = Rectifier(cal, cam.K)  # the maps are built once, as at flight start-up
        ms = _median_ms(lambda: rect.rectify(left, right), max(args.repeats, 20))
        verdict = "meets" if ms <= RECTIFY_TARGET_MS else "MISSES"
        print(f"rectification         {ms:8.2f} ms per pair  (cv2.remap, CV_16SC2 maps; {verdict} the "
              f"{RECTIFY_TARGET_MS:g} ms target)")
    slices = _slice_ms(matcher, left, right, args.repeats)
    print(f"stereo slices         {np.median(slices):8.1f} ms median, {max(slices):.1f} ms longest "
          f"({len(slices) // args.repeats} slices per pair: SGBM, correlation, refinement bands)")

    ms = stages["merge"]
    print(f"merge one view        {ms:8.1f} ms  = {points / ms / 1e3:6.2f} M points/s (world covariance "
          "and fusion into an empty map)")
    rng = np.random.default_rng(0)
    X, Y = grid.centers()
    pick = rng.integers(0, grid.nx * grid.ny, BATCH_POINTS)
    batch = np.column_stack([X.ravel()[pick] + rng.uniform(-0.015, 0.015, BATCH_POINTS),
                             Y.ravel()[pick] + rng.uniform(-0.015, 0.015, BATCH_POINTS),
                             rng.normal(0.0, 0.01, BATCH_POINTS)])
    cov = np.zeros((BATCH_POINTS, 3, 3))
    cov[:, 0, 0] = cov[:, 1, 1] = 1e-5
    cov[:, 2, 2] = 1e-4

    def merge_batch() -> None:
        ElevationMap(grid, cfg.fusion).merge(batch, cov=cov)

    ms = _median_ms(merge_batch, args.repeats)
    verdict = "meets" if ms <= MERGE_TARGET_MS else "MISSES"
    print(f"merge {BATCH_POINTS} points {ms:8.1f} ms  = {BATCH_POINTS / ms / 1e3:6.2f} M points/s "
          f"({verdict} the {MERGE_TARGET_MS:g} ms target)")

    passing = _pipeline(bench)
    for i, p in enumerate(edge_pass_poses(world, cfg.mast)):
        passing.merge_view(_frame(*rend.render(p), p, i))
    emap = passing.map
    seed_xy = world.rover_start[:2]

    def fit() -> None:
        cells = edge_cells(emap, world.plateau_z, seed_xy, cfg.edge)
        poly = fit_polygon(emap, cells, cfg.edge)
        fit_line(cells, seed_xy)
        edge_path(poly, cfg.edge.setback_m, cfg.edge.path_spacing_m)

    ms = _median_ms(fit, args.repeats)
    cells = edge_cells(emap, world.plateau_z, seed_xy, cfg.edge)
    poly = fit_polygon(emap, cells, cfg.edge)
    print(f"edge fit              {ms:8.1f} ms  ({len(cells.points_xy)} edge points, "
          f"{poly.lines.length:.2f} m of polygon edge, after {len(edge_pass_poses(world, cfg.mast))}"
          " views)")

    with tempfile.TemporaryDirectory() as tmp:
        store = MapStore(checkpoint.CheckpointConfig(directory=tmp, keep=3))
        seq = iter(range(10**6))
        ms_enc = _median_ms(lambda: checkpoint.encode(emap, 0, 0.0), args.repeats)
        ms_save = _median_ms(lambda: store.save(emap, next(seq), 0.0), args.repeats)
        ms_load = _median_ms(store.load_latest, args.repeats)
        size = store.paths()[-1].stat().st_size
    print(f"checkpoint            {ms_save:8.1f} ms save (encode {ms_enc:.1f} ms, fsync, rename), "
          f"{ms_load:.1f} ms load+verify, {size / 1024:.0f} KiB")

    if args.plot:
        return _calibration(args, bench, world, grid, rend)
    return 0


def _slice_ms(matcher, left, right, repeats: int) -> list[float]:  # type: ignore[no-untyped-def]
    """Wall time of each slice of the slack-job matcher (``match_steps``), ``repeats`` pairs."""
    import time

    out = []
    for _ in range(repeats):
        gen = matcher.match_steps(left, right)
        t0 = time.perf_counter()
        while True:
            try:
                next(gen)
            except StopIteration:
                out.append(1e3 * (time.perf_counter() - t0))
                break
            t1 = time.perf_counter()
            out.append(1e3 * (t1 - t0))
            t0 = t1
    return out


def _bench_config(cfg, world):  # type: ignore[no-untyped-def]
    """The flight configuration for the bench's views: the ideal renderer's pairs (no
    rectification), the true poses (registration off), the scenario's map grid."""
    import dataclasses

    return dataclasses.replace(cfg, map=world.map_grid,
                               camera=dataclasses.replace(cfg.camera, calibration_file=""),
                               registration=dataclasses.replace(cfg.registration, enabled=False))


def _pipeline(bench):  # type: ignore[no-untyped-def]
    """A fresh sensing pipeline (the flight's, ``fsw.core.pipeline``) on an empty map."""
    from fsw.core.pipeline import SensingPipeline

    return SensingPipeline(bench, None)


def _frame(left, right, pose, view_id: int = 0, cov=None):  # type: ignore[no-untyped-def]
    """A camera frame at ``pose`` (covariance ``cov``; None: exact)."""
    import numpy as np

    from fsw.tasks.messages import CameraFrame

    return CameraFrame(view_id, 0.0, left, right, pose, np.zeros((6, 6)) if cov is None else cov)


def _stage_ms(bench, frame, repeats: int) -> dict[str, float]:  # type: ignore[no-untyped-def]
    """Median CPU ms per stage of the pipeline merging ``frame`` into a fresh map, after a warm-up."""
    import statistics

    from hil_sim.lab.bench.bench_cycle import StageClock

    runs = []
    for _ in range(repeats + 1):
        clock = StageClock()
        gen = _pipeline(bench).merge_view_steps(frame, clock)
        for _ in gen:
            pass
        clock.stop()
        runs.append(clock.seconds)
    return {k: 1e3 * statistics.median(r[k] for r in runs[1:]) for k in runs[0]}


def _calibration(args, bench, world, grid, rend) -> int:  # type: ignore[no-untyped-def]
    import math
    import sys
    from pathlib import Path

    import numpy as np

    from fsw.core.geometry import CameraPose
    from fsw.core.localization.localization import so3_exp
    from fsw.core.map.elevation_map import ElevationMap
    from fsw.core.pipeline import RegisteredPose
    from fsw.core.registration.registration import Registration
    from fsw.core.steps import run_to_end
    from hil_sim.lab.perception_eval import (
        calibration,
        calibration_figure,
        cell_range_m,
        pit_view_poses,
    )

    truth = world.truth_on_grid(grid)
    panels = []

    def panel(title: str, emap: ElevationMap, sel: np.ndarray) -> None:
        ok = sel & np.isfinite(truth) & emap.mapped
        panels.append((f"{world.name}: {title}", emap.z[ok] - truth[ok], np.sqrt(emap.var[ok])))

    pose = pit_view_poses(world, bench.mast, 1)[0]
    left, right = rend.render(pose)
    single = _pipeline(bench)
    single.merge_view(_frame(left, right, pose))
    one = single.map
    r = cell_range_m(grid, truth, pose)
    r0, r1 = args.range_m
    near = (r >= r0) & (r <= r1)
    print(f"calibration (cells at {r0:g}-{r1:g} m):")
    print(f"  one view, true pose: {calibration(one.z, one.var, truth, one.mapped & near).line()}")
    panel(f"one view, true pose ({r0:g}-{r1:g} m)", one, near)

    # the pose term: the same view seen from poses drawn from a pose covariance
    S = np.diag([math.radians(0.2) ** 2] * 3 + [0.01**2] * 3)
    pts = single.matcher.points(left, right)  # the view in the camera frame
    rng = np.random.default_rng(args.seed)
    errs, sigs = [], []
    for _ in range(25):
        dx = np.sqrt(np.diag(S)) * rng.normal(size=6)
        est = RegisteredPose(Registration("off"), CameraPose(so3_exp(dx[:3]) @ pose.R, pose.t + dx[3:]), S, None)
        drawn = _pipeline(bench)  # the view merged from the drawn pose, with its covariance
        run_to_end(drawn.fuse_steps(est, run_to_end(drawn.world_parts_steps(est, pts))))
        m = drawn.map
        ok = m.mapped & near & np.isfinite(truth)
        errs.append(m.z[ok] - truth[ok])
        sigs.append(np.sqrt(m.var[ok]))
    err, sig = np.concatenate(errs), np.concatenate(sigs)
    print(f"  one view, pose sigma 0.2 deg / 1 cm, 25 draws: RMS error "
          f"{100 * np.sqrt(np.mean(err**2)):.2f} cm, |err| <= 2 sigma for "
          f"{100 * np.mean(np.abs(err) <= 2 * sig):.1f} % of {err.size} cell-draws")
    panels.append((f"{world.name}: one view, pose 0.2 deg / 1 cm (25 draws)", err, sig))

    fusing = _pipeline(bench)
    masks = []
    for i, p in enumerate(pit_view_poses(world, bench.mast, 10, seed=1)):
        fr = _frame(*rend.render(p), p, i)
        alone = _pipeline(bench)
        alone.merge_view(fr)
        m = alone.map
        fusing.merge_view(fr)
        rr = cell_range_m(grid, truth, p)
        masks.append(m.mapped & (rr >= r0) & (rr <= r1))
        print(f"  view {i} of 10: {calibration(m.z, m.var, truth, masks[-1]).line()}")
    fused = fusing.map
    common = np.all(masks, axis=0)
    print(f"  10 views fused: {calibration(fused.z, fused.var, truth, common).line()}")
    panel("10 views fused (cells seen by all)", fused, common)
    try:
        Path(args.plot).parent.mkdir(parents=True, exist_ok=True)
        calibration_figure(args.plot, panels)
    except (OSError, ValueError) as err:
        print(f"safer-hil bench perception: cannot write {args.plot}: {err}", file=sys.stderr)
        return 2
    print(f"wrote {args.plot}")
    return 0
