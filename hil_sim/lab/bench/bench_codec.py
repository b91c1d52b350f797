"""``safer-hil bench codec``: map codec speed (docs/algorithm.md §6).

Encodes (hazard analysis + reduction + predictive coding + zstd) and decodes two maps
``--repeat`` times each and prints the median, best and worst wall time and the median CPU
time of each, against the 100 ms encode target:

* a ``--size`` square Viking-model Mars map at ``dH = --dh`` (issue 6's 512 x 512 case);
* the demo's mission map (``--scenario``, default ``lab``, the scenario ``safer-hil demo``
  flies): the world's truth on the flight map grid (256 x 256 cells of 3 cm), 1.5 cm of height
  noise and unknown textureless ground, as the experiment's mission-like maps, reduced for the
  receiving rover's wheel (``[codec] receiver_wheel_diameter_m``); ``--scenario ""`` skips it;
* the team's maps (``--team-seeds``, default 3 ``cliff-team`` scenes from seed 0): the ground of
  the cliff scene on the flight map grid, the full-resolution map ``safer-hil experiment team``
  reduces, encoded as the RECON-bot's radio encodes it for the Cliff-bot (the flight ``[codec]``
  with its relief hold); ``--team-seeds 0`` skips them.

The first run of each is a warm-up and not counted. Timings on a shared machine are noisy;
the median is the figure to quote, the CPU time the one least disturbed by other load.
"""

from __future__ import annotations

import argparse
from typing import Any

HELP = "map codec encode/decode time: a 512x512 Mars map and the demo's mission map (target: encode <= 100 ms)"
TARGET_MS = 100.0


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--size", type=int, default=512, help="Mars map side, cells")
    p.add_argument("--cell-m", type=float, default=0.02, help="Mars map cell size, m")
    p.add_argument("--dh", type=float, default=8.0, help="Mars map terrain variation / wheel diameter")
    p.add_argument("--k", type=float, default=0.12, help="Viking rock coverage")
    p.add_argument("--seed", type=int, default=0, help="map seed")
    p.add_argument("--scenario", default="lab",
                   help="scenario of the mission-size map (the demo flies lab; terrain:N = terrain family "
                   "seed N); empty to skip")
    p.add_argument("--team-seeds", type=int, default=3, help="cliff-team scenes timed, from seed --team-seed")
    p.add_argument("--team-seed", type=int, default=0, help="first cliff-team seed")
    p.add_argument("--repeat", type=int, default=20, help="timed runs per map")
    p.add_argument("--config", default=None, help="flight config for [codec], [rover] (default config/fsw.toml)")


def _time(label: str, z: Any, cell_m: float, wheel: float, codec: Any, repeat: int) -> float:
    """Print the timing lines of one map; returns the median encode wall time, ms."""
    import time

    import numpy as np

    from fsw.core.codec.mapcodec import decode_map, encode_map

    enc_ms, dec_ms, cpu_ms = [], [], []
    for i in range(repeat + 1):
        c0 = time.process_time()
        t0 = time.perf_counter()
        enc = encode_map(z, cell_m=cell_m, wheel_diameter_m=wheel, cfg=codec)
        t1 = time.perf_counter()
        c1 = time.process_time()
        decode_map(enc.data)
        t2 = time.perf_counter()
        if i:
            enc_ms.append((t1 - t0) * 1e3)
            cpu_ms.append((c1 - c0) * 1e3)
            dec_ms.append((t2 - t1) * 1e3)
    e, d = np.array(enc_ms), np.array(dec_ms)
    print(f"{label}: {z.shape[0]}x{z.shape[1]} cells of {cell_m:g} m ({int(np.isfinite(z).sum())} known), wheel "
          f"{wheel:.3f} m, {enc.tree.n_leaves} leaves, {len(enc.data)} bytes, max error {enc.max_error_m:.4f} m")
    print(f"  encode ms: median {np.median(e):.1f}  best {e.min():.1f}  worst {e.max():.1f}  "
          f"(target <= {TARGET_MS:.0f} ms: {'OK' if np.median(e) <= TARGET_MS else 'MISSED'})")
    print(f"  encode CPU ms (process time, less sensitive to other load): median "
          f"{np.median(cpu_ms):.1f}  best {min(cpu_ms):.1f}")
    print(f"  decode ms: median {np.median(d):.1f}  best {d.min():.1f}  worst {d.max():.1f}")
    return float(np.median(e))


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from fsw.core.codec.mapcodec import CodecConfig
    from fsw.core.geometry import MapGrid, RoverConfig
    from fsw.framework.params import ConfigError, build, load_toml
    from fsw.settings import DEFAULT_CONFIG
    from hil_sim.lab.experiments.experiment_reduction import _mission_like
    from hil_sim.world import load_scenario
    from hil_sim.world.config import ScenarioError
    from hil_sim.world.mars import viking_heightfield

    path = args.config or str(DEFAULT_CONFIG)
    try:
        data = load_toml(path)
        codec = build(CodecConfig, data.get("codec", {}), path, "codec")
        rover = build(RoverConfig, data.get("rover", {}), path, "rover")
    except ConfigError as exc:
        print(f"safer-hil: error: {exc}")
        return 2
    if args.size < 8 or args.repeat < 1 or args.dh <= 0 or args.team_seeds < 0:
        print("safer-hil: error: need --size >= 8, --repeat >= 1, --dh > 0 and --team-seeds >= 0")
        return 2
    mission = None
    if args.scenario:
        try:
            mission = _mission_like(args.scenario, 0.015)
        except (ScenarioError, ConfigError, ValueError) as exc:
            print(f"safer-hil: error: scenario {args.scenario!r}: {exc}")
            return 2
    z = viking_heightfield((args.size, args.size), args.cell_m, args.k, args.seed)
    _time(f"Mars map, dH {args.dh:g}", z, args.cell_m, float(z.max() - z.min()) / args.dh, codec, args.repeat)
    if mission is not None:
        name, zm, cell = mission
        _time(f"mission map ({name}, as the demo's)", zm, cell, codec.wheel_m(rover.wheel_diameter_m), codec,
              args.repeat)
    for seed in range(args.team_seed, args.team_seed + args.team_seeds):
        world = load_scenario("cliff-team", seed)
        grid = MapGrid.from_config(world.map_grid)
        _time(f"team map (cliff-team seed {seed})", world.ground_on_grid(grid).astype(np.float32), grid.cell,
              codec.wheel_m(rover.wheel_diameter_m), codec, args.repeat)
    return 0
