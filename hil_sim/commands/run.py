"""``safer-hil run``: one lockstep mission with a progress bar, summary.json and PNGs."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

HELP = "run one lockstep mission (scenario, method, steps, seed) and write its report"
DESCRIPTION = (
    "Run the flight software against the HIL bench in lockstep: the full mission (panorama, "
    "next-view selection, moves, stereo, map fusion, transmission to the Cliff-bot). Writes "
    "DIR/summary.json (schema in docs/experiments.md), map.png, coverage.png, the Cliff-bot's "
    "received-map figure and the flight software's fsw.tlog."
)


def add_arguments(p: argparse.ArgumentParser) -> None:
    from fsw.settings import DEFAULT_CONFIG

    p.add_argument("--scenario", default="lab", help="lab, cliff, mars or file:PATH")
    p.add_argument(
        "--method", default="5", choices=("1", "2", "3", "4", "5", "oracle"), help="mapping method (ALGORITHM.md §7)"
    )
    p.add_argument("--steps", type=int, default=20, help="imaging steps after the panorama")
    p.add_argument("--seed", type=int, default=0, help="seed of world, hardware and radio")
    p.add_argument("--out", type=Path, default=Path("out/run"), help="report directory")
    p.add_argument("--config", default=str(DEFAULT_CONFIG), help="flight configuration (TOML)")
    p.add_argument("--no-transmit", action="store_true", help="skip sending the map to the Cliff-bot")
    p.add_argument("--camera", default="config", choices=("config", "ideal", "raw"),
                   help="config: the cameras of hil_hardware.toml, rectified with fsw.toml's calibration file; "
                        "ideal: the ideal pinhole pair, no calibration; raw: the real cameras fed to stereo "
                        "without rectification")


def run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from fsw.config import ConfigError
    from hil_sim.mission_run import RunSpec, run_mission

    if args.steps < 0:
        print("safer-hil run: --steps must be >= 0", file=sys.stderr)
        return 2
    spec = RunSpec(args.scenario, args.method, args.steps, args.seed, args.config, not args.no_transmit, args.out,
                   camera=getattr(args, "camera", "config"))
    bar = tqdm(total=args.steps + 1, desc=f"{args.scenario} method {args.method}", unit="step")

    def progress(step: int, total: int, state: str) -> None:
        bar.n = min(step, total + 1)
        bar.set_postfix_str(state, refresh=False)
        bar.refresh()

    try:
        s = run_mission(spec, progress)
    except ConfigError as err:
        bar.close()
        print(f"safer-hil run: config error: {err}", file=sys.stderr)
        return 2
    except ValueError as err:  # e.g. an unknown or unreadable scenario
        bar.close()
        print(f"safer-hil run: {err}", file=sys.stderr)
        return 2
    bar.n = bar.total
    bar.close()
    cb = s["cliffbot"]
    print(
        f"{s['mapped_cells']} cells mapped in {len(s['steps']) - 1} steps; map RMSE "
        f"{(s['map_rmse_m'] or float('nan')) * 100:.2f} cm; edge violations {s['edge_violations']}; "
        f"slips {s['slips']}; end: {s['end_reason']} ({s['final_state']})"
    )
    if cb is not None:
        print(
            f"Cliff-bot: map {cb['map_id']} {'decoded' if cb['decoded'] else 'NOT decoded'}, "
            f"{cb['container_bytes']} B, max error {cb['max_error_m']} m"
        )
    print(f"report: {args.out / 'summary.json'} (map.png, coverage.png, fsw.tlog)")
    return 0 if s["final_state"] == "DONE" else 1
