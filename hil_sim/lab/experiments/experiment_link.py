"""``safer-hil experiment link``: map-link goodput against loss and bit error rate (docs/algorithm.md §6.6).

Runs the flight link (``fsw.comm.link_sender`` / ``link_receiver``) over the seeded channel
model (``hil_sim.link.radio_channel``) on a simulated clock, ``--seeds`` runs per point, sending
``--bytes`` of map data at ``--rate-bps``. Goodput = map bytes x 8 / time until the
Cliff-bot accepted the verified map. Capacity lines: ``rate x (1 - loss)`` for packet loss,
``rate x (1 - PER)`` for bit errors, with ``PER = 1 - (1 - BER) ** (8 x packet bytes)``.
Writes ``link_goodput.csv``, ``link_goodput.png`` and ``report.md`` into ``--out``.

``--transport udp`` runs the same link over real loopback sockets instead: the Cliff-bot,
an impairment relay and the RECON-bot's sender as three processes
(``hil_sim.lab.link_udp_experiment``), ``--seeds`` runs per ``--losses`` point with
``--ber``, ``--duplicate``, ``--reorder`` and an ``--outage``, and writes ``udp_runs.csv``
and ``udp_report.md`` (per run and per loss, with the lockstep simulation of the same seeds).
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from hil_sim.lab.results import command_line, write_results

HELP = "goodput vs packet loss (0 to 0.3) and bit error rate at 9600 bit/s, with capacity lines"
DESCRIPTION = (
    "Map-link goodput. --transport sim (default): the lockstep simulation, a grid of loss and "
    "BER points (--losses, --bers, --seeds). --transport udp: the RECON-bot's sender and the "
    "Cliff-bot's receiver as separate processes over 127.0.0.1 UDP through the project's "
    "impairment relay (loss, --ber, --duplicate, --reorder, --outage, --rate-bps), --seeds "
    "runs per --losses point (defaults 0.1 and 0.3, 5 runs), table per run in udp_report.md."
)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--rate-bps", type=float, default=9600.0, help="radio bit rate")
    p.add_argument("--bytes", type=int, default=65536, help="map bytes per transfer")
    p.add_argument("--transport", choices=("sim", "udp"), default="sim",
                   help="sim: lockstep simulation; udp: three processes over loopback UDP")
    p.add_argument("--losses", type=float, nargs="+", default=None,
                   help="packet loss points (sim: 0 to 0.3 by 0.05; udp: 0.1 0.3)")
    p.add_argument("--bers", type=float, nargs="+", default=[0.0, 1e-6, 1e-5, 3e-5, 1e-4],
                   help="bit error rate points (at zero loss)")
    p.add_argument("--seeds", type=int, default=None, help="runs per point (sim 10, udp 5)")
    p.add_argument("--reverse-loss", type=float, default=-1.0,
                   help="udp: loss of the Cliff-bot's answers (acknowledgements) alone; -1: as the loss")
    p.add_argument("--ber", type=float, default=3e-5, help="udp: bit error rate of every run")
    p.add_argument("--duplicate", type=float, default=0.1, help="udp: duplication probability")
    p.add_argument("--reorder", type=float, default=0.1, help="udp: reordering probability")
    p.add_argument("--reorder-delay-s", type=float, default=0.5, help="udp: longest hold-back")
    p.add_argument("--outage", type=float, nargs=2, default=[20.0, 20.0], metavar=("START_S", "DURATION_S"),
                   help="udp: outage window from the first datagram (duration 0: none)")
    p.add_argument("--jobs", type=int, default=2, help="udp: transfers run at the same time")
    p.add_argument("--timeout", type=float, default=400.0, help="udp: bound of one transfer, s")
    p.add_argument("--latency-s", type=float, default=0.05, help="one-way latency")
    p.add_argument("--config", default=None, help="flight config for [link] (default config/fsw.toml)")
    p.add_argument("--out", type=Path, default=Path("out/experiments/link"), help="output dir")
    p.add_argument("--results", type=Path, default=None,
                   help="udp: also write the report there, with date, commit and command "
                   "(e.g. docs/results/link_udp_loss.md)")


def run(args: argparse.Namespace) -> int:
    import csv

    import numpy as np

    from fsw.comm.link import LinkConfig
    from fsw.comm.link_packets import DATA_OVERHEAD
    from fsw.framework.params import ConfigError, build, load_toml
    from fsw.settings import DEFAULT_CONFIG
    from hil_sim.lab.link_sim import run_transfer
    from hil_sim.link.radio_channel import RadioChannelConfig

    path = args.config or str(DEFAULT_CONFIG)
    try:
        base = build(LinkConfig, load_toml(path).get("link", {}), path, "link")
        link = LinkConfig(**{**vars(base), "rate_bps": args.rate_bps})
    except (ConfigError, ValueError) as exc:
        print(f"safer-hil: error: {exc}")
        return 2
    if args.transport == "udp":
        return _run_udp(args, link)
    args.losses = args.losses or [0.0, 0.05, 0.1, 0.15, 0.2, 0.25, 0.3]
    args.seeds = args.seeds or 10
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
    write_results("link", command_line("link"), report, [args.out / "link_goodput.png"])
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


def provenance() -> str:
    """Date, commit and command line of this run (the first lines of a results file)."""
    import datetime
    import shlex
    import subprocess
    import sys

    try:
        commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                                timeout=10, check=False).stdout.strip() or "unknown"
    except OSError:
        commit = "unknown"
    date = datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M UTC")
    return f"{date}, commit {commit}: `safer-hil {shlex.join(sys.argv[1:])}`"


def _run_udp(args: argparse.Namespace, link: Any) -> int:
    import math

    import numpy as np

    from hil_sim.lab.link_udp_experiment import UdpRunSpec, run_all, sim_ratio, write_tables

    losses = args.losses or [0.1, 0.3]
    seeds = args.seeds or 5
    nums = [*losses, args.reverse_loss, args.ber, args.duplicate, args.reorder, args.reorder_delay_s, *args.outage,
            args.timeout, args.rate_bps, args.latency_s]
    if not all(math.isfinite(x) for x in nums) or not all(0 <= x < 1 for x in
                                                          [*losses, args.ber, args.duplicate, args.reorder]) \
            or not (args.reverse_loss == -1 or 0 <= args.reverse_loss < 1) or seeds < 1 or args.jobs < 1 \
            or args.bytes < 1 or args.timeout <= 0 or min(args.outage) < 0:
        print("safer-hil: error: udp needs finite values, loss/BER/duplicate/reorder in [0, 1), "
              "--reverse-loss -1 or in [0, 1), "
              "--seeds, --jobs, --bytes >= 1, --timeout > 0, --outage >= 0")
        return 2
    outage = (args.outage[0], args.outage[1]) if args.outage[1] > 0 else None
    specs = [UdpRunSpec(loss, seed, args.ber, args.duplicate, args.reorder, args.reorder_delay_s,
                        outage, args.rate_bps, args.latency_s, args.bytes, args.config, args.timeout,
                        reverse_loss=args.reverse_loss)
             for loss in losses for seed in range(seeds)]
    rows = run_all(specs, args.jobs)
    data = np.random.default_rng(0).integers(0, 256, args.bytes, dtype=np.uint8).tobytes()
    for spec, row in zip(specs, rows, strict=True):
        row["sim_ratio"] = round(sim_ratio(spec, link, data), 4)
    back = "as the loss" if args.reverse_loss < 0 else f"{args.reverse_loss:g}"
    header = (f"# Map link over loopback UDP ({args.rate_bps:g} bit/s, {args.bytes} B, answers lost: {back}, "
              f"BER {args.ber:g}, "
              f"duplicate {args.duplicate:g}, reorder {args.reorder:g}, outage {outage}, "
              f"segment {link.segment_bytes} B)")
    header += "\n\n" + provenance()
    text = write_tables(rows, args.out, header)
    print(text)
    print(f"wrote {args.out}/udp_runs.csv, udp_report.md")
    if args.results is not None:
        args.results.parent.mkdir(parents=True, exist_ok=True)
        args.results.write_text(text)
        print(f"wrote {args.results}")
    name = "link-udp" if args.reverse_loss < 0 else "link-udp-answers-lost"
    write_results(name, command_line("link"), (args.out / "udp_report.md").read_text())
    ok = all(r["bit_exact"] for r in rows)
    return 0 if ok else 1
