"""``safer-hil calibration-target``: render stereo pairs of the calibration target to PNGs.

The bench's true cameras (``[camera]`` of config/hil_hardware.toml: lenses, misalignment,
exposure, noise) look at the ``[calibration]`` board of config/fsw.toml held at varied
poses in front of the mast (``hil_sim.world.target``). The pairs go to
``DIR/left_NN.png`` and ``DIR/right_NN.png``, the input of ``safer-fsw calibrate DIR``.
Deterministic for a seed.
"""

from __future__ import annotations

import argparse
from pathlib import Path

HELP = "render stereo pairs of the calibration target (input of `safer-fsw calibrate`)"


def add_arguments(p: argparse.ArgumentParser) -> None:
    from fsw.settings import DEFAULT_CONFIG
    from hil_sim.rig import DEFAULT_HARDWARE

    p.add_argument("--out", type=Path, default=Path("out/calibration"), help="directory for the PNG pairs")
    p.add_argument("--views", type=int, default=60,
                   help="pairs to render (more pairs, a smaller disparity offset error: docs/perception.md)")
    p.add_argument("--seed", type=int, default=0, help="seed of the target poses and the sensor noise")
    p.add_argument("--scenario", default="lab", help="world behind the target (lab, cliff, mars, file:PATH)")
    p.add_argument("--config", default=str(DEFAULT_CONFIG), help="flight configuration (camera, target)")
    p.add_argument("--hardware", default=str(DEFAULT_HARDWARE), help="bench hardware configuration (true cameras)")


def run(args: argparse.Namespace) -> int:
    import sys

    import cv2

    from fsw.framework.params import ConfigError
    from hil_sim.lab.bench.bench_calibration import load_bench

    if not 1 <= args.views <= 200:
        print("safer-hil calibration-target: --views must be 1..200", file=sys.stderr)
        return 2
    try:
        world, cfg, cameras, noise = load_bench(args.scenario, args.seed, args.config, args.hardware)
    except (ConfigError, ValueError) as err:
        print(f"safer-hil calibration-target: {err}", file=sys.stderr)
        return 2
    from hil_sim.world.target import render_target_pairs

    args.out.mkdir(parents=True, exist_ok=True)
    for name, left, right in render_target_pairs(world, cfg, cameras, args.views, args.seed, noise):
        for side, img in (("left", left), ("right", right)):
            cv2.imwrite(str(args.out / f"{side}_{name}.png"), img)
    print(f"wrote {args.views} pairs to {args.out} ({'ideal' if cameras.ideal else 'real'} cameras, "
          f"noise {noise:g} grey levels); next: safer-fsw calibrate {args.out}")
    return 0
