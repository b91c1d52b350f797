"""Where the information model's expected new cells part from the obtained ones (issue 30 item 3;
docs/algorithm.md §3.2, docs/nbv.md "Expected vs obtained new cells").

A planner's expected new cells for a view are ``stereo_return * sum of P_V`` over the unmapped
cells in its field of view and depth range (``fsw.core.planning.nbv``). For every rated view of a
finished mission, :func:`decompose_run` takes the map before and after the view and the pose the
view was taken from (the mission's recording, ``mission.mcap``: the flight's map after every
merge, its pose estimate and mast joints), and counts against the world's truth:

* ``ideal``: the unmapped, textured cells in the view's field and depth range that the TRUE
  terrain leaves visible from the camera (true ``P_V > 0.5``, ``nbv_scene.simulated_view``'s ideal
  view);
* ``pv_sum``: the model's ``sum of P_V`` over the unmapped cells at that pose (the occlusion
  model on the flight's map, its unknown cells from the prior); ``pv_sum / ideal`` is the
  occlusion model's share of the error;
* ``obtained`` (the view's own new cells), of which ``outside_fov`` lie outside the true field of
  view and depth range, ``hidden`` in view but not visible on the truth, ``textureless`` on
  textureless ground; ``obtained / ideal`` is the stereo's return, which the model takes as
  ``stereo_return``;
* ``what_if``: ``sum of P_V`` with other ``[nbv.visibility]`` values (the same views rated again).

The interest function is no part of the count (it ranks views only), so it is not split out.
No rendering and no stereo: a mission's views take seconds.
"""

from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from hil_sim.mission.mission_report import UNRATED_VIEWS

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class ViewSplit:
    """One rated view's expected and obtained new cells, split as the module docstring says."""

    step: int
    expected: float
    obtained: int
    pv_sum: float
    ideal: int
    obtained_ideal: int
    outside_fov: int
    hidden: int
    textureless: int
    what_if: dict[str, float] = field(default_factory=dict)


@dataclass(frozen=True)
class _Recording:
    maps: list[tuple[float, F64, F64 | None]]  # (time, elevation NaN unknown, variance)
    grid: tuple[float, float, float, int, int]  # x0, y0, cell, nx, ny
    poses: list[tuple[float, ...]]  # (time, x, y, z, roll, pitch, yaw, pan, tilt, lift)
    frames: list[float]  # capture times


def _rpy(q: Any) -> tuple[float, float, float]:
    w, x, y, z = q.w, q.x, q.y, q.z
    return (math.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y)),
            math.asin(max(-1.0, min(1.0, 2 * (w * y - z * x)))),
            math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z)))


def read_recording(path: Path, vehicle: str = "recon") -> _Recording:
    """The maps, poses and capture times of one vehicle in a mission recording (ValueError with
    one line if the file is damaged or truncated)."""
    try:
        return _read(path, vehicle)
    except Exception as exc:  # noqa: BLE001 - any damage to the file: one line, not a traceback
        raise ValueError(f"{path.name}: unreadable recording ({type(exc).__name__}: {str(exc)[:120]})") from None


def _read(path: Path, vehicle: str) -> _Recording:
    from mcap.reader import make_reader
    from mcap_protobuf.decoder import DecoderFactory

    maps: list[tuple[float, F64, F64 | None]] = []
    variance: dict[int, F64] = {}
    poses: list[tuple[float, ...]] = []
    frames: list[float] = []
    grid = (0.0, 0.0, 1.0, 0, 0)
    base, mast = f"{vehicle}/base_link", f"{vehicle}/mast"
    with path.open("rb") as fh:
        for _s, ch, m, msg in make_reader(fh, decoder_factories=[DecoderFactory()]).iter_decoded_messages():
            t = m.log_time * 1e-9
            if ch.topic in (f"/{vehicle}/map/elevation", f"/{vehicle}/map/variance"):
                a = np.frombuffer(msg.data, "<f4").reshape(-1, msg.column_count).astype(np.float64)
                if ch.topic.endswith("elevation"):
                    maps.append((m.log_time, a, None))
                    grid = (msg.pose.position.x, msg.pose.position.y, msg.cell_size.x, a.shape[1], a.shape[0])
                else:
                    variance[m.log_time] = a
            elif ch.topic == f"/{vehicle}/camera/left":
                frames.append(t)
            elif ch.topic == "/tf":
                tf = {f.child_frame_id: f for f in msg.transforms}
                if base in tf and mast in tf:
                    b, j = tf[base], tf[mast]
                    roll, pitch, yaw = _rpy(b.rotation)
                    _, minus_tilt, pan = _rpy(j.rotation)
                    poses.append((t, b.translation.x, b.translation.y, b.translation.z, roll, pitch, yaw,
                                  pan, -minus_tilt, j.translation.z))
    maps = [(ns * 1e-9, z, variance.get(int(ns))) for ns, z, _ in maps]
    return _Recording(maps, grid, poses, frames)


def rated_views(steps: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """The steps whose view the planner rated (``mission_report.prediction_ratios``' choice)."""
    return [s for s in steps if s.get("view", "") not in UNRATED_VIEWS
            and float(s.get("expected_new_cells", 0.0)) > 0.0 and int(s.get("view_new_cells", -1)) >= 0]


def decompose_run(run: Path, scenario: str, seed: int, config: str | None = None,
                  what_if: dict[str, dict[str, float]] | None = None) -> list[ViewSplit]:
    """:class:`ViewSplit` of every rated view of the mission in ``run`` (its ``summary.json`` and
    ``mission.mcap``) on the world ``scenario``/``seed``; ``what_if``: name -> ``[nbv.visibility]``
    values to rate the same views with. A view whose map update is not found is skipped."""
    from fsw.core.geometry import MapGrid, camera_pose_from_rover
    from fsw.core.map.elevation_map import ElevationMap
    from fsw.core.planning.nbv import predicted_visibility
    from fsw.core.planning.visibility import cell_points, in_view, terrain_from_heights
    from fsw.core.planning.visibility_kernel import pv_fast
    from fsw.settings import DEFAULT_CONFIG, load_settings
    from hil_sim.world import load_scenario

    summary = json.loads((run / "summary.json").read_text())
    cfg = load_settings(config or str(DEFAULT_CONFIG))
    cam, mast, vis = cfg.camera, cfg.mast, cfg.nbv.visibility
    rec = read_recording(run / str((summary.get("files") or {}).get("recording") or "mission.mcap"))
    if not rec.maps or not rec.poses:
        return []
    x0, y0, cell, nx, ny = rec.grid
    grid = MapGrid(x0, y0, cell, nx, ny)
    world = load_scenario(scenario, seed)
    sx, sy, syaw = world.rover_start
    frame = (float(sx), float(sy), float(syaw))
    truth = world.truth_on_grid(grid, frame)
    truth = np.where(np.isfinite(truth), truth, np.nanmin(truth))
    textured = ~world.textureless_on_grid(grid, frame)
    true_terrain = terrain_from_heights(truth, grid, 0.005)
    iy, ix = np.nonzero(np.ones(grid.shape, bool))
    true_points = cell_points(true_terrain, iy, ix)
    out: list[ViewSplit] = []
    used: set[int] = set()
    for st in rated_views(summary["steps"]):
        k = next((i for i in range(1, len(rec.maps)) if i not in used and int(
            (np.isfinite(rec.maps[i][1]) & ~np.isfinite(rec.maps[i - 1][1])).sum()) == int(st["view_new_cells"])), None)
        if k is None:
            continue
        used.add(k)
        t_map = rec.maps[k][0]
        shot = max((f for f in rec.frames if f <= t_map + 1e-6), default=t_map)
        t, x, y, z, roll, pitch, yaw, pan, tilt, lift = next(
            (p for p in reversed(rec.poses) if p[0] <= shot + 1e-6), rec.poses[0])
        pose = camera_pose_from_rover((x, y, yaw), (pan, tilt, lift), mast, ground_z_m=z, attitude=(roll, pitch))
        before, after, var = rec.maps[k - 1][1], rec.maps[k][1], rec.maps[k - 1][2]
        known = np.isfinite(before)
        emap = ElevationMap(grid, cfg.fusion)
        emap.z[:] = before
        emap.var[:] = np.where(known, var if var is not None else 1e-4, np.inf)
        emap.n[:] = known.astype(np.int32)
        pv_sum = float(predicted_visibility(emap, pose, cam, vis)[~known].sum())
        alt = {name: float(predicted_visibility(emap, pose, cam, _with(vis, kw))[~known].sum())
               for name, kw in (what_if or {}).items()}
        fov = in_view(pose, cam, true_points).reshape(grid.shape)
        jy, jx = np.nonzero(fov & ~known)
        seen = np.zeros(grid.shape, bool)
        c = (float(pose.t[0]), float(pose.t[1]), float(pose.t[2]))
        seen[jy, jx] = pv_fast(true_terrain, c, jy, jx, vis) > 0.5
        ideal = seen & textured & ~known
        new = np.isfinite(after) & ~known
        out.append(ViewSplit(int(st["step"]), float(st["expected_new_cells"]), int(new.sum()), pv_sum,
                             int(ideal.sum()), int((new & ideal).sum()), int((new & ~fov).sum()),
                             int((new & fov & ~seen).sum()), int((new & ~textured).sum()), alt))
    return out


def what_if_values(items: list[str]) -> dict[str, dict[str, float]]:
    """``KEY=VALUE`` items as ``{item: {key: value}}`` of ``[nbv.visibility]``; ValueError if bad."""
    from fsw.core.planning.visibility import VisibilityConfig

    known = {f.name for f in dataclasses.fields(VisibilityConfig)}
    out: dict[str, dict[str, float]] = {}
    for item in items:
        key, eq, value = item.partition("=")
        if not eq or key.strip() not in known:
            raise ValueError(f"{item!r} is not KEY=VALUE of [nbv.visibility] ({', '.join(sorted(known))})")
        out[item.strip()] = {key.strip(): float(value)}
    return out


def _with(vis: Any, values: dict[str, float]) -> Any:
    """``[nbv.visibility]`` with ``values`` replaced (ValueError on an unknown key)."""
    known = {f.name for f in dataclasses.fields(vis)}
    bad = sorted(set(values) - known)
    if bad:
        raise ValueError(f"[nbv.visibility] has no {', '.join(bad)}")
    return dataclasses.replace(vis, **values)


def split_table(views: list[ViewSplit], stereo_return: float) -> str:
    """Medians (10th-90th percentile) over the views of each part of the model's error, markdown."""
    if not views:
        return "no rated view to split\n"

    def a(f: Any) -> F64:
        return np.array([f(v) for v in views], np.float64)

    def q(x: F64) -> str:
        p10, med, p90 = np.percentile(x, [10, 50, 90])
        return f"{med:.2f} ({p10:.2f}-{p90:.2f})"

    ideal = np.maximum(a(lambda v: v.ideal), 1.0)
    obtained = np.maximum(a(lambda v: v.obtained), 1.0)
    rows = [
        ("obtained / expected (the planner's, at the pose it rated)",
         q(a(lambda v: v.obtained) / a(lambda v: v.expected)), "0.8-1.25"),
        (f"obtained / ({stereo_return:g} sum P_V) at the pose taken", q(a(lambda v: v.obtained)
                                                                        / (stereo_return * a(lambda v: v.pv_sum))),
         "0.8-1.25"),
        ("occlusion model: sum P_V / cells the truth leaves visible", q(a(lambda v: v.pv_sum) / ideal), "1"),
        ("stereo return: obtained / cells the truth leaves visible", q(a(lambda v: v.obtained) / ideal),
         f"{stereo_return:g} (stereo_return)"),
        ("of the obtained: outside the field of view and depth range", q(a(lambda v: v.outside_fov) / obtained), "0"),
        ("of the obtained: in view but hidden on the truth", q(a(lambda v: v.hidden) / obtained), "0"),
        ("of the obtained: on textureless ground", q(a(lambda v: v.textureless) / obtained), "0"),
    ]
    for name in views[0].what_if:
        rows.append((f"with {name}: obtained / ({stereo_return:g} sum P_V)",
                     q(a(lambda v, n=name: v.obtained) / (stereo_return * a(lambda v, n=name: v.what_if[n]))),
                     "0.8-1.25"))
        rows.append((f"with {name}: sum P_V / cells the truth leaves visible",
                     q(a(lambda v, n=name: v.what_if[n]) / ideal), "1"))
    lines = [f"The information model's error split over {len(views)} rated views (median, 10th-90th percentile):",
             "", "| part | measured | model's value |", "|---|---|---|"]
    lines += [f"| {what} | {value} | {target} |" for what, value, target in rows]
    return "\n".join(lines) + "\n"


# ``safer-hil experiment prediction``: the split over finished missions (their run directories).
HELP = "where the information model's expected new cells part from the obtained, over finished missions"


def add_arguments(p: Any) -> None:
    p.add_argument("runs", nargs="+", type=Path,
                   help="mission run directories (with summary.json and mission.mcap), or directories holding them")
    p.add_argument("--methods", default="3,4,5", help="the information methods whose missions are split")
    p.add_argument("--what-if", action="append", default=[], metavar="KEY=VALUE",
                   help="also rate the views with this [nbv.visibility] value (repeatable), e.g. prior_corr_len_m=2")
    p.add_argument("--jobs", type=int, default=2, help="missions split in parallel (processes)")


def mission_dirs(paths: list[Path]) -> list[Path]:
    """The mission run directories in ``paths`` (each one, or the ones directly inside it), sorted."""
    out: list[Path] = []
    for p in paths:
        if (p / "summary.json").is_file():
            out.append(p)
        elif p.is_dir():
            out += sorted(d for d in p.iterdir() if (d / "summary.json").is_file())
    return out


def _split_one(run: str, what_if: dict[str, dict[str, float]]) -> tuple[str, str, list[ViewSplit]]:
    s = json.loads((Path(run) / "summary.json").read_text())
    kind = str(s["scenario"]).split("?")[0].split(":")[0]
    return str(s["method"]), kind, decompose_run(Path(run), str(s["scenario"]), int(s["seed"]), what_if=what_if)


def run(args: Any) -> int:
    import multiprocessing
    import sys
    from concurrent.futures import ProcessPoolExecutor, as_completed

    from tqdm import tqdm

    from fsw.settings import DEFAULT_CONFIG, load_settings
    from hil_sim.lab.results import command_line, write_results

    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    try:
        what_if = what_if_values(args.what_if)
    except ValueError as err:
        print(f"safer-hil experiment prediction: --what-if: {err}", file=sys.stderr)
        return 2
    runs = mission_dirs(list(args.runs))
    runs = [r for r in runs if str(json.loads((r / "summary.json").read_text()).get("method")) in methods]
    if not runs or args.jobs < 1 or not methods:
        print("safer-hil experiment prediction: no finished mission of those methods in the directories given "
              "(or --jobs < 1)", file=sys.stderr)
        return 2
    by: dict[tuple[str, str], list[ViewSplit]] = {}
    failed: list[str] = []
    with (ProcessPoolExecutor(max_workers=args.jobs, mp_context=multiprocessing.get_context("spawn")) as pool,
          tqdm(total=len(runs), desc="prediction", unit="mission") as bar):
        futs = {pool.submit(_split_one, str(r), what_if): r for r in runs}
        for fut in as_completed(futs):
            try:
                m, kind, views = fut.result()
                by.setdefault((m, kind), []).extend(views)
            except Exception as exc:  # noqa: BLE001 - one unreadable mission is reported, the rest go on
                failed.append(f"{futs[fut].name}: {type(exc).__name__}: {exc}")
            bar.update()
    rho = load_settings(str(DEFAULT_CONFIG)).nbv.visibility.stereo_return
    lines = [f"{len(runs)} missions ({', '.join(sorted({r.parent.name + '/' for r in runs}))})", ""]
    for m in methods:
        kinds = sorted(k for mm, k in by if mm == m)
        for kind in [*kinds, *(["all"] if len(kinds) > 1 else [])]:
            views = [v for (mm, k), vs in sorted(by.items()) if mm == m and kind in (k, "all") for v in vs]
            lines += [f"## Method {m}, {kind}", "", split_table(views, rho)]
    if failed:
        lines += ["## Missions not split", ""] + [f"- {f}" for f in failed]
    md = "\n".join(lines) + "\n"
    print(md)
    write_results("prediction", command_line("prediction"), md)
    return 1 if failed else 0
