"""``safer-hil bench render``: time per stereo pair of the renderer (goal <= 0.3 s at 640x480).

Renders the scenario's stereo pair at each size from a fixed set of representative views
(the Cliff-bot straight on, looking down over the edge, a far oblique view and a view
along the edge), ``--repeats`` times each after one warm-up, and prints the median time
per pair (both images, noise included) per size, the spread over views, and whether the
640x480 median meets the goal. Timings on a shared machine are noisy: the figure is the
median, and the per-view medians show the spread.
"""

from __future__ import annotations

import argparse

HELP = "time per rendered stereo pair at 320x240 and 640x480 (goal <= 0.3 s at 640x480)"
GOAL_S = 0.3
VIEWS = (  # (name, pan_deg, tilt_deg, lift_m) from the rover start
    ("cliffbot", None, None, 0.3),
    ("down over the edge", -90.0, -55.0, 0.3),
    ("far oblique", -60.0, -20.0, 0.5),
    ("along the edge", -20.0, -30.0, 0.3),
)


def _size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WxH like 640x480, got {text!r}") from None
    if not (32 <= w <= 4096 and 32 <= h <= 4096):
        raise argparse.ArgumentTypeError(f"size {text} out of range (32..4096 a side)")
    return w, h


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--scenario", default="lab", help="world (hil_sim.world.load_scenario spec)")
    p.add_argument("--seed", type=int, default=0, help="world and noise seed")
    p.add_argument("--sizes", type=_size, nargs="+", default=[(320, 240), (640, 480)],
                   metavar="WxH", help="image sizes to time")
    p.add_argument("--repeats", type=int, default=5, help="timed pairs per view and size")
    p.add_argument("--noise", type=float, default=2.0, help="sensor noise, grey levels")
    p.add_argument("--strict", action="store_true",
                   help="exit 1 when the 640x480 median misses the goal")
    p.add_argument("--config", default=None,
                   help="flight config for camera and mast (default config/fsw.toml)")


def run(args: argparse.Namespace) -> int:
    import dataclasses
    import math
    import statistics
    import time

    from fsw.core.geometry import camera_pose_from_rover
    from fsw.framework.params import ConfigError
    from fsw.settings import DEFAULT_CONFIG, load_settings
    from hil_sim.render import StereoRenderer
    from hil_sim.world import load_scenario
    from hil_sim.world.world import aim_at

    if args.repeats < 1 or args.noise < 0:
        print("safer-hil bench render: --repeats must be >= 1 and --noise >= 0")
        return 2
    try:
        cfg = load_settings(args.config or DEFAULT_CONFIG)
        t0 = time.perf_counter()
        world = load_scenario(args.scenario, args.seed)
        build_s = time.perf_counter() - t0
    except (ConfigError, ValueError) as err:
        print(f"safer-hil bench render: {err}")
        return 2
    print(f"scenario {world.name} seed {world.seed}: truth grid {world.shape[1]}x{world.shape[0]} "
          f"cells of {world.cell_m * 100:g} cm, built in {build_s:.2f} s")
    rover = world.rover_start
    poses = []
    for name, pan, tilt, lift in VIEWS:
        if pan is None or tilt is None:
            joints = aim_at(world, rover, cfg.mast)
        else:
            joints = cfg.mast.clamp(math.radians(pan), math.radians(tilt), lift)
        poses.append((name, camera_pose_from_rover(rover, joints, cfg.mast, world.plateau_z)))
    missed = False
    print(f"{'size':>9}  {'median s/pair':>13}  {'min':>6}  {'max':>6}  per view (median s)")
    for w, h in args.sizes:
        camera = dataclasses.replace(cfg.camera, width_px=w, height_px=h)
        renderer = StereoRenderer(world, camera, args.noise, args.seed)
        times: list[float] = []
        per_view = []
        for _, pose in poses:
            renderer.render(pose)  # warm-up (allocations, caches)
            view_t = []
            for _ in range(args.repeats):
                t0 = time.perf_counter()
                renderer.render(pose)
                view_t.append(time.perf_counter() - t0)
            times += view_t
            per_view.append(statistics.median(view_t))
        med = statistics.median(times)
        views = ", ".join(f"{n} {t:.3f}" for (n, _), t in zip(poses, per_view, strict=True))
        print(f"{w:>4}x{h:<4}  {med:13.3f}  {min(times):6.3f}  {max(times):6.3f}  {views}")
        if (w, h) == (640, 480):
            ok = med <= GOAL_S
            missed = not ok
            print(f"goal: 640x480 pair <= {GOAL_S} s: {'met' if ok else 'MISSED'} "
                  f"(median {med:.3f} s over {len(times)} pairs)")
    return 1 if (missed and args.strict) else 0
