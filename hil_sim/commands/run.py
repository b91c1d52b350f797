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
    "received-map figure and the flight software's fsw.tlog. After each imaging step the map, "
    "the mission state and the bench's truth are checkpointed in DIR/checkpoints; a killed run "
    "continues with --resume DIR (same result as an uninterrupted run). An out directory that "
    "holds a mission is refused unless --resume or --fresh is given."
)


def add_arguments(p: argparse.ArgumentParser) -> None:
    from fsw.settings import DEFAULT_CONFIG

    p.add_argument("--scenario", default="lab", help="lab, cliff, mars or file:PATH")
    p.add_argument(
        "--method",
        default="5",
        choices=("1", "2", "3", "4", "5", "oracle"),
        help="mapping method (docs/algorithm.md §7)",
    )
    p.add_argument("--steps", type=int, default=20, help="imaging steps after the panorama")
    p.add_argument("--seed", type=int, default=0, help="seed of world, hardware and radio")
    p.add_argument("--out", type=Path, default=Path("out/run"), help="report directory")
    p.add_argument("--config", default=str(DEFAULT_CONFIG), help="flight configuration (TOML)")
    p.add_argument("--live", metavar="URL", help="also stream the mission to the live view at URL "
                                                 "(safer-ground rerun --live prints it: rerun+http://127.0.0.1:PORT/proxy)")
    p.add_argument("--no-transmit", action="store_true", help="skip sending the map to the Cliff-bot")
    g = p.add_mutually_exclusive_group()
    g.add_argument(
        "--resume",
        type=Path,
        metavar="DIR",
        default=None,
        help="continue the killed mission in DIR at the step where it stopped (scenario, method, "
        "steps, seed and config come from DIR/run.json; the options above are ignored)",
    )
    g.add_argument("--fresh", action="store_true", help="delete the mission already in --out and start a new one")
    p.add_argument("--camera", default="config", choices=("config", "ideal", "raw"),
                   help="config: the cameras of hil_hardware.toml, rectified with fsw.toml's calibration file; "
                        "ideal: the ideal pinhole pair, no calibration; raw: the real cameras fed to stereo "
                        "without rectification")


def resume_hint(args: argparse.Namespace) -> str:
    """What ``safer-hil`` adds to "interrupted": the command that continues the mission, once the
    out directory holds one."""
    import shlex

    from hil_sim.mission.run_dir import has_mission

    out = getattr(args, "resume", None) or getattr(args, "out", None)
    if out is not None and has_mission(Path(out)):
        return f"; continue it with: safer-hil run --resume {shlex.quote(str(out))}"
    return ""


def run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from fsw.framework.params import ConfigError
    from fsw.framework.storage import StorageError, describe
    from hil_sim.mission.mission_run import run_mission
    from hil_sim.mission.run_dir import finished, has_mission
    from hil_sim.mission.run_spec import RunSpec, read_manifest

    if args.steps < 0:
        print("safer-hil run: --steps must be >= 0", file=sys.stderr)
        return 2
    resume = getattr(args, "resume", None)
    if resume is not None:
        try:
            spec = read_manifest(resume)
        except ValueError as err:
            print(f"safer-hil run: {err}", file=sys.stderr)
            return 2
        mode = "resume"
        if finished(resume):
            print(f"safer-hil run: the mission in {resume} has finished; report: {resume / 'summary.json'}")
            return 0
    else:
        spec = RunSpec(args.scenario, args.method, args.steps, args.seed, args.config, not args.no_transmit, args.out,
                       camera=getattr(args, "camera", "config"))
        mode = "fresh" if getattr(args, "fresh", False) else "new"
        if mode == "new" and has_mission(args.out):
            print(f"safer-hil run: {args.out} holds a mission; --resume {args.out} continues it, "
                  "--fresh deletes it", file=sys.stderr)
            return 2
    out = spec.out
    assert out is not None
    bars: list[tqdm] = []  # made at the first step, so a refusal before it is one line

    def progress(step: int, total: int, state: str) -> None:
        if not bars:
            bars.append(tqdm(total=total + 1, desc=f"{spec.scenario} method {spec.method}", unit="step"))
        bar = bars[0]
        bar.n = min(step, total + 1)
        bar.set_postfix_str(state, refresh=False)
        bar.refresh()

    def close_bar(done: bool) -> None:
        if bars:
            if done:
                bars[0].n = bars[0].total
            bars[0].close()

    live = getattr(args, "live", None)
    if live is not None and not live.startswith(("rerun+http://127.0.0.1:", "rerun+http://localhost:")):
        print(f"safer-hil run: --live {live!r}: expected rerun+http://127.0.0.1:PORT/proxy "
              "(safer-ground rerun --live prints it)", file=sys.stderr)
        return 2
    try:
        s = run_mission(spec, progress, mode=mode, live=live)
    except OSError as err:  # a full or failing disk (StorageError, or one no writer expected)
        close_bar(False)
        print(f"safer-hil run: {err if isinstance(err, StorageError) else describe(err)}", file=sys.stderr)
        return 1
    except ConfigError as err:
        close_bar(False)
        print(f"safer-hil run: config error: {err}", file=sys.stderr)
        return 2
    except ValueError as err:  # e.g. an unknown or unreadable scenario, an unusable checkpoint
        close_bar(False)
        print(f"safer-hil run: {err}", file=sys.stderr)
        return 2
    close_bar(True)
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
    print(f"report: {out / 'summary.json'} (map.png, coverage.png, fsw.tlog; mission.mcap for Foxglove, "
          f"safer-ground rerun for rerun)")
    return 0 if s["final_state"] == "DONE" else 1
