"""``safer-hil experiment link``: map-link goodput against loss and bit error rate (ALGORITHM.md §6.6).

Runs the flight link (``fsw.comm.link_sender`` / ``link_receiver``) over the seeded channel
model (``hil_sim.radio_channel``) on a simulated clock, ``--seeds`` runs per point, sending
``--bytes`` of map data at ``--rate-bps``. Goodput = map bytes x 8 / time until the
Cliff-bot accepted the verified map. Capacity lines: ``rate x (1 - loss)`` for packet loss,
``rate x (1 - PER)`` for bit errors, with ``PER = 1 - (1 - BER) ** (8 x packet bytes)``.
Writes ``link_goodput.csv``, ``link_goodput.png`` and ``report.md`` into ``--out``.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

HELP = "goodput vs packet loss (0 to 0.3) and bit error rate at 9600 bit/s, with capacity lines"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--rate-bps", type=float, default=9600.0, help="radio bit rate")
    p.add_argument("--bytes", type=int, default=65536, help="map bytes per transfer")
    p.add_argument("--losses", type=float, nargs="+",
                   default=[0.0, 0.05, 0.1, 0.15, 0.2, 0.25, 0.3], help="packet loss points")
    p.add_argument("--bers", type=float, nargs="+", default=[0.0, 1e-6, 1e-5, 3e-5, 1e-4],
                   help="bit error rate points (at zero loss)")
    p.add_argument("--seeds", type=int, default=10, help="runs per point")
    p.add_argument("--latency-s", type=float, default=0.05, help="one-way latency")
    p.add_argument("--config", default=None, help="flight config for [link] (default config/fsw.toml)")
    p.add_argument("--out", type=Path, default=Path("out/experiments/link"), help="output dir")


def run(args: argparse.Namespace) -> int:
    import csv

    import numpy as np

    from fsw.comm.link import LinkConfig
    from fsw.comm.link_packets import DATA_OVERHEAD
    from fsw.framework.params import ConfigError, build, load_toml
    from fsw.settings import DEFAULT_CONFIG
    from hil_sim.link_sim import run_transfer
    from hil_sim.radio_channel import RadioChannelConfig

    path = args.config or str(DEFAULT_CONFIG)
    try:
        base = build(LinkConfig, load_toml(path).get("link", {}), path, "link")
        link = LinkConfig(**{**vars(base), "rate_bps": args.rate_bps})
    except (ConfigError, ValueError) as exc:
        print(f"safer-hil: error: {exc}")
        return 2
    if args.bytes < 1 or args.seeds < 1 or not all(0 <= x < 1 for x in args.losses + args.bers):
        print("safer-hil: error: need --bytes >= 1, --seeds >= 1, loss and BER in [0, 1)")
        return 2
    data = np.random.default_rng(0).integers(0, 256, args.bytes, dtype=np.uint8).tobytes()
    pkt_bits = 8 * (link.segment_bytes + DATA_OVERHEAD)
    points = [("loss", x, RadioChannelConfig(rate_bps=args.rate_bps, latency_s=args.latency_s, loss=x),
               args.rate_bps * (1 - x)) for x in args.losses]
    points += [("ber", x, RadioChannelConfig(rate_bps=args.rate_bps, latency_s=args.latency_s, ber=x),
                args.rate_bps * (1 - x) ** pkt_bits) for x in args.bers]
    rows: list[dict[str, Any]] = []
    for kind, x, ch, cap in points:
        g, ok = [], 0
        for seed in range(args.seeds):
            r = run_transfer(data, link, ch, seed=seed)
            ok += r.delivered == data
            g.append(r.goodput_bps)
        ga = np.array(g)
        rows.append({"kind": kind, "value": x, "capacity_bps": round(cap, 1),
                     "goodput_median_bps": round(float(np.median(ga)), 1),
                     "goodput_min_bps": round(float(ga.min()), 1), "goodput_max_bps": round(float(ga.max()), 1),
                     "ratio_median": round(float(np.median(ga)) / cap, 4),
                     "ratio_min": round(float(ga.min()) / cap, 4), "bit_exact": f"{ok}/{args.seeds}"})
        print(f"{kind}={x:g}: goodput median {np.median(ga):.0f} bit/s "
              f"({np.median(ga) / cap:.3f} of capacity {cap:.0f}), bit-exact {ok}/{args.seeds}", flush=True)
    args.out.mkdir(parents=True, exist_ok=True)
    with (args.out / "link_goodput.csv").open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    _plot(rows, args, args.out / "link_goodput.png")
    report = _report(rows, args, link)
    (args.out / "report.md").write_text(report)
    print(report)
    print(f"wrote {args.out}/link_goodput.csv, link_goodput.png, report.md")
    return 0


def _plot(rows: list[dict[str, Any]], args: argparse.Namespace, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.3))
    for ax, kind, xlabel in ((axes[0], "loss", "packet loss"), (axes[1], "ber", "bit error rate")):
        sel = [r for r in rows if r["kind"] == kind]
        if not sel:
            continue
        x = np.array([r["value"] for r in sel])
        med = np.array([r["goodput_median_bps"] for r in sel])
        lo = np.array([r["goodput_min_bps"] for r in sel])
        hi = np.array([r["goodput_max_bps"] for r in sel])
        cap = np.array([r["capacity_bps"] for r in sel])
        xs = x if kind == "loss" else np.maximum(x, 1e-7)
        ax.plot(xs, cap, "k--", label="capacity: rate x (1 - loss)" if kind == "loss"
                else "capacity: rate x (1 - PER)")
        if kind == "loss":
            ax.plot(xs, 0.9 * cap, "k:", lw=1, label="0.9 x capacity (target at 10 % loss)")
        ax.errorbar(xs, med, yerr=[med - lo, hi - med], fmt="o-", capsize=3,
                    label=f"goodput: median, min-max of {args.seeds} seeds")
        if kind == "ber":
            ax.set_xscale("log")
        ax.set_xlabel(xlabel + (" (0 plotted at 1e-7)" if kind == "ber" else ""))
        ax.set_ylabel("bit/s")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle(f"Map link goodput at {args.rate_bps:g} bit/s, {args.bytes} B per map")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _report(rows: list[dict[str, Any]], args: argparse.Namespace, link: Any) -> str:
    lines = [f"# Map link goodput ({args.rate_bps:g} bit/s, {args.bytes} B, {args.seeds} seeds/point, "
             f"segment {link.segment_bytes} B, latency {args.latency_s} s)", "",
             "| impairment | value | capacity bit/s | goodput median | min | max | median / capacity "
             "| min / capacity | bit-exact |", "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['kind']} | {r['value']:g} | {r['capacity_bps']:.0f} | {r['goodput_median_bps']:.0f} "
                     f"| {r['goodput_min_bps']:.0f} | {r['goodput_max_bps']:.0f} | {r['ratio_median']:.3f} "
                     f"| {r['ratio_min']:.3f} | {r['bit_exact']} |")
    return "\n".join(lines) + "\n"
