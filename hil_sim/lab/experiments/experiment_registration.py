"""``safer-hil experiment registration``: is the registration's covariance right? (lockstep)

Runs one mission per seed (``--scenario`` with ``{seed}`` or a generated family, seeded),
records its views (``hil_sim.lab.view_replay``) and merges them again from their TRUE poses under
each ``--config``: the map is then in the truth's frame, so every registered view's pose
error is the registration's own. Prints, per seed and configuration, the views registered,
the mean and median NEES (normalised estimation error squared) of roll/pitch (2 dof) and of
all six directions, the median tilt error against its sigma, and the replay's map RMSE and
tilt; then the totals. A consistent covariance gives a mean NEES near 2 and 6 (medians near
1.39 and 5.35). This is how ``[registration] n_eff`` was chosen (docs/perception.md, "How
many independent points"). Writes OUT/registration.json.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
from pathlib import Path
from typing import Any

from hil_sim.lab.results import command_line, markdown_table, write_results

HELP = "registration consistency: NEES of the registered poses against the truth, per config"


def add_arguments(p: argparse.ArgumentParser) -> None:
    from fsw.settings import DEFAULT_CONFIG

    p.add_argument("--scenario", default="terrain?slope_deg=-1",
                   help="scenario spec, seeded per mission (default: the generated family, slopes 0-12 deg)")
    p.add_argument("--seeds", default="0-7", help="seeds, e.g. 0-7 or 0,3,5")
    p.add_argument("--method", default="5", choices=("1", "2", "3", "4", "5"))
    p.add_argument("--steps", type=int, default=3, help="imaging steps after the panorama")
    p.add_argument("--config", action="append", default=None,
                   help=f"flight configuration to replay with (repeatable; default: {DEFAULT_CONFIG.name})")
    p.add_argument("--out", type=Path, default=Path("out/registration"), help="result directory")


def _seeds(text: str) -> list[int]:
    out: list[int] = []
    for part in text.split(","):
        a, sep, b = part.partition("-")
        lo, hi = int(a), int(b) if sep else int(a)
        if lo < 0 or hi < lo:
            raise ValueError(f"bad seed range {part!r}")
        out.extend(range(lo, hi + 1))
    return out


def _stats(rows: list[dict[str, float]]) -> dict[str, Any]:
    if not rows:
        return {"views": 0}
    col = lambda k: [r[k] for r in rows]  # noqa: E731
    return {"views": len(rows), "nees_rp_mean": statistics.fmean(col("nees_rp")),
            "nees_rp_median": statistics.median(col("nees_rp")), "nees6_mean": statistics.fmean(col("nees6")),
            "nees6_median": statistics.median(col("nees6")),
            "tilt_err_deg_median": statistics.median(col("tilt_err_deg")),
            "tilt_sd_deg_median": statistics.median(col("tilt_sd_deg"))}


def _line(name: str, s: dict[str, Any], extra: str = "") -> str:
    if not s["views"]:
        return f"{name:36s} no registered view{extra}"
    return (f"{name:36s} {s['views']:4d} {s['nees_rp_mean']:8.2f} {s['nees_rp_median']:8.2f} "
            f"{s['nees6_mean']:8.2f} {s['nees6_median']:8.2f} {s['tilt_err_deg_median']:9.3f} "
            f"{s['tilt_sd_deg_median']:8.3f}{extra}")


def run(args: argparse.Namespace) -> int:
    from fsw.framework.params import ConfigError
    from fsw.settings import DEFAULT_CONFIG, load_settings
    from hil_sim.lab.view_replay import record_mission, registration_errors
    from hil_sim.mission.mission_run import RunSpec
    from hil_sim.world import load_scenario

    configs = args.config or [str(DEFAULT_CONFIG)]
    try:
        seeds = _seeds(args.seeds)
        if args.steps < 1:
            raise ValueError("--steps must be >= 1")
        for c in configs:
            load_settings(c)
        load_scenario(args.scenario, seeds[0])
    except (ConfigError, ValueError, OSError) as err:
        print(f"safer-hil experiment registration: {err}", file=sys.stderr)
        return 2
    head = f"{'seed / config':36s} {'views':>4s} {'rp mean':>8s} {'rp med':>8s} {'6 mean':>8s} {'6 med':>8s} " \
           f"{'tilt err':>9s} {'tilt sd':>8s}   (NEES; deg)"
    print(head)
    rows: dict[str, list[dict[str, float]]] = {c: [] for c in configs}
    result: list[dict[str, Any]] = []
    for seed in seeds:
        spec = RunSpec(scenario=args.scenario, method=args.method, steps=args.steps, seed=seed, transmit=False)
        _, views = record_mission(spec)
        for c in configs:
            errs, q = registration_errors(views, args.scenario, seed, c)
            rows[c].extend(errs)
            s = _stats(errs)
            result.append({"seed": seed, "config": c, **s, "map_rms_m": q["rms_m"], "map_tilt_deg": q["tilt_err_deg"]})
            print(_line(f"{seed} {Path(c).name}", s, f"   map {100 * q['rms_m']:.2f} cm, {q['tilt_err_deg']:.3f} deg"),
                  flush=True)
    print("totals")
    totals = {c: _stats(r) for c, r in rows.items()}
    for c, s in totals.items():
        print(_line(Path(c).name, s))
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "registration.json").write_text(json.dumps({"per_seed": result, "totals": totals}, indent=1) + "\n")
    write_results("registration", command_line("registration"),
                  "Per seed and config:\n\n" + markdown_table(result)
                  + "\n\nTotals:\n\n" + markdown_table([{"config": c, **s} for c, s in totals.items()]))
    return 0
