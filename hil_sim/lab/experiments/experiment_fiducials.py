"""``safer-hil experiment fiducials``: relative localization of the Cliff-bot against range.

The RECON-bot localizes the Cliff-bot from its ArUco markers (docs/algorithm.md §5, §8:
``fsw.core.localization.fiducials.CliffbotLocalizer``, the flight's code). For each range
(metres from the mast camera) the Cliff-bot is placed ``--poses`` times on the scenario's
ground at a random bearing below the plateau, turned a random ``+-60`` deg away from facing
the RECON-bot; the mast aims at it, the bench renders the stereo pair (sensor noise of the
scenario, a new noise draw per pose) and the localizer solves the body pose. Per range:
fixes obtained, median and worst position error (cm) and heading error (deg), and the
fraction of fixes whose NEES (6-dof pose error normalised by the fix's own covariance) is
within the chi-square 95 % bound (12.59). A fix from one marker whose mirror pose fits
nearly as well is refused (NO_FIX, ``[localization] fiducial_ambiguity_ratio``); the table
counts those refusals and the worst error the refused fixes would have had.

Each range runs in its own process (``--jobs``), seeded by ``--seed`` and the range's index.

The camera pose is given exactly (the mast's own pose error is not in these figures: the
flight adds it to the fix's covariance, ``_compose``). Writes OUT/fiducials.csv and
OUT/fiducials.md and prints the table.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import math
import sys
from pathlib import Path
from typing import Any

HELP = "relative localization of the Cliff-bot by its fiducials: error and NEES against range"
CHI2_95_6DOF = 12.5916


def add_arguments(p: argparse.ArgumentParser) -> None:
    from fsw.settings import DEFAULT_CONFIG

    p.add_argument("--scenario", default="cliff-team?face_slope_deg=60&drop_m=3",
                   help="scenario spec (the Cliff-bot is placed on its ground)")
    p.add_argument("--ranges", default="2,3,4,5,6,8,10", help="comma-separated ranges, metres")
    p.add_argument("--poses", type=int, default=8, help="Cliff-bot placements per range")
    p.add_argument("--seed", type=int, default=0, help="seed of the placements and the sensor noise")
    p.add_argument("--config", default=str(DEFAULT_CONFIG), help="flight configuration (TOML)")
    p.add_argument("--out", type=Path, default=Path("out/fiducials"), help="output directory")
    p.add_argument("--jobs", type=int, default=1, help="ranges run in parallel (processes)")


def run(args: argparse.Namespace) -> int:
    from concurrent.futures import ProcessPoolExecutor, as_completed

    import numpy as np

    from fsw.framework.params import ConfigError
    from fsw.settings import load_settings
    from hil_sim.lab.results import command_line, write_results
    from hil_sim.world import ScenarioError, load_scenario

    me = "safer-hil experiment fiducials"
    try:
        ranges = [float(r) for r in args.ranges.split(",") if r.strip()]
    except ValueError:
        print(f"{me}: --ranges must be comma-separated numbers", file=sys.stderr)
        return 2
    if not ranges or any(not (0.5 <= r <= 50.0) for r in ranges) or args.poses < 1 or args.jobs < 1:
        print(f"{me}: ranges must lie in 0.5..50 m, --poses and --jobs must be >= 1", file=sys.stderr)
        return 2
    try:
        load_settings(args.config)
        load_scenario(args.scenario, args.seed)
    except (ConfigError, ScenarioError, ValueError) as exc:
        print(f"{me}: {exc}", file=sys.stderr)
        return 2
    rows: list[dict[str, Any]] = []
    with ProcessPoolExecutor(max_workers=args.jobs) as pool:
        futs = {pool.submit(range_rows, args.scenario, args.seed, args.config, k, r, args.poses): r
                for k, r in enumerate(ranges)}
        for n, fut in enumerate(as_completed(futs), 1):
            got = fut.result()
            rows.extend(got)
            print(f"[{n}/{len(ranges)}] {futs[fut]:g} m: {sum(r['fix'] for r in got)} fixes of {len(got)}",
                  file=sys.stderr, flush=True)
    rows.sort(key=lambda r: (r["range_m"], r["pose"]))
    args.out.mkdir(parents=True, exist_ok=True)
    keys = ["range_m", "pose", "true_range_m", "fix", "pos_err_cm", "yaw_err_deg", "nees", "markers", "ambiguous",
            "ambiguous_pos_err_cm", "ambiguous_yaw_err_deg"]
    with open(args.out / "fiducials.csv", "w", newline="") as fh:
        wr = csv.DictWriter(fh, fieldnames=keys)
        wr.writeheader()
        wr.writerows(rows)
    lines = ["| range (m) | placed | fixes | position error median / worst (cm) | heading error median / "
             "worst (deg) | NEES within chi2 95 % | refused as ambiguous (their worst error, cm / deg) |",
             "|---|---|---|---|---|---|---|"]
    for r in ranges:
        sel = [row for row in rows if row["range_m"] == r]
        fx = [row for row in sel if row["fix"]]
        amb = [row for row in sel if row["ambiguous"]]
        amb_s = (f"{len(amb)} ({max(a['ambiguous_pos_err_cm'] for a in amb):.2f} / "
                 f"{max(a['ambiguous_yaw_err_deg'] for a in amb):.2f})" if amb else "0")
        if not fx:
            lines.append(f"| {r:g} | {len(sel)} | 0 | - | - | - | {amb_s} |")
            continue
        pe = np.array([row["pos_err_cm"] for row in fx])
        ye = np.array([row["yaw_err_deg"] for row in fx])
        ok = np.mean([row["nees"] <= CHI2_95_6DOF for row in fx])
        lines.append(f"| {r:g} | {len(sel)} | {len(fx)} | {np.median(pe):.2f} / {pe.max():.2f} | "
                     f"{np.median(ye):.2f} / {ye.max():.2f} | {100 * ok:.0f} % | {amb_s} |")
    fx_all = [row for row in rows if row["fix"]]
    within = np.mean([row["nees"] <= CHI2_95_6DOF for row in fx_all]) if fx_all else float("nan")
    table = "\n".join(lines)
    report = (f"Scenario `{args.scenario}`, seed {args.seed}, {args.poses} placements per range; the camera "
              f"pose given exactly. NEES within the chi2 95 % bound over all {len(fx_all)} fixes: "
              f"{100 * within:.0f} %.\n\n{table}\n")
    (args.out / "fiducials.md").write_text(f"# Relative localization against range\n\n{report}")
    write_results("fiducials", command_line("fiducials"), report)
    print(table)
    return 0


def range_rows(scenario: str, seed: int, config: str, index: int, r: float, poses: int) -> list[dict[str, Any]]:
    """``poses`` placements of the Cliff-bot at range ``r`` (one process; seeded by ``seed`` and
    ``index``): one row each."""
    import numpy as np

    from fsw.core.geometry import camera_pose_from_rover, point_mast
    from fsw.core.localization.fiducials import CliffbotLocalizer
    from fsw.core.localization.localization import PoseEstimate
    from fsw.settings import load_settings
    from hil_sim.render import StereoRenderer
    from hil_sim.world import load_scenario
    from hil_sim.world.cliffbot import build_cliffbot

    cfg = load_settings(config)
    world = load_scenario(scenario, seed)
    rng = np.random.default_rng([seed, 55, index])
    loc = CliffbotLocalizer(cfg.localization, cfg.cliffbot, cfg.camera.K, cfg.camera.baseline_m)
    # the same localizer without the ambiguity refusal: what a refused fix would have been
    loose = CliffbotLocalizer(dataclasses.replace(cfg.localization, fiducial_ambiguity_ratio=1.0), cfg.cliffbot,
                              cfg.camera.K, cfg.camera.baseline_m)
    cb0 = world.cliffbot
    rover = world.rover_start
    base = camera_pose_from_rover(rover, (0.0, 0.0, 0.3), cfg.mast).t
    rows: list[dict[str, Any]] = []
    exact = np.zeros((6, 6))
    for _ in range(50 * poses):
        if len(rows) == poses:
            break
        bearing = rover[2] + math.radians(rng.uniform(-85.0, -5.0))  # the drop is on the right
        horiz = math.sqrt(max(r * r - 1.0, 0.25))
        x, y = base[0] + horiz * math.cos(bearing), base[1] + horiz * math.sin(bearing)
        zg = float(world.ground_at(x, y))
        if not math.isfinite(zg):
            continue
        horiz = math.sqrt(max(r * r - (base[2] - zg) ** 2, 0.25))
        x, y = base[0] + horiz * math.cos(bearing), base[1] + horiz * math.sin(bearing)
        zg = float(world.ground_at(x, y))
        if not math.isfinite(zg):
            continue
        yaw = math.atan2(base[1] - y, base[0] - x) + math.radians(rng.uniform(-60.0, 60.0))
        cb = build_cliffbot(x, y, zg, yaw, size_m=(cb0.length_m, cb0.width_m, cb0.height_m),
                            marker_size_m=cfg.cliffbot.marker_size_m, seed=seed)
        w = dataclasses.replace(world, cliffbot=cb)
        joints, reachable = point_mast(rover, (x, y, zg + 0.25), cfg.mast, 0.3)
        if not reachable:
            continue  # the mast cannot point there
        pose = camera_pose_from_rover(rover, joints, cfg.mast)
        rend = StereoRenderer(w, cfg.camera, world.noise_sigma, seed=int(rng.integers(1 << 30)))
        left, right = rend.render(pose)
        row: dict[str, Any] = {"range_m": r, "pose": len(rows), "true_range_m": float(np.linalg.norm(cb.t - pose.t)),
                               "fix": 0, "ambiguous": 0}
        rows.append(row)

        est = loc.locate(left, PoseEstimate(pose, exact), right)
        if est is not None:
            pe, ye, nees = _errors(est, cb)
            row.update(fix=1, pos_err_cm=pe, yaw_err_deg=ye, nees=nees, markers=len(est.marker_ids))
            continue
        alt = loose.locate(left, PoseEstimate(pose, exact), right)
        if alt is not None and alt.ambiguity < cfg.localization.fiducial_ambiguity_ratio:
            pe, ye, _ = _errors(alt, cb)
            row.update(ambiguous=1, ambiguous_pos_err_cm=pe, ambiguous_yaw_err_deg=ye, markers=len(alt.marker_ids))
    return rows


def _errors(est: Any, cb: Any) -> tuple[float, float, float]:
    """Position (cm) and heading (deg) error of a body estimate against the true Cliff-bot, and its NEES."""
    import numpy as np

    from fsw.core.localization.localization import so3_log

    e = np.concatenate([so3_log(est.R @ cb.R.T), est.t - cb.t])
    try:
        nees = float(e @ np.linalg.solve(est.cov, e))
    except np.linalg.LinAlgError:
        nees = math.inf
    dyaw = math.degrees(math.atan2(math.sin(est.yaw - cb.yaw), math.cos(est.yaw - cb.yaw)))
    return 100 * float(np.linalg.norm(est.t - cb.t)), abs(dyaw), nees
