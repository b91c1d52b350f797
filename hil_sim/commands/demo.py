"""``safer-hil demo``: the default mission (lab, method 5) end to end; prints where its report is."""

from __future__ import annotations

import argparse
from pathlib import Path

HELP = "the default HIL mission end to end (lab scenario, method 5, 20 steps; replaces the last demo)"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--steps", type=int, default=20, help="imaging steps after the panorama")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", type=Path, default=Path("out/demo"), help="report directory")


def run(args: argparse.Namespace) -> int:
    from fsw.settings import DEFAULT_CONFIG
    from hil_sim.commands import run as run_cmd

    print(f"safer-hil demo: the flight software maps the lab scenario's cliff edge on a simulated rover\n"
          f"  (lockstep bench: simulated cameras, wheels and mast; method 5, {args.steps} steps, seed {args.seed}).\n"
          f"  The lines below are the flight software's events; KEY_NONE only says the demo has no\n"
          f"  signing key, so ground commands are refused. Results go to {args.out}/: summary.json,\n"
          f"  map.png, fsw.tlog (safer-ground map / plot), mission.mcap (opens in Foxglove).", flush=True)

    ns = argparse.Namespace(
        scenario="lab",
        method="5",
        steps=args.steps,
        seed=args.seed,
        out=args.out,
        config=str(DEFAULT_CONFIG),
        no_transmit=False,
        fresh=True,  # a demo always starts a new mission (the previous demo's report is replaced)
    )
    return run_cmd.run(ns)
