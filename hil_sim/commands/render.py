"""``safer-hil render``: render one stereo pair of a scenario and write it with its truth.

Writes ``left.png`` and ``right.png`` (8-bit grayscale, what the flight cameras would
deliver), ``depth.npy`` (left-camera range along the optical axis, metres, NaN = nothing),
``truth_elevation.png`` (the truth heightfield, colour-mapped, with the true edge, the
Cliff-bot, the rover and the camera's view), ``truth_elevation.npy`` (float32 metres, the
world's truth grid) and ``render.json`` (scenario, seed, camera intrinsics and pose, truth
grid origin and cell, Cliff-bot marker corners), so a run can be reproduced and checked.
"""

from __future__ import annotations

import argparse
from pathlib import Path

HELP = "render a stereo pair of a scenario (PNG) with its truth elevation and depth"
DESCRIPTION = (
    "Render the left/right images the rover's stereo pair sees in a scenario, and write them "
    "with the truth elevation (PNG figure and .npy), the left depth map and a JSON record. "
    "The camera pose comes from the rover pose and mast joints (fsw.core.geometry), by "
    "default the scenario's rover start with the mast aimed at the Cliff-bot. Camera and "
    "mast parameters come from the flight config. Exit 2 on bad arguments or input files."
)


def _floats(n: int, what: str):  # type: ignore[no-untyped-def]
    def parse(text: str) -> tuple[float, ...]:
        try:
            vals = tuple(float(v) for v in text.split(","))
        except ValueError:
            raise argparse.ArgumentTypeError(f"{what}: expected {n} comma-separated numbers, "
                                             f"got {text!r}") from None
        if len(vals) != n:
            raise argparse.ArgumentTypeError(f"{what}: expected {n} numbers, got {len(vals)}")
        return vals
    return parse


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--scenario", default="lab",
                   help="lab | cliff | mars | file:PATH | a scenario .toml, with optional "
                        "?key=value&... overrides (e.g. mars?k=0.16)")
    p.add_argument("--out", type=Path, required=True,
                   help="output directory (created)%(default).0s")
    p.add_argument("--seed", type=int, default=None,
                   help="world and noise seed (default: the scenario file's seed)%(default).0s")
    p.add_argument("--noise", type=float, default=None, metavar="SIGMA",
                   help="sensor noise std in grey levels (default: the scenario's)%(default).0s")
    p.add_argument("--rover", type=_floats(3, "--rover"), default=None, metavar="X,Y,YAW_DEG",
                   help="rover pose (default: the scenario's rover start)%(default).0s")
    p.add_argument("--mast", type=_floats(3, "--mast"), default=None,
                   metavar="PAN_DEG,TILT_DEG,LIFT_M",
                   help="mast joints, e.g. --mast=-60,-30,0.3 (write '=' when the value "
                        "starts with '-'); default: aim at the Cliff-bot, lift 0.3 m%(default).0s")
    p.add_argument("--size", type=_floats(2, "--size"), default=None, metavar="W,H",
                   help="image size in pixels (default: the flight config's camera)%(default).0s")
    p.add_argument("--dem-scale", type=float, default=None, metavar="M_PER_COUNT",
                   help="for file:*.png scenarios: metres per 16-bit count "
                        "(default: config/scenarios/file.toml)%(default).0s")
    p.add_argument("--dem-cell", type=float, default=None, metavar="M",
                   help="for file: scenarios: DEM cell size in metres "
                        "(default: config/scenarios/file.toml)%(default).0s")
    p.add_argument("--config", type=Path, default=None,
                   help="flight config TOML for camera and mast (default: config/fsw.toml)"
                        "%(default).0s")


def scenario_spec(args: argparse.Namespace) -> str:
    """The scenario spec with the DEM options folded in as overrides."""
    spec = str(args.scenario)
    extra = []
    if getattr(args, "dem_scale", None) is not None:
        extra.append(f"file.z_scale_m={args.dem_scale}")
    if getattr(args, "dem_cell", None) is not None:
        extra.append(f"file.cell_m={args.dem_cell}")
    if extra:
        spec += ("&" if "?" in spec else "?") + "&".join(extra)
    return spec


def run(args: argparse.Namespace) -> int:
    import dataclasses
    import json
    import math

    import cv2
    import numpy as np

    from fsw.core.geometry import camera_pose_from_rover
    from fsw.framework.params import ConfigError
    from fsw.settings import DEFAULT_CONFIG, load_settings
    from hil_sim.render import StereoRenderer
    from hil_sim.world import load_scenario
    from hil_sim.world.figures import elevation_figure
    from hil_sim.world.world import aim_at

    try:
        cfg = load_settings(args.config or DEFAULT_CONFIG)
        world = load_scenario(scenario_spec(args), args.seed)
        camera = cfg.camera
        if args.size is not None:
            camera = dataclasses.replace(camera, width_px=int(args.size[0]),
                                         height_px=int(args.size[1]))
        noise = world.noise_sigma if args.noise is None else args.noise
        if noise < 0:
            raise ValueError(f"--noise must be >= 0, got {noise}")
        args.out.mkdir(parents=True, exist_ok=True)
    except (ConfigError, ValueError, OSError) as err:
        print(f"safer-hil render: {err}")
        return 2
    x, y, yaw = world.rover_start
    if args.rover is not None:
        x, y, yaw = args.rover[0], args.rover[1], math.radians(args.rover[2])
    if args.mast is not None:
        joints = (math.radians(args.mast[0]), math.radians(args.mast[1]), args.mast[2])
    else:
        joints = aim_at(world, (x, y, yaw), cfg.mast)
    pose = camera_pose_from_rover((x, y, yaw), joints, cfg.mast, world.plateau_z)
    renderer = StereoRenderer(world, camera, noise, world.seed)
    left, right = renderer.render(pose)
    depth = renderer.render_depth(pose)
    cv2.imwrite(str(args.out / "left.png"), left)
    cv2.imwrite(str(args.out / "right.png"), right)
    np.save(args.out / "depth.npy", depth)
    np.save(args.out / "truth_elevation.npy", np.asarray(world.height))
    elevation_figure(world, args.out / "truth_elevation.png", pose=pose, camera=camera)
    record = {
        "scenario": scenario_spec(args), "world": world.name, "seed": world.seed,
        "noise_sigma": noise, "rover_xy_yaw": [x, y, yaw], "mast_pan_tilt_lift": list(joints),
        "camera": {"width_px": camera.width_px, "height_px": camera.height_px,
                   "K": camera.K.tolist(), "baseline_m": camera.baseline_m},
        "left_pose": {"R_cam_to_world": pose.R.tolist(), "t": pose.t.tolist()},
        "truth_grid": {"x0_m": world.x0, "y0_m": world.y0, "cell_m": world.cell_m,
                       "shape": list(world.shape)},
        "cliffbot": {"xyz": [world.cliffbot.x, world.cliffbot.y, world.cliffbot.z],
                     "yaw": world.cliffbot.yaw,
                     "marker_corners_world": {str(k): v.tolist() for k, v in
                                              world.cliffbot.marker_corners_world().items()}},
    }
    (args.out / "render.json").write_text(json.dumps(record, indent=1))
    seen = np.isfinite(depth)
    print(f"{world.name} seed {world.seed}: {camera.width_px}x{camera.height_px} pair written "
          f"to {args.out} (terrain in {seen.mean():.0%} of the view, depth "
          f"{np.nanmin(depth) if seen.any() else float('nan'):.2f}.."
          f"{np.nanmax(depth) if seen.any() else float('nan'):.2f} m)")
    return 0
