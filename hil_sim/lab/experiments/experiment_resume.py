"""``safer-hil experiment resume``: kill a lockstep mission with SIGKILL, resume it, compare.

One uninterrupted reference run, then the same mission (same seed) run as a separate
``safer-hil run`` process that is killed with SIGKILL at ``--kills`` random moments (delays
drawn from ``--kill-seed``) and continued each time with ``safer-hil run --resume``. Printed
per kill: when, the step the killed run had shown, the step its newest checkpoint holds (the
step the resume starts from), the completed steps lost (must be 0: only the step in progress
is redone) and the temporary files left by a kill during a save (removed by the resume).
Then the final maps: mapped cells of both, the fraction of the reference's cells present,
and whether every map layer is bit-identical. Writes OUT/resume.json. Exit 0 if every resume
finished the mission, no completed step was lost and the map holds >= 99 % of the cells.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

from hil_sim.lab.results import command_line, markdown_table, write_results

HELP = "SIGKILL a lockstep mission at random moments, resume it each time, compare with an uninterrupted run"
LAYERS = ("z", "var", "n", "interest", "misses", "outliers", "var_common")
_SHOWN = re.compile(r"(\d+)/\d+ \[")


def add_arguments(p: argparse.ArgumentParser) -> None:
    from fsw.settings import DEFAULT_CONFIG

    p.add_argument("--scenario", default="lab", help="lab, cliff, mars or file:PATH")
    p.add_argument("--method", default="5", choices=("1", "2", "3", "4", "5", "oracle"))
    p.add_argument("--steps", type=int, default=20, help="imaging steps after the panorama")
    p.add_argument("--seed", type=int, default=0, help="seed of the mission (world, hardware, radio)")
    p.add_argument("--kills", type=int, default=10, help="SIGKILLs during the mission")
    p.add_argument("--kill-seed", type=int, default=0, help="seed of the kill moments")
    p.add_argument("--max-delay", type=float, default=0.0, metavar="S",
                   help="kill each process uniformly within 1..S s of its start (0: 1.6 x the reference's "
                   "wall time / kills)")
    p.add_argument("--config", default=str(DEFAULT_CONFIG), help="flight configuration (TOML)")
    p.add_argument("--out", type=Path, default=Path("out/resume"), help="output directory")


def run_cmd(out: Path, *extra: str) -> list[str]:
    """The ``safer-hil run`` command line of a new run in ``out``."""
    return [sys.executable, "-m", "hil_sim.cli", "run", *extra, "--out", str(out)]


def resume_cmd(out: Path) -> list[str]:
    """The ``safer-hil run --resume`` command line of the run in ``out``."""
    return [sys.executable, "-m", "hil_sim.cli", "run", "--resume", str(out)]


def start(cmd: list[str], log: Path) -> subprocess.Popen[bytes]:
    with open(log, "ab") as fh:
        return subprocess.Popen(cmd, stdout=fh, stderr=subprocess.STDOUT, start_new_session=True)


def shown_step(log: Path) -> int:
    """The last step the run's progress bar showed (steps completed)."""
    found = _SHOWN.findall(log.read_bytes().decode(errors="replace").split("\n=== ")[-1])
    return int(found[-1]) if found else 0


def newest(out: Path) -> Any:
    """The newest good checkpoint of the run in ``out`` (``LoadResult``)."""
    from fsw.core.map.checkpoint import CheckpointConfig
    from fsw.drivers.map_store import MapStore

    return MapStore(CheckpointConfig(directory=str(out / "checkpoints"))).load_latest()


def checkpoint_step(out: Path) -> int:
    st = newest(out).state
    return int(st["mission"]["step"]) if st else 0


def temporaries(out: Path) -> int:
    d = out / "checkpoints"
    return len(list(d.glob(".map_*.tmp"))) if d.is_dir() else 0


def compare_maps(ref_out: Path, out: Path) -> dict[str, Any]:
    """Mapped cells of both final maps, the reference's cells present, identical layers."""
    import numpy as np

    a, b = newest(ref_out).emap, newest(out).emap
    if a is None or b is None:
        return {"ref_cells": None, "cells": None, "fraction": 0.0, "identical": False}
    both = int((a.mapped & b.mapped).sum())
    ref = int(a.mapped.sum())
    same = all(np.array_equal(getattr(a, n), getattr(b, n), equal_nan=True) for n in LAYERS)
    return {"ref_cells": ref, "cells": int(b.mapped.sum()), "fraction": both / ref if ref else 1.0, "identical": same}


def run(args: argparse.Namespace) -> int:
    import numpy as np

    if args.kills < 0 or args.steps < 0 or not args.max_delay >= 0:
        print("safer-hil experiment resume: --kills, --steps and --max-delay must be >= 0", file=sys.stderr)
        return 2
    args.out.mkdir(parents=True, exist_ok=True)
    mission = ["--scenario", args.scenario, "--method", args.method, "--steps", str(args.steps),
               "--seed", str(args.seed), "--config", args.config]
    ref_out, out = args.out / "reference", args.out / "killed"
    log = args.out / "killed.log"
    log.write_bytes(b"")
    t0 = time.perf_counter()
    ref = subprocess.run(run_cmd(ref_out, "--fresh", *mission), capture_output=True)
    ref_wall_s = time.perf_counter() - t0
    if ref.returncode != 0:
        print(f"reference run failed (exit {ref.returncode}): {ref.stdout.decode()[-300:]}", file=sys.stderr)
        return 1
    print(f"reference: {ref_wall_s:.1f} s wall, {args.steps} steps, seed {args.seed}")
    rng = np.random.default_rng(args.kill_seed)
    hi = args.max_delay if args.max_delay > 0 else 1.6 * ref_wall_s / max(1, args.kills)
    delays = rng.uniform(1.0, max(2.0, hi), args.kills)
    kills: list[dict[str, Any]] = []
    proc = start(run_cmd(out, "--fresh", *mission), log)
    print(f"{'kill':>4} {'at s':>6} {'shown':>5} {'ckpt':>4} {'lost':>4} {'tmp':>3}")
    for i, delay in enumerate(delays):
        try:
            proc.wait(timeout=float(delay))
            break  # the mission ended before this kill
        except subprocess.TimeoutExpired:
            pass
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
        shown, ckpt, tmp = shown_step(log), checkpoint_step(out), temporaries(out)
        row = {"kill": i + 1, "after_s": round(float(delay), 2), "shown_step": shown, "checkpoint_step": ckpt,
               "lost_steps": max(0, shown - ckpt), "temporaries": tmp}
        kills.append(row)
        print(f"{i + 1:>4} {delay:6.1f} {shown:>5} {ckpt:>4} {row['lost_steps']:>4} {tmp:>3}")
        with open(log, "ab") as fh:
            fh.write(f"\n=== resume {i + 1}\n".encode())
        proc = start(resume_cmd(out), log)
    rc = proc.wait()
    summary = json.loads((out / "summary.json").read_text()) if (out / "summary.json").exists() else {}
    cmp = compare_maps(ref_out, out)
    result = {
        "scenario": args.scenario, "method": args.method, "steps": args.steps, "seed": args.seed,
        "kill_seed": args.kill_seed, "reference_wall_s": round(ref_wall_s, 1), "kills": kills,
        "final_exit": rc, "final_state": summary.get("final_state"), "temporaries_left": temporaries(out), **cmp,
    }
    (args.out / "resume.json").write_text(json.dumps(result, indent=2) + "\n")
    print(f"kills: {len(kills)}; completed steps lost: {sum(k['lost_steps'] for k in kills)}; "
          f"temporaries found after kills: {sum(k['temporaries'] for k in kills)}, left at the end: "
          f"{result['temporaries_left']}; final state {result['final_state']} (exit {rc})")
    print(f"mapped cells: reference {cmp['ref_cells']}, resumed {cmp['cells']}; reference cells present "
          f"{100 * cmp['fraction']:.2f} %; all map layers identical: {cmp['identical']}")
    print(f"report: {args.out / 'resume.json'}")
    write_results("resume", command_line("resume"), markdown_table(kills) + "\n\n" + markdown_table(
        [{k: v for k, v in result.items() if k != "kills"}]))
    ok = rc == 0 and all(k["lost_steps"] == 0 for k in kills) and cmp["fraction"] >= 0.99
    return 0 if ok else 1
