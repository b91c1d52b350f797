"""``safer-hil experiment reduction``: Figures 12 and 13 and the hazard check of the map codec.

docs/algorithm.md §6 (and "Mars terrain statistics"); docs/quadtree.md. The sets of maps:

* ``--maps`` Viking-model Mars maps (``hil_sim.world.mars.viking_heightfield``, rock coverage
  ``k`` spread over Viking Lander 1 to 2, 0.07 .. 0.16), each reduced for the wheel diameters
  that make ``dH = (max - min elevation) / wheel diameter`` take the values ``--dh``
  (Figure 12), with the configured codec (hazard-preserving by default) and with the height
  bound alone (``hazard = false``, the rule before issue 25);
* the real DEM sample (``hil_sim.world.sample_dem``: USGS Jacksboro fault at rover scale, with
  a 1 m cliff drop), unless ``--no-dem``;
* mission maps: ``--missions`` runs a short mission (``--mission-steps`` imaging steps,
  method ``--mission-method``) on each scenario spec (``terrain:N`` is the seeded terrain
  family) and takes the RECON-bot's flight map at its end (fused stereo, holes, as the radio
  task encodes it); ``--map-files`` reads maps saved elsewhere (map checkpoints, or ``.npy``
  on the ``[map]`` grid);
* mission-like maps of ``--terrains``: the world's truth on the flight map grid, plus
  ``--noise-m`` of Gaussian height noise, unknown where the ground is textureless.

Per map (the Viking maps at ``--compare-dh``, the others with the receiving rover's wheel,
``[codec] receiver_wheel_diameter_m``): the obstacles (connected cells whose relief, the white
top-hat over a ``relief_disc_m`` disc, is >= one wheel diameter ``w``) and those >= ``2w`` in
the input, how many the decoded map keeps (decoded relief, max over the footprint, >= ``w``),
the worst height error and the worst relief loss against the bounds the container states
(``safer-map info``), the position error, the step cells (a step >= ``w`` within one wheel
diameter: the cliff edge) kept and the largest drop before and after, the bytes, and the bytes
of JPEG-LS near-lossless (imagecodecs, 1 mm input grid) at the largest NEAR whose decoded map
keeps the same obstacles and the same height bound (bisection over NEAR), and at the height
bound alone.

Maps are processed in ``--jobs`` processes; every map is seeded, so the tables do not depend
on ``--jobs``. Writes ``reduction.csv``, ``maps.csv``, ``report.md`` and the figures into
``--out``, and the result file ``docs/results/reduction.md`` with its figures
(``hil_sim.lab.results``).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

from hil_sim.lab.results import command_line, write_results

HELP = "Figures 12/13 and the hazard check: obstacles kept, bytes against JPEG-LS (issue 25)"
DEFAULT_TERRAINS = "terrain:0,terrain:1,terrain:2,terrain:3,terrain:4,terrain:5,terrain:6,terrain:7," \
    "terrain:8,terrain:9,lab,cliff,mars"
DEFAULT_MISSIONS = ",".join(f"terrain:{i}" for i in range(10))


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--maps", type=int, default=32, help="number of Viking-model Mars maps")
    p.add_argument("--size", type=int, default=512, help="Mars map side, cells")
    p.add_argument("--cell-m", type=float, default=0.02, help="Mars map cell size, m")
    p.add_argument("--k-range", type=float, nargs=2, default=(0.07, 0.16), metavar=("LO", "HI"),
                   help="rock coverage k spread over this range (Viking Lander 1 .. 2)")
    p.add_argument("--dh", type=float, nargs="+", default=[1, 2, 3, 4, 6, 8, 12, 16],
                   help="terrain variation / wheel diameter values")
    p.add_argument("--compare-dh", type=float, default=8.0,
                   help="dH of the per-map hazard check and the JPEG-LS comparison")
    p.add_argument("--seed", type=int, default=0, help="seed of map 0 (map i uses seed + i)")
    p.add_argument("--missions", default=DEFAULT_MISSIONS,
                   help="comma-separated scenario specs to run a short mission on and take its map "
                   "(terrain:N = terrain family seed N); empty for none")
    p.add_argument("--mission-steps", type=int, default=4, help="imaging steps of each mission")
    p.add_argument("--mission-method", default="5", help="the missions' NBV method")
    p.add_argument("--map-files", type=Path, nargs="*", default=[],
                   help="mission maps saved elsewhere: map checkpoints, or .npy on the [map] grid")
    p.add_argument("--terrains", default=DEFAULT_TERRAINS,
                   help="comma-separated scenario specs for mission-like maps (truth + noise); empty for none")
    p.add_argument("--noise-m", type=float, default=0.015, help="height noise of the mission-like maps, m")
    p.add_argument("--no-dem", action="store_true", help="skip the real DEM sample")
    p.add_argument("--jobs", type=int, default=1, help="maps processed in parallel (processes)")
    p.add_argument("--config", default=None, help="flight config for [codec], [rover] (default config/fsw.toml)")
    p.add_argument("--out", type=Path, default=Path("out/experiments/reduction"), help="output dir")


def jpegls_for_hazards(z: Any, w: float, bound: float, cell_m: float, disc_m: float,
                       relief_threshold: Any = None) -> dict[str, Any]:
    """JPEG-LS near-lossless on a 1 mm grid: bytes at the largest NEAR that keeps the input's
    obstacles (all kept at >= w, as ours; and the issue's bar, >= 99 % of them and all >= 2w)
    within the height bound, and at the bound alone; obstacles read as ours are
    (``relief_threshold``: across the ground, ``check_obstacles``)."""
    import imagecodecs
    import numpy as np
    import zstandard

    from fsw.core.codec.hazard import check_obstacles, relief, step

    ref = (relief(z, cell_m, disc_m), step(z, cell_m, w))
    known = np.isfinite(z)
    zmin = float(z[known].min())
    span = float(z[known].max()) - zmin
    unit = max(0.001, span / 60000.0)
    fill = np.where(known, z, zmin)
    q = np.rint((fill - zmin) / unit).astype(np.uint16)
    mask_bytes = 0 if known.all() else len(zstandard.ZstdCompressor(level=19).compress(
        np.packbits(known).tobytes()))

    def trial(near: int) -> tuple[int, Any, float]:
        enc = imagecodecs.jpegls_encode(q, level=near)
        back = imagecodecs.jpegls_decode(enc).astype(np.float64) * unit + zmin
        zd = np.where(known, back, np.nan).astype(np.float32)
        err = float(np.abs(zd[known].astype(np.float64) - z[known]).max()) if known.any() else 0.0
        return len(enc) + mask_bytes, check_obstacles(z, zd, cell_m, w, disc_m, reference=ref,
                                                  relief_threshold=relief_threshold), err

    n_max = max(0, int(np.floor((bound - 0.5 * unit) / unit)))
    n_max = min(n_max, 255)
    b_max, c_max, e_max = trial(n_max)
    out: dict[str, Any] = {"jls_bound_bytes": b_max, "jls_bound_kept": c_max.kept,
                           "jls_bound_kept_2x": c_max.kept_2x, "jls_bound_near_mm": n_max * unit * 1e3}

    def largest(ok: Any) -> tuple[int, int]:
        """Largest NEAR (bisection, assuming monotone) whose decoded map passes ``ok``."""
        if ok(c_max, e_max):
            return n_max, b_max
        lo, hi = 0, n_max
        b0, _, _ = trial(0)
        best = (0, b0)
        while hi - lo > 1:
            mid = (lo + hi) // 2
            b, c, e = trial(mid)
            if ok(c, e):
                lo, best = mid, (mid, b)
            else:
                hi = mid
        return best

    def all_kept(c: Any, err: float) -> bool:
        return bool(c.kept == c.n and c.kept_2x == c.n_2x and err <= bound)

    def most_kept(c: Any, err: float) -> bool:  # the bar: >= 99 % of >= w, all >= 2w
        return bool(c.kept >= 0.99 * c.n and c.kept_2x == c.n_2x and err <= bound)

    for key, rule in (("jls_hazard", all_kept), ("jls_99", most_kept)):
        near, nbytes = largest(rule)
        out[f"{key}_bytes"] = nbytes
        out[f"{key}_near_mm"] = round(near * unit * 1e3, 2)
    return out


def _scenario(spec: str) -> tuple[str, int]:
    """``terrain:N`` -> (``terrain``, N); any other spec -> (spec, 0)."""
    if spec.startswith("terrain:"):
        return "terrain", int(spec.split(":", 1)[1])
    return spec, 0


def _mission_like(spec: str, noise_m: float) -> tuple[str, Any, float]:
    import numpy as np

    from fsw.core.geometry import MapGrid
    from hil_sim.world import load_scenario

    scenario, seed = _scenario(spec)
    w = load_scenario(scenario, seed=seed)
    grid = MapGrid.from_config(w.map_grid)
    z = w.truth_on_grid(grid)
    rng = np.random.default_rng([seed, 25])
    z = z + rng.normal(0.0, noise_m, z.shape)
    z[w.textureless_on_grid(grid)] = np.nan
    return spec, z.astype(np.float32), grid.cell


def _mission_map(spec: str, steps: int, method: str, out: Path) -> tuple[Any, float, str]:
    """Run a short mission on ``spec`` and return the RECON-bot's flight map at its end (NaN
    where unmapped, as the radio task encodes it), its cell size and the mission's end."""
    import numpy as np

    from hil_sim.mission.mission_run import RunSpec, run_mission

    scenario, seed = _scenario(spec)
    benches: list[Any] = []
    summary = run_mission(RunSpec(scenario, method, steps, seed, transmit=False, out=out),
                          on_bench=benches.append, mode="fresh")
    emap = benches[0].exe.tasks["perception"].map
    z = np.where(emap.mapped, emap.z, np.nan).astype(np.float32)
    return z, float(emap.grid.cell), str(summary.get("end_reason", ""))


def _map_file(path: Path, default_cell_m: float) -> tuple[Any, float]:
    """A map checkpoint (its grid's cell) or a 2-D ``.npy`` (``default_cell_m``); ValueError."""
    import numpy as np

    from fsw.core.map import checkpoint

    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise ValueError(f"{path}: cannot read ({exc.strerror or exc})") from None
    if raw.startswith(checkpoint.MAGIC):
        try:
            emap, _ = checkpoint.decode(raw)
        except checkpoint.CheckpointError as exc:
            raise ValueError(f"{path}: map checkpoint, unreadable: {exc}") from None
        return np.where(emap.mapped, emap.z, np.nan).astype(np.float32), float(emap.grid.cell)
    try:
        z = np.load(path, allow_pickle=False)
    except (OSError, ValueError) as exc:
        raise ValueError(f"{path}: neither a map checkpoint nor a .npy map ({exc})") from None
    if z.ndim != 2 or z.dtype.kind != "f" or np.isinf(z).any():
        raise ValueError(f"{path}: expected a 2-D float map (NaN = unknown), got {z.dtype} {z.shape}")
    return z.astype(np.float32), default_cell_m


def _across(z: Any, cell_m: float, threshold_m: float, codec: Any) -> Any:
    """The per-cell relief threshold a reduction with the relief hold reads its hazards by
    (relief across the ground, the container's ``hazard_across_ground``), or None: the
    obstacles are counted as the reduction promises to keep them."""
    from fsw.core.codec.hazard import disc
    from fsw.core.codec.relief_hold import relief_threshold

    if not (codec.hazard and codec.relief_ceiling):
        return None
    return relief_threshold(z, cell_m, threshold_m, disc(codec.relief_disc_m, cell_m))


def check_map(name: str, kind: str, z: Any, cell: float, wheel: float, dh: float | None, codec: Any,
              want_figure: bool = False) -> tuple[dict[str, Any], Any]:
    """The per-map hazard check (module docstring); with ``want_figure`` also the Figure 13
    data (original, decoded, wheel, cell, stats, title)."""
    import numpy as np

    from fsw.core.codec.hazard import check_obstacles, relief, step
    from fsw.core.codec.mapcodec import CodecConfig, decode_map, encode_map

    height_only = CodecConfig(**{**vars(codec), "hazard": False})
    enc = encode_map(z, cell_m=cell, wheel_diameter_m=wheel, cfg=codec)
    old = encode_map(z, cell_m=cell, wheel_diameter_m=wheel, cfg=height_only)
    dec, dec_old = decode_map(enc.data), decode_map(old.data)
    h = dec.header
    thr, step_disc = codec.hazard_relief_wheels * wheel, codec.step_disc_wheels * wheel
    across = _across(z, cell, thr, codec)
    c = check_obstacles(z, dec.z, cell, thr, codec.relief_disc_m, step_disc, relief_threshold=across)
    co = check_obstacles(z, dec_old.z, cell, thr, codec.relief_disc_m, step_disc, relief_threshold=across)
    known = np.isfinite(z)
    r0, r1 = relief(z, cell, codec.relief_disc_m), relief(dec.z, cell, codec.relief_disc_m)
    loss_any = float((r0 - r1)[known].max()) if known.any() else 0.0
    s0, s1 = step(z, cell, step_disc), step(dec.z, cell, step_disc)
    jls = jpegls_for_hazards(z, wheel, h.error_bound_m, cell, codec.relief_disc_m, across)
    row = {
        "map": name, "kind": kind, "cells": int(z.size), "known": int(known.sum()),
        "wheel_m": round(wheel, 4), "dH": dh, "obst": c.n, "kept": c.kept, "obst_2w": c.n_2x,
        "kept_2w": c.kept_2x, "kept_height_only": co.kept, "kept_2w_height_only": co.kept_2x,
        "max_error_m": enc.max_error_m, "bound_m": h.error_bound_m,
        "worst_peak_loss_m": round(c.worst_peak_loss_m, 4), "worst_relief_loss_m": round(c.worst_relief_loss_m, 4),
        "relief_loss_bound_m": h.relief_loss_hazard_m, "worst_relief_loss_any_m": round(loss_any, 4),
        "relief_loss_any_bound_m": h.relief_loss_any_m,
        "worst_peak_loss_height_only_m": round(co.worst_peak_loss_m, 4),
        "position_error_cells": c.position_error_cells, "new_obstacles": c.new_obstacles,
        "new_obstacles_height_only": co.new_obstacles,
        "step_cells": c.step_cells, "step_kept": round(c.step_kept, 4),
        "worst_step_loss_m": round(c.worst_step_loss_m, 4), "step_slack_m": h.step_slack_m,
        "step_kept_height_only": round(co.step_kept, 4),
        "max_step_m": round(float(np.nanmax(s0)), 4) if known.any() else 0.0,
        "max_step_decoded_m": round(float(np.nanmax(s1)), 4) if known.any() else 0.0,
        "bytes": len(enc.data), "bytes_height_only": len(old.data),
        "reduction": round(enc.tree.reduction_factor, 2), **jls}
    fig = None
    if want_figure:
        stats = {"reduction": enc.tree.reduction_factor, "bytes": len(enc.data), "max_error_m": enc.max_error_m}
        fig = (z, dec.z, wheel, cell, stats, name)
    return row, fig


def _viking_job(i: int, k: float, args: argparse.Namespace, dhs: list[float], codec: Any) -> dict[str, Any]:
    """Figure 12 rows of Viking map ``i`` and its hazard check at ``--compare-dh``."""
    from fsw.core.codec.hazard import check_obstacles
    from fsw.core.codec.mapcodec import CodecConfig, decode_map, encode_map
    from hil_sim.world.mars import viking_heightfield

    height_only = CodecConfig(**{**vars(codec), "hazard": False})
    z = viking_heightfield((args.size, args.size), args.cell_m, float(k), args.seed + i)
    relief_m = float(z.max() - z.min())
    rows: list[dict[str, Any]] = []
    out: dict[str, Any] = {"rows": rows, "map": None, "fig": None}
    for dh in dhs:
        wheel = relief_m / dh
        tic = time.process_time()
        enc = encode_map(z, cell_m=args.cell_m, wheel_diameter_m=wheel, cfg=codec)
        dt = time.process_time() - tic
        old = encode_map(z, cell_m=args.cell_m, wheel_diameter_m=wheel, cfg=height_only)
        dz = decode_map(enc.data).z
        c = check_obstacles(z, dz, args.cell_m, wheel, codec.relief_disc_m,
                            relief_threshold=_across(z, args.cell_m, wheel, codec))
        rows.append({"map": i, "k": round(float(k), 4), "seed": args.seed + i, "relief_m": round(relief_m, 4),
                     "dH": dh, "wheel_m": round(wheel, 5), "bound_m": codec.error_bound_wheels * wheel,
                     "leaves": enc.tree.n_leaves, "reduction": round(enc.tree.reduction_factor, 2),
                     "bytes": len(enc.data), "max_error_m": enc.max_error_m,
                     "rms_error_m": round(enc.rms_error_m, 6), "obst": c.n, "kept": c.kept,
                     "obst_2w": c.n_2x, "kept_2w": c.kept_2x,
                     "worst_relief_loss_m": round(c.worst_relief_loss_m, 5),
                     "encode_cpu_ms": round(dt * 1e3, 1),
                     "reduction_height_only": round(old.tree.reduction_factor, 2),
                     "bytes_height_only": len(old.data)})
        if dh == args.compare_dh:
            out["map"], out["fig"] = check_map(f"viking {i}", "viking", z, args.cell_m, wheel, dh, codec,
                                               want_figure=i == 0)
            if out["fig"] is not None:
                out["fig"] = (*out["fig"][:5], f"Viking map 0, dH = {dh:g}")
    out["label"] = f"viking {i} (k={k:.3f}, relief {relief_m:.2f} m)"
    return out


def _other_job(name: str, kind: str, source: Any, wheel: float, codec: Any, args: argparse.Namespace,
               default_cell_m: float) -> dict[str, Any]:
    """One DEM, mission, map-file or mission-like map: load (or fly) it and check it."""
    note = ""
    if kind == "dem":
        from hil_sim.world.sample_dem import jacksboro_dem

        z, cell = jacksboro_dem(0.03), 0.03
    elif kind == "mission":
        z, cell, note = _mission_map(source, args.mission_steps, args.mission_method,
                                     args.out / "missions" / source.replace(":", "_"))
    elif kind == "file":
        z, cell = _map_file(source, default_cell_m)
    else:
        _, z, cell = _mission_like(source, args.noise_m)
    row, fig = check_map(name, kind, z, cell, wheel, None, codec, want_figure=True)
    label = f"{name} ({kind}{', ' + note if note else ''})"
    return {"rows": [], "map": row, "fig": fig, "label": label}


def run(args: argparse.Namespace) -> int:
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor, as_completed

    import numpy as np

    from fsw.core.codec.mapcodec import CodecConfig
    from fsw.core.geometry import MapGridConfig, RoverConfig
    from fsw.framework.params import ConfigError, build, load_toml
    from fsw.settings import DEFAULT_CONFIG
    from hil_sim.lab.reduction_report import fig12, fig13, report_md, write_csv
    from hil_sim.world import load_scenario
    from hil_sim.world.config import ScenarioError

    me = "safer-hil: error:"
    cfg_path = args.config or str(DEFAULT_CONFIG)
    try:
        data = load_toml(cfg_path)
        codec = build(CodecConfig, data.get("codec", {}), cfg_path, "codec")
        rover = build(RoverConfig, data.get("rover", {}), cfg_path, "rover")
        grid_cfg = build(MapGridConfig, data.get("map", {}), cfg_path, "map")
    except ConfigError as exc:
        print(f"{me} {exc}", file=sys.stderr)
        return 2
    if args.maps < 0 or args.size < 8 or not all(d > 0 for d in args.dh) or args.noise_m < 0 \
            or args.jobs < 1 or args.mission_steps < 1:
        print(f"{me} need --maps >= 0, --size >= 8, positive --dh, --noise-m >= 0, --jobs >= 1, "
              "--mission-steps >= 1", file=sys.stderr)
        return 2
    terrains = [t.strip() for t in args.terrains.split(",") if t.strip()]
    missions = [t.strip() for t in args.missions.split(",") if t.strip()]
    for spec in terrains + missions:  # a bad spec: one line and exit 2, before any work
        try:
            load_scenario(*_scenario(spec))
        except (ScenarioError, ConfigError, ValueError) as exc:
            print(f"{me} scenario {spec!r}: {exc}", file=sys.stderr)
            return 2
    for path in args.map_files:
        try:
            _map_file(path, grid_cfg.cell_m)
        except ValueError as exc:
            print(f"{me} {exc}", file=sys.stderr)
            return 2
    args.out.mkdir(parents=True, exist_ok=True)
    wheel = codec.wheel_m(rover.wheel_diameter_m)  # the receiving rover's wheel
    ks = np.linspace(args.k_range[0], args.k_range[1], max(args.maps, 1))[:args.maps]
    dhs = sorted(set(args.dh) | {args.compare_dh})
    t0 = time.perf_counter()
    jobs: list[tuple[tuple[int, int], Any, tuple[Any, ...]]] = []  # (sort key, function, arguments)
    order = {"viking": 0, "dem": 1, "mission": 2, "file": 3, "mission-like": 4}
    for i, k in enumerate(ks):
        jobs.append(((0, i), _viking_job, (i, float(k), args, dhs, codec)))
    if not args.no_dem:
        jobs.append(((1, 0), _other_job, ("jacksboro", "dem", None, wheel, codec, args, grid_cfg.cell_m)))
    for j, spec in enumerate(missions):
        jobs.append(((2, j), _other_job, (f"mission {spec}", "mission", spec, wheel, codec, args, grid_cfg.cell_m)))
    for j, path in enumerate(args.map_files):
        jobs.append(((3, j), _other_job, (path.name, "file", path, wheel, codec, args, grid_cfg.cell_m)))
    for j, spec in enumerate(terrains):
        jobs.append(((4, j), _other_job, (spec, "mission-like", spec, wheel, codec, args, grid_cfg.cell_m)))
    jobs.sort(key=lambda j: (j[0][0] != order["mission"], j[0]))  # the missions, the longest, first
    results: dict[tuple[int, int], dict[str, Any]] = {}
    failed = 0

    def finished(key: tuple[int, int], get: Any) -> None:
        nonlocal failed
        try:
            results[key] = get()
        except Exception as exc:  # noqa: BLE001 - one failed map is reported, the rest go on
            failed += 1
            print(f"{me} job {key}: {type(exc).__name__}: {exc}", file=sys.stderr)
            return
        print(f"[{len(results) + failed}/{len(jobs)}] {results[key]['label']} "
              f"({time.perf_counter() - t0:.0f} s)", flush=True)

    if args.jobs == 1:  # in this process
        for key, fn, a in jobs:
            finished(key, lambda fn=fn, a=a: fn(*a))
    else:  # spawn, not fork: a forked child inherits OpenCV's thread pool without its threads and hangs
        with ProcessPoolExecutor(max_workers=args.jobs, mp_context=multiprocessing.get_context("spawn")) as pool:
            futs = {pool.submit(fn, *a): key for key, fn, a in jobs}
            for fut in as_completed(futs):
                finished(futs[fut], fut.result)
    done = [results[k] for k in sorted(results)]
    rows = [r for d in done for r in d["rows"]]
    per_map = [d["map"] for d in done if d["map"] is not None]
    figs: dict[str, Any] = {}
    for d in done:
        kind = d["map"]["kind"] if d["map"] is not None else ""
        fig_key = {"viking": "viking", "mission": "mission"}.get(kind, d["map"]["map"] if d["map"] else "")
        if d["fig"] is not None and fig_key not in figs:
            figs[fig_key] = d["fig"]

    write_csv(args.out / "reduction.csv", rows)
    write_csv(args.out / "maps.csv", per_map)
    written = ["reduction.csv", "maps.csv", "report.md"]
    if rows:
        fig12(rows, dhs, args.out / "fig12_reduction.png")
        written.append("fig12_reduction.png")
    fig_files = {"viking": "fig13_transmitted.png", "mission": "fig13_mission.png", "cliff": "fig13_cliff.png"}
    for fig_name, fname in fig_files.items():
        if fig_name in figs:
            fz, fzd, fw, fcell, fstats, ftitle = figs[fig_name]
            fig13(fz, fzd, fw, fcell, fstats, ftitle, args.out / fname, codec.relief_disc_m)
            written.append(fname)
    report = report_md(rows, per_map, dhs, codec, args)
    (args.out / "report.md").write_text(report)
    print(report)
    write_results("reduction", command_line("reduction"), report,
                  [args.out / f for f in ("fig12_reduction.png", *fig_files.values())])
    print(f"wrote {', '.join(str(args.out / f) for f in written)}")
    return 1 if failed else 0
