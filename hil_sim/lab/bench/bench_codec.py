"""``safer-hil bench codec``: map codec speed on a Viking-model Mars map (docs/algorithm.md §6).

Encodes (reduction + predictive coding + zstd) and decodes a ``--size`` square map
``--repeat`` times at ``dH = --dh`` and prints the median, best and worst wall time of each,
against the 100 ms encode target for a 512 x 512 map (issue 6). The first run is a warm-up
and not counted. Timings on a shared machine are noisy; the median is the figure to quote.
"""

from __future__ import annotations

import argparse

HELP = "map codec encode/decode time for a 512x512 Mars map (target: encode <= 100 ms)"
TARGET_MS = 100.0


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--size", type=int, default=512, help="map side, cells")
    p.add_argument("--cell-m", type=float, default=0.02, help="cell size, m")
    p.add_argument("--dh", type=float, default=8.0, help="terrain variation / wheel diameter")
    p.add_argument("--k", type=float, default=0.12, help="Viking rock coverage")
    p.add_argument("--seed", type=int, default=0, help="map seed")
    p.add_argument("--repeat", type=int, default=20, help="timed runs")
    p.add_argument("--config", default=None, help="flight config for [codec] (default config/fsw.toml)")


def run(args: argparse.Namespace) -> int:
    import time

    import numpy as np

    from fsw.core.codec.mapcodec import CodecConfig, decode_map, encode_map
    from fsw.framework.params import ConfigError, build, load_toml
    from fsw.settings import DEFAULT_CONFIG
    from hil_sim.world.mars import viking_heightfield

    path = args.config or str(DEFAULT_CONFIG)
    try:
        codec = build(CodecConfig, load_toml(path).get("codec", {}), path, "codec")
    except ConfigError as exc:
        print(f"safer-hil: error: {exc}")
        return 2
    if args.size < 8 or args.repeat < 1 or args.dh <= 0:
        print("safer-hil: error: need --size >= 8, --repeat >= 1 and --dh > 0")
        return 2
    z = viking_heightfield((args.size, args.size), args.cell_m, args.k, args.seed)
    wheel = float(z.max() - z.min()) / args.dh
    enc_ms, dec_ms, cpu_ms = [], [], []
    data = b""
    for i in range(args.repeat + 1):
        c0 = time.process_time()
        t0 = time.perf_counter()
        enc = encode_map(z, cell_m=args.cell_m, wheel_diameter_m=wheel, cfg=codec)
        t1 = time.perf_counter()
        c1 = time.process_time()
        decode_map(enc.data)
        t2 = time.perf_counter()
        if i:
            enc_ms.append((t1 - t0) * 1e3)
            cpu_ms.append((c1 - c0) * 1e3)
            dec_ms.append((t2 - t1) * 1e3)
        data = enc.data
    e, d = np.array(enc_ms), np.array(dec_ms)
    print(f"map {args.size}x{args.size}, dH {args.dh:g} (wheel {wheel:.3f} m), "
          f"{enc.tree.n_leaves} leaves, {len(data)} bytes, max error {enc.max_error_m:.4f} m")
    print(f"encode ms: median {np.median(e):.1f}  best {e.min():.1f}  worst {e.max():.1f}  "
          f"(target <= {TARGET_MS:.0f} ms: {'OK' if np.median(e) <= TARGET_MS else 'MISSED'})")
    print(f"encode CPU ms (process time, less sensitive to other load): median "
          f"{np.median(cpu_ms):.1f}  best {min(cpu_ms):.1f}")
    print(f"decode ms: median {np.median(d):.1f}  best {d.min():.1f}  worst {d.max():.1f}")
    return 0
