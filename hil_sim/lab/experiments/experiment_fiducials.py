"""``safer-hil experiment fiducials``: relative localization of the Cliff-bot against range.

The RECON-bot localizes the Cliff-bot from its ArUco markers (docs/algorithm.md §5, §8:
``fsw.core.localization.fiducials.CliffbotLocalizer``, the flight's code). For each range
(metres from the mast camera) the Cliff-bot is placed ``--poses`` times on the scenario's
ground at a random bearing below the plateau, turned a random ``+-60`` deg away from facing
the RECON-bot; the mast aims at it, the bench renders the stereo pair (sensor noise of the
scenario, a new noise draw per pose) and the localizer solves the body pose. Per range: the
placements where a Cliff-bot marker was detected and the largest one's side in the image (px),
fixes obtained, median and worst position error (cm) and heading error (deg), and the
fraction of fixes whose NEES (6-dof pose error normalised by the fix's own covariance) is
within the chi-square 95 % bound (12.59). A fix from one marker whose mirror pose fits
nearly as well is refused (NO_FIX, ``[localization] fiducial_ambiguity_ratio``); the table
counts those refusals and the worst error the refused fixes would have had.

Each range runs in its own process (``--jobs``), seeded by ``--seed`` and the range's index.

The camera pose is given exactly (the mast's own pose error is not in these figures: the
flight adds it to the fix's covariance, ``_compose``). Writes OUT/fiducials.csv and
OUT/fiducials.md and prints the table.

``--missions DIR`` measures the fix with the RECON-bot's pose as a mission leaves it instead
(docs/algorithm.md §5.2): for each team mission stored in DIR (``safer-hil experiment
team-mission --out DIR``; the summary's ``team.recon_pose``: the RECON-bot's estimate where it
ended, its covariance and the truth) the RECON-bot stands at its TRUE end pose and aims and
computes with its ESTIMATE, as the flight fixer does; the Cliff-bot is placed at each range
toward the face. Each placement gives two fixes from the same pair: from the rover's estimate
(with its covariance against its start, as the flight's fix without a plate:
``fsw.tasks.fixer.fix_pose.frame_extra``; a mission stored without ``frame_cov`` gives the
map-relative one) and through the Anchorbots' plates (both plates viewed once from where
it stands, ``fsw.core.localization.landmarks``). One process per mission (``--jobs``); writes
OUT/fiducials_missions.csv and ``docs/results/fiducials-missions.md``.
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
    p.add_argument("--jobs", type=int, default=1, help="ranges (missions) run in parallel (processes)")
    p.add_argument("--missions", type=Path, default=None, metavar="DIR",
                   help="the RECON-bot where each team mission stored in DIR ended (its own pose error), "
                        "fixes from its estimate and through the Anchorbots' plates")


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
    if args.missions is not None:
        return run_missions(args, ranges)
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
            "ambiguous_pos_err_cm", "ambiguous_yaw_err_deg", "marker_px"]
    with open(args.out / "fiducials.csv", "w", newline="") as fh:
        wr = csv.DictWriter(fh, fieldnames=keys)
        wr.writeheader()
        wr.writerows(rows)
    lines = ["| range (m) | placed | markers detected: placements, largest side median (px) | fixes | position "
             "error median / worst (cm) | heading error median / worst (deg) | NEES within chi2 95 % | refused as "
             "ambiguous (their worst error, cm / deg) |",
             "|---|---|---|---|---|---|---|---|"]
    for r in ranges:
        sel = [row for row in rows if row["range_m"] == r]
        fx = [row for row in sel if row["fix"]]
        amb = [row for row in sel if row["ambiguous"]]
        px = [row["marker_px"] for row in sel if row["marker_px"] > 0]
        px_s = f"{len(px)}, {np.median(px):.1f}" if px else "0, -"
        amb_s = (f"{len(amb)} ({max(a['ambiguous_pos_err_cm'] for a in amb):.2f} / "
                 f"{max(a['ambiguous_yaw_err_deg'] for a in amb):.2f})" if amb else "0")
        if not fx:
            lines.append(f"| {r:g} | {len(sel)} | {px_s} | 0 | - | - | - | {amb_s} |")
            continue
        pe = np.array([row["pos_err_cm"] for row in fx])
        ye = np.array([row["yaw_err_deg"] for row in fx])
        ok = np.mean([row["nees"] <= CHI2_95_6DOF for row in fx])
        lines.append(f"| {r:g} | {len(sel)} | {px_s} | {len(fx)} | {np.median(pe):.2f} / {pe.max():.2f} | "
                     f"{np.median(ye):.2f} / {ye.max():.2f} | {100 * ok:.0f} % | {amb_s} |")
    fx_all = [row for row in rows if row["fix"]]
    within = np.mean([row["nees"] <= CHI2_95_6DOF for row in fx_all]) if fx_all else float("nan")
    table = "\n".join(lines)
    f_px = load_settings(args.config).camera.K[0, 0]
    report = (f"Scenario `{args.scenario}`, seed {args.seed}, {args.poses} placements per range; the camera "
              f"pose given exactly. NEES within the chi2 95 % bound over all {len(fx_all)} fixes: "
              f"{100 * within:.0f} %. A marker's side in the image is at most f s / r ({f_px:.0f} px x "
              f"the marker's side over the range), less when it is seen obliquely.\n\n{table}\n")
    (args.out / "fiducials.md").write_text(f"# Relative localization against range\n\n{report}")
    write_results("fiducials", command_line("fiducials"), report)
    print(table)
    return 0


def _ground_at_range(world: Any, base: Any, bearing: float, r: float) -> tuple[float, float, float] | None:
    """A ground point at about slant range ``r`` from the camera centre ``base`` along ``bearing``
    (two passes: a first guess 1 m below the camera, then the ground's height there); None off
    the terrain."""
    zg = 0.0
    for drop in (1.0, None):
        dz = drop if drop is not None else base[2] - zg
        horiz = math.sqrt(max(r * r - dz ** 2, 0.25))
        x, y = base[0] + horiz * math.cos(bearing), base[1] + horiz * math.sin(bearing)
        zg = float(world.ground_at(x, y))
        if not math.isfinite(zg):
            return None
    return x, y, zg


def range_rows(scenario: str, seed: int, config: str, index: int, r: float, poses: int) -> list[dict[str, Any]]:
    """``poses`` placements of the Cliff-bot at range ``r`` (one process; seeded by ``seed`` and
    ``index``): one row each."""
    import numpy as np

    from fsw.core.geometry import camera_pose_from_rover, point_mast
    from fsw.core.localization.fiducials import CliffbotLocalizer, _side_px
    from fsw.core.localization.localization import PoseEstimate
    from fsw.settings import load_settings
    from hil_sim.render import StereoRenderer
    from hil_sim.world import load_scenario
    from hil_sim.world.cliffbot import build_cliffbot

    cfg = load_settings(config)
    world = load_scenario(scenario, seed)
    rng = np.random.default_rng([seed, 55, index])
    sensor = np.random.default_rng([seed, 57, index])  # the attitude sensor's noise (its own stream)
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
        spot = _ground_at_range(world, base, bearing, r)
        if spot is None:
            continue
        x, y, zg = spot
        yaw = math.atan2(base[1] - y, base[0] - x) + math.radians(rng.uniform(-60.0, 60.0))
        cb = build_cliffbot(x, y, zg, yaw, size_m=(cb0.length_m, cb0.width_m, cb0.height_m),
                            marker_size_m=cfg.cliffbot.marker_size_m, seed=seed)
        w = dataclasses.replace(world, cliffbot=cb)
        joints, reachable = point_mast(rover, (x, y, zg + 0.25), cfg.mast, 0.3)
        if not reachable:
            continue  # the mast cannot point there
        pose = camera_pose_from_rover(rover, joints, cfg.mast)
        if abs(float(np.linalg.norm(cb.t - pose.t)) - r) > 0.1 * r:
            continue  # no ground at that range along this bearing (the drop is deeper than r)
        rend = StereoRenderer(w, cfg.camera, world.noise_sigma, seed=int(rng.integers(1 << 30)))
        left, right = rend.render(pose)
        row: dict[str, Any] = {"range_m": r, "pose": len(rows), "true_range_m": float(np.linalg.norm(cb.t - pose.t)),
                               "fix": 0, "ambiguous": 0}
        rows.append(row)

        seen = [_side_px(c) for c in loc.detect_known(loc.corners, left)[0].values()]
        row["marker_px"] = max(seen) if seen else 0.0  # the largest Cliff-bot marker detected (0: none)
        # the level body's roll and pitch as its attitude sensor reads them: the request carries them
        attitude = _sensed_attitude(sensor)
        est = loc.locate(left, PoseEstimate(pose, exact), right, attitude)
        if est is not None:
            pe, ye, nees = _errors(est, cb)
            row.update(fix=1, pos_err_cm=pe, yaw_err_deg=ye, nees=nees, markers=len(est.marker_ids))
            continue
        alt = loose.locate(left, PoseEstimate(pose, exact), right)
        if alt is not None and alt.ambiguity < cfg.localization.fiducial_ambiguity_ratio:
            pe, ye, _ = _errors(alt, cb)
            row.update(ambiguous=1, ambiguous_pos_err_cm=pe, ambiguous_yaw_err_deg=ye, markers=len(alt.marker_ids))
    return rows


def _sensed_attitude(rng: Any) -> tuple[float, float]:
    """A level Cliff-bot's roll and pitch (rad) as its attitude sensor reads them (the bench's
    noise, ``CliffbotHw.imu_noise_deg``): what its fix request carries (docs/algorithm.md §5.3)."""
    from hil_sim.team.cliffbot_rig import CliffbotHw

    roll, pitch = (math.radians(float(v)) for v in CliffbotHw().imu_noise_deg * rng.standard_normal(2))
    return roll, pitch


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


MISSION_KEYS = ["seed", "range_m", "pose", "true_range_m", "raw_fix", "raw_pos_err_cm", "raw_yaw_err_deg", "raw_nees",
                "plates_fix", "plates_pos_err_cm", "plates_yaw_err_deg", "plates_nees"]


def run_missions(args: argparse.Namespace, ranges: list[float]) -> int:
    """``--missions``: the fix with the RECON-bot's pose as each stored team mission left it."""
    import json
    from concurrent.futures import ProcessPoolExecutor, as_completed

    import numpy as np

    from hil_sim.lab.results import command_line, write_results

    me = "safer-hil experiment fiducials"
    missions = []
    for d in sorted(args.missions.glob("seed*")):
        try:
            spec = json.loads((d / "run.json").read_text())["spec"]
            pose = json.loads((d / "summary.json").read_text())["team"]["recon_pose"]
        except (OSError, ValueError, KeyError, TypeError) as exc:
            print(f"{me}: {d}: no stored team mission with the RECON-bot's pose ({type(exc).__name__}: {exc})",
                  file=sys.stderr)
            continue
        if pose:
            missions.append((str(spec["scenario"]), int(spec["seed"]), pose))
    if not missions:
        print(f"{me}: {args.missions}: no team missions with team.recon_pose (run safer-hil experiment team-mission "
              f"--out {args.missions} first)", file=sys.stderr)
        return 2
    rows: list[dict[str, Any]] = []
    heads: list[dict[str, Any]] = []
    with ProcessPoolExecutor(max_workers=args.jobs) as pool:
        futs = {pool.submit(mission_rows, sc, sd, pose, args.config, ranges, args.poses, args.seed): sd
                for sc, sd, pose in missions}
        for n, fut in enumerate(as_completed(futs), 1):
            head, got = fut.result()
            heads.append(head)
            rows.extend(got)
            print(f"[{n}/{len(missions)}] mission seed {futs[fut]}: {sum(r['plates_fix'] for r in got)} fixes of "
                  f"{len(got)} placements", file=sys.stderr, flush=True)
    rows.sort(key=lambda r: (r["range_m"], r["seed"], r["pose"]))
    heads.sort(key=lambda h: h["seed"])
    args.out.mkdir(parents=True, exist_ok=True)
    with open(args.out / "fiducials_missions.csv", "w", newline="") as fh:
        wr = csv.DictWriter(fh, fieldnames=MISSION_KEYS, restval="")
        wr.writeheader()
        wr.writerows(rows)
    own = ["| mission seed | RECON-bot heading error (deg) | its sigma: on its map / against its start (deg) | "
           "place error (cm) | its sigma: on its map / against its start (cm) | plates resected |",
           "|---|---|---|---|---|---|"]
    for h in heads:
        star = "" if h["has_frame"] else " (not stored)"
        own.append(f"| {h['seed']} | {h['yaw_err_deg']:+.2f} | {h['yaw_sigma_deg']:.2f} / "
                   f"{h['frame_yaw_sigma_deg']:.2f}{star} | {h['pos_err_cm']:.1f} | {h['pos_sigma_cm']:.1f} / "
                   f"{h['frame_pos_sigma_cm']:.1f}{star} | {h['plates']} of 2 |")
    lines = ["| range (m) | placed | from the rover's estimate: fixes, position median / worst (cm), heading "
             "median / worst (deg), NEES within | through the plates: fixes, position median / worst (cm), "
             "heading median / worst (deg), NEES within |", "|---|---|---|---|"]

    def cell(sel: list[dict[str, Any]], k: str) -> str:
        fx = [r for r in sel if r[f"{k}_fix"]]
        if not fx:
            return "0"
        pe = np.array([r[f"{k}_pos_err_cm"] for r in fx])
        ye = np.array([r[f"{k}_yaw_err_deg"] for r in fx])
        ok = np.mean([r[f"{k}_nees"] <= CHI2_95_6DOF for r in fx])
        return (f"{len(fx)}: {np.median(pe):.2f} / {pe.max():.2f} cm, {np.median(ye):.2f} / {ye.max():.2f} deg, "
                f"{100 * ok:.0f} %")

    for r in ranges:
        sel = [row for row in rows if row["range_m"] == r]
        lines.append(f"| {r:g} | {len(sel)} | {cell(sel, 'raw')} | {cell(sel, 'plates')} |")
    within = {k: np.mean([row[f"{k}_nees"] <= CHI2_95_6DOF for row in rows if row[f"{k}_fix"]])
              if any(row[f"{k}_fix"] for row in rows) else float("nan") for k in ("raw", "plates")}
    report = (f"The RECON-bot where each of {len(heads)} team missions in `{args.missions.name}` ended (seeds "
              f"{', '.join(str(h['seed']) for h in heads)}), with its own pose error; {args.poses} placements of "
              f"the Cliff-bot per range and mission, toward the face. Each placement's pair gives a fix from the "
              f"rover's estimate and one through the Anchorbots' plates (docs/algorithm.md §5.2). NEES within the "
              f"chi2 95 % bound over all fixes: {100 * within['raw']:.0f} % from the estimate, "
              f"{100 * within['plates']:.0f} % through the plates.\n\n" + "\n".join(own) + "\n\n"
              + "\n".join(lines) + "\n")
    (args.out / "fiducials_missions.md").write_text(f"# Relative localization with the mission's pose\n\n{report}")
    write_results("fiducials-missions", command_line("fiducials"), report)
    print(report)
    return 0


def mission_rows(scenario: str, seed: int, recon: dict[str, Any], config: str, ranges: list[float], poses: int,
                 draw_seed: int) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """One mission's placements (a process of its own): the RECON-bot at its true end pose,
    computing with its estimate (team frame = world frame shifted by its start)."""
    import numpy as np

    from fsw.core.geometry import MapGrid, camera_pose_from_rover, point_mast
    from fsw.core.localization.fiducials import CliffbotLocalizer
    from fsw.core.localization.landmarks import Landmark, anchor_marker_corners, camera_from_landmarks
    from fsw.core.localization.localization import PoseEstimate
    from fsw.settings import load_settings
    from fsw.tasks.camera import camera_pose_covariance
    from fsw.tasks.fixer.fix_pose import frame_extra
    from fsw.tasks.messages import NavPose
    from hil_sim.render import StereoRenderer
    from hil_sim.team.cliffbot_rig import CliffbotRig
    from hil_sim.team.team_bench import TeamFrame
    from hil_sim.world import load_scenario
    from hil_sim.world.cliffbot import build_cliffbot

    cfg = load_settings(config)
    world = load_scenario(scenario, seed)
    grid = MapGrid.from_config(world.map_grid)
    rig = CliffbotRig(world, grid, cfg.tether, cfg.climber)
    x0, y0, yaw0 = (float(v) for v in world.rover_start)
    frame = TeamFrame(x0, y0, yaw0, 0.0)

    def to_world(p: list[float]) -> tuple[float, float, float]:
        xy = frame.to_world(np.array([p[:2]]))[0]
        return float(xy[0]), float(xy[1]), float(p[2]) + yaw0

    truth, est = to_world(recon["truth"]), to_world(recon["estimate"])
    c, s_ = math.cos(yaw0), math.sin(yaw0)
    rot = np.array([[c, -s_, 0.0], [s_, c, 0.0], [0.0, 0.0, 1.0]])
    nav_cov = rot @ np.asarray(recon["cov"], float) @ rot.T
    # against the start (the flight's fix without a plate carries it, frame_extra); older missions: the map's
    frame_cov = rot @ np.asarray(recon.get("frame_cov", recon["cov"]), float) @ rot.T
    rng = np.random.default_rng([draw_seed, 56, seed])
    sensor = np.random.default_rng([draw_seed, 58, seed])  # the attitude sensor's noise (its own stream)
    loc = CliffbotLocalizer(cfg.localization, cfg.cliffbot, cfg.camera.K, cfg.camera.baseline_m)
    js = math.radians(cfg.capture.joint_sigma_deg)
    seen = rig.world_now()
    plates = anchor_marker_corners(rig.anchors[0], rig.anchors[1], cfg.localization)

    def joints_to(target: Any) -> tuple[float, float, float] | None:
        joints, reachable = point_mast(est, target, cfg.mast, 0.3)  # aimed with its estimate, as the fixer does
        return joints if reachable else None

    def view(w: Any, joints: tuple[float, float, float]) -> tuple[Any, Any, Any, Any, Any, Any]:
        rend = StereoRenderer(w, cfg.camera, world.noise_sigma, seed=int(rng.integers(1 << 30)))
        true_pose = camera_pose_from_rover(truth, joints, cfg.mast)
        left, right = rend.render(true_pose)
        nav = NavPose(0.0, *est, nav_cov, joints, frame_cov=frame_cov)
        pred, pred_cov = camera_pose_covariance(nav, cfg.mast, (js, js, 0.002))
        q = camera_pose_covariance(NavPose(0.0, *est, np.zeros((3, 3)), joints), cfg.mast, (js, js, 0.002))[1]
        return left, right, pred, pred_cov + frame_extra(nav, cfg), q, true_pose

    landmarks = []
    for corners in plates.values():
        j = joints_to(corners.mean(axis=0))
        if j is None:
            continue
        left, right, pred, _, q, _ = view(seen, j)
        m = loc.resect(plates, left, right)
        if m is not None:
            landmarks.append(Landmark(m, pred, q))
    dyaw = math.degrees(math.atan2(math.sin(est[2] - truth[2]), math.cos(est[2] - truth[2])))
    head = {"seed": seed, "yaw_err_deg": dyaw, "yaw_sigma_deg": math.degrees(math.sqrt(max(nav_cov[2, 2], 0.0))),
            "pos_err_cm": 100 * math.hypot(est[0] - truth[0], est[1] - truth[1]),
            "pos_sigma_cm": 100 * math.sqrt(max(nav_cov[0, 0] + nav_cov[1, 1], 0.0)), "plates": len(landmarks),
            "frame_yaw_sigma_deg": math.degrees(math.sqrt(max(frame_cov[2, 2], 0.0))),
            "frame_pos_sigma_cm": 100 * math.sqrt(max(frame_cov[0, 0] + frame_cov[1, 1], 0.0)),
            "has_frame": "frame_cov" in recon}
    cb0 = world.cliffbot
    base = camera_pose_from_rover(truth, (0.0, 0.0, 0.3), cfg.mast).t
    rows: list[dict[str, Any]] = []
    for r in ranges:
        placed = 0
        for _ in range(50 * poses):
            if placed == poses:
                break
            bearing = math.radians(rng.uniform(-170.0, -10.0))  # toward the face (the drop lies along -y)
            spot = _ground_at_range(world, base, bearing, r)
            j = joints_to((spot[0], spot[1], spot[2] + 0.25)) if spot is not None else None
            if spot is None or j is None:
                continue
            x, y, zg = spot
            yaw = math.atan2(base[1] - y, base[0] - x) + math.radians(rng.uniform(-60.0, 60.0))
            cb = build_cliffbot(x, y, zg, yaw, size_m=(cb0.length_m, cb0.width_m, cb0.height_m),
                                marker_size_m=cfg.cliffbot.marker_size_m, seed=seed)
            if abs(float(np.linalg.norm(cb.t - camera_pose_from_rover(truth, j, cfg.mast).t)) - r) > 0.1 * r:
                continue  # no ground at that range along this bearing
            left, right, pred, pred_cov, q, true_pose = view(dataclasses.replace(seen, cliffbot=cb), j)
            row: dict[str, Any] = {"seed": seed, "range_m": r, "pose": placed,
                                   "true_range_m": float(np.linalg.norm(cb.t - true_pose.t)), "raw_fix": 0,
                                   "plates_fix": 0}
            placed += 1
            rows.append(row)
            cams = {"raw": PoseEstimate(pred, pred_cov), "plates": camera_from_landmarks(landmarks, pred, q)}
            for k, cam in cams.items():
                got = loc.locate(left, cam, right, _sensed_attitude(sensor)) if cam is not None else None
                if got is not None:
                    pe, ye, nees = _errors(got, cb)
                    row.update({f"{k}_fix": 1, f"{k}_pos_err_cm": pe, f"{k}_yaw_err_deg": ye, f"{k}_nees": nees})
    return head, rows
