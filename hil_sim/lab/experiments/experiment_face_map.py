"""``safer-hil experiment face-map``: the face map against the gravity grid, and both agents' views.

For each seeded ``cliff-team`` scene (``--scenes`` from ``--seed``, in ``--jobs`` processes),
no mission: the map is measured. Views are rendered from

* ``--recon-views`` RECON-bot mast poses on the plateau behind the edge, looking down the face
  (the flight camera, the ideal pinhole pair: no rectification), and
* ``--cliff-views`` Cliff-bot poses on the face (alternately up the dip, from the body's upper
  end, and down it, from its lower end; position and pan drawn from the seed) with its small
  pair (``hil_sim.team.team_sensing``),

each with the tethers, the RECON-bot, the Anchorbots and the Cliff-bot in the picture, and each
camera pose wrong by an error drawn from the covariance it is fused with (RECON-bot: 0.2 deg,
1 cm; Cliff-bot: its navigation after a fix, 0.5 deg, 2 cm). Every view goes through the sensing
pipeline (``fsw.core.pipeline``: stereo, world points with covariance, the team mask of
``fsw.core.map.body_mask`` at the robots' estimated poses; registration off, the poses are
given), then into:

* ``gravity``: the scenario's gravity grid, every point (the one-grid map of today);
* ``face`` + its gravity grid: the face map fitted on the gravity grid after the RECON-bot's
  views, or after the first Cliff-bot view at which the fit accepts a plane
  (``fsw.core.map.face_plane.fit_face_plane``; cell at equal memory: ``c_g / sqrt(cos a)``), and the hand-over of
  docs/algorithm.md §8.1 (the views before the fit are fused once it is there);
* ``face_recon``, ``face_cliff``: the same face map fed by one agent only.

Figures per scene: ``fit_views``, the views fused when the face plane was first accepted
(``fit_face_plane`` refuses a plane its steep cells do not yet hold; none: no face map in the
scene); ``frame_off_deg``, its normal's angle from the scenario's nominal face
(``hil_sim.team.face_eval.frame_off_deg``) and ``frame_off_true_deg``, from the plane of the
true face lip to foot (``true_face_normal``: ledges make a face fall less steeply than the
scenario's slope between them); ``face_rmse_m`` and ``face_rmse_gravity_m``
(``hil_sim.team.face_eval``: each map queried at the same true face points in its own
coordinates, the distance from the point it
returns to the true one), their ratio, the gravity grid's distance from the true surface along
the face normal (``face_rmse_gravity_normal_m``) and that ratio, the truth overhang cells
flagged (and, of them, those a view could show: a true sight line passes under the outer surface,
``hil_sim.team.face_eval.overhang_seen``), those the views show as two surfaces (a true point
on ground facing the face, or air and ground above it in the column more than the gap apart:
``overhang_shown``; the others are one surface to every view, not observable) and those with
air as wide as the gap between their surfaces (``overhang_open``: the truth counts a cell whose
normal's first and last crossing are the gap apart, however thin the air between them), the
false flags (and of them those where an overhang covers part of the cell, off its centre:
``overhang_false_part``), the fused vs single-agent RMS on
cells both agents mapped, the fraction of cells
within 2 sigma (each agent, fused; of them the cells beside a step of the true relief, a rise out
of the face of ``overhang_gap_m`` or more within 2 cells, ``*_step``; ``out2s_*``: the cells more
than 2 sigma out of the face), the stereo points on a robot or a tether (judged on the
truth: ``hil_sim.team.face_scene.team_points``, from the renderer's label of each pixel),
those of them that survive the mask into the map, and the gravity-grid cells they fall in
(robot/tether cells mapped as terrain). Writes OUT/face_map.csv and ``docs/results/face-map.md``
(medians, worst cases; ``--results-name`` names another, e.g. for a held-out run on other seeds).
``--why`` runs the same scenes and, instead of the figures, sorts each missed truth overhang
cell by what the views gave the detector there, and each false flag by the test that set it,
the agent whose view did and what the truth holds there (``hil_sim.team.overhang_why``; writes
``docs/results/NAME-overhang-misses.md``).
``--resolve-cells K`` sets the face map's incidence limit (docs/algorithm.md §8.1: a point whose
stereo window spans more than K face cells is not fused; 0 off, the default).
"""

from __future__ import annotations

import argparse
import csv
import sys
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path
from typing import Any

HELP = "the face-aligned map vs the gravity grid at equal memory, both agents' views, the team mask"
COLUMNS = ("seed", "slope_deg", "views", "fit_views", "frame_off_deg", "frame_off_true_deg", "face_cells",
           "face_rmse_m", "face_rmse_gravity_m", "ratio",
           "face_rmse_gravity_normal_m", "ratio_normal",
           "overhang_truth", "overhang_flagged", "overhang_false", "overhang_false_part", "overhang_seen",
           "overhang_seen_flagged",
           "overhang_shown", "overhang_shown_flagged",
           "overhang_open", "overhang_open_flagged",
           "both_cells", "rmse_recon_m",
           "rmse_cliff_m", "rmse_fused_m", "in2s_recon", "in2s_cliff", "in2s_fused", "cells_recon",
           "within2s_recon", "cells_cliff", "within2s_cliff", "cells_fused", "within2s_fused",
           "out2s_recon", "cells_recon_step", "within2s_recon_step", "out2s_recon_step",
           "out2s_cliff", "cells_cliff_step", "within2s_cliff_step", "out2s_cliff_step",
           "out2s_fused", "cells_fused_step", "within2s_fused_step", "out2s_fused_step", "team_points_seen",
           "team_points_fused", "team_cells_mapped")


def add_arguments(p: argparse.ArgumentParser) -> None:
    from fsw.settings import DEFAULT_CONFIG

    p.add_argument("--scenario", default="cliff-team", help="scenario spec (seeded per scene)")
    p.add_argument("--scenes", type=int, default=30, help="number of seeded scenes")
    p.add_argument("--seed", type=int, default=0, help="first seed")
    p.add_argument("--jobs", type=int, default=1, help="scenes run in parallel (processes)")
    p.add_argument("--recon-views", type=int, default=4, help="RECON-bot views per scene")
    p.add_argument("--cliff-views", type=int, default=4, help="Cliff-bot views per scene")
    p.add_argument("--resolve-cells", type=float, default=None,
                   help="the face map's incidence limit: a point whose matching window spans more face cells "
                        "than this is not fused (0: off; default: FaceMapConfig.resolve_cells)")
    p.add_argument("--config", default=str(DEFAULT_CONFIG), help="flight configuration (TOML)")
    p.add_argument("--out", type=Path, default=Path("out/face-map"), help="output directory")
    p.add_argument("--why", action="store_true",
                   help="instead of the figures: why each missed truth overhang cell was missed "
                        "(hil_sim.team.overhang_why), written to docs/results/NAME-overhang-misses.md")
    p.add_argument("--results-name", default="face-map",
                   help="results file docs/results/NAME.md (e.g. a held-out run on other seeds)")


def run(args: argparse.Namespace) -> int:
    from fsw.framework.params import ConfigError
    from fsw.settings import load_settings
    from hil_sim.lab.results import bad_results_name, command_line, markdown_table, write_results
    from hil_sim.world import ScenarioError, load_scenario

    me = "safer-hil experiment face-map"
    if args.resolve_cells is not None and not 0.0 <= args.resolve_cells <= 100.0:
        print(f"{me}: --resolve-cells takes 0 to 100, got {args.resolve_cells}", file=sys.stderr)
        return 2
    if args.scenes < 1 or args.jobs < 1 or args.recon_views < 1 or args.cliff_views < 0:
        print(f"{me}: --scenes, --jobs and --recon-views must be >= 1, --cliff-views >= 0", file=sys.stderr)
        return 2
    if (bad := bad_results_name(args.results_name)) is not None:
        print(f"{me}: {bad}", file=sys.stderr)
        return 2
    try:
        load_settings(args.config, check_calibration=False)
        w = load_scenario(args.scenario, args.seed)
        if w.team is None:
            raise ScenarioError(f"{args.scenario} has no team (use a cliff-team scenario)")
    except (ScenarioError, ConfigError, ValueError, OSError) as exc:
        print(f"{me}: {exc}", file=sys.stderr)
        return 2
    seeds = list(range(args.seed, args.seed + args.scenes))
    if args.why:
        return _why(args, seeds)
    rows = _scenes(scene, args, seeds, lambda r: (
        f"face {_f(r['face_rmse_m'])} m, gravity {_f(r['face_rmse_gravity_m'])} m, overhangs "
        f"{r['overhang_flagged']}/{r['overhang_truth']}, team cells {r['team_cells_mapped']}"))
    if not rows:
        return 1
    args.out.mkdir(parents=True, exist_ok=True)
    with (args.out / "face_map.csv").open("w", newline="") as f:
        wr = csv.DictWriter(f, fieldnames=list(COLUMNS))
        wr.writeheader()
        wr.writerows(rows)
    md = report(rows, markdown_table)
    print(md)
    write_results(args.results_name, command_line("face-map"), md)
    return 0 if len(rows) == len(seeds) else 1


def _scenes(fn: Callable[..., dict[str, Any]], args: argparse.Namespace, seeds: list[int],
            line: Callable[[dict[str, Any]], str]) -> list[dict[str, Any]]:
    """``fn(scenario, seed, config, recon_views, cliff_views, resolve_cells)`` for every seed in
    ``args.jobs`` processes, a progress line per scene (``line``), sorted by seed; a scene that
    fails is reported on stderr and left out."""
    rows: list[dict[str, Any]] = []
    with ProcessPoolExecutor(max_workers=args.jobs) as pool:
        futs = {pool.submit(fn, args.scenario, s, args.config, args.recon_views, args.cliff_views,
                            args.resolve_cells): s for s in seeds}
        for fut in as_completed(futs):
            try:
                rows.append(fut.result())
            except Exception as exc:  # noqa: BLE001 - one failed scene is reported, the rest go on
                print(f"seed {futs[fut]}: FAILED {type(exc).__name__}: {exc}", file=sys.stderr)
                continue
            print(f"[{len(rows)}/{len(seeds)}] seed {rows[-1]['seed']}: {line(rows[-1])}", flush=True)
    return sorted(rows, key=lambda r: r["seed"])


def _why(args: argparse.Namespace, seeds: list[int]) -> int:
    """``--why``: the missed overhang cells' reasons per scene, in parallel, and the results file."""
    from hil_sim.lab.results import command_line, markdown_table, write_results
    from hil_sim.team.overhang_why import why_report, why_scene

    rows = _scenes(why_scene, args, seeds, lambda r: (
        f"overhangs {r['flagged']}/{r['truth']}, missed {r['missed']}, false {r['false']}"))
    if not rows:
        return 1
    md = why_report(rows, markdown_table)
    print(md)
    write_results(f"{args.results_name}-overhang-misses", command_line("face-map"), md)
    return 0 if len(rows) == len(seeds) else 1


def _f(v: Any) -> str:
    return "-" if v is None else f"{v:.4f}"


def report(rows: list[dict[str, Any]], table: Any) -> str:
    """The summary (medians, worst cases, pooled rates) and the per-scene table."""
    import numpy as np

    def col(k: str) -> Any:
        return np.array([r[k] for r in rows if r[k] is not None], float)

    ratio, fused = col("ratio"), col("rmse_fused_m")
    better = np.array([min(r["rmse_recon_m"], r["rmse_cliff_m"]) for r in rows
                       if None not in (r["rmse_recon_m"], r["rmse_cliff_m"], r["rmse_fused_m"])])
    fused_b = np.array([r["rmse_fused_m"] for r in rows
                        if None not in (r["rmse_recon_m"], r["rmse_cliff_m"], r["rmse_fused_m"])])
    ot, of = sum(r["overhang_truth"] for r in rows), sum(r["overhang_flagged"] for r in rows)
    summary = []

    def add(name: str, v: Any, worst: Any, goal: str) -> None:
        summary.append({"figure": name, "median": v, "worst": worst, "goal": goal})

    fitted = [r for r in rows if r["fit_views"] is not None]
    add("scenes with a face plane fitted (views fused at the fit: median, most)",
        f"{len(fitted)} of {len(rows)}", (f"{float(np.median(col('fit_views'))):g}, {int(col('fit_views').max())}"
                                           if fitted else ""), "")
    if fitted:
        add("fitted face normal from the scenario's face (deg)", float(np.median(col("frame_off_deg"))),
            float(col("frame_off_deg").max()), "")
        add("fitted face normal from the true face's plane (deg)", float(np.median(col("frame_off_true_deg"))),
            float(col("frame_off_true_deg").max()), "")
    if ratio.size:
        add("face_rmse_m / face_rmse_gravity_m", float(np.median(ratio)), float(ratio.max()), "<= 0.5")
        add("face_rmse_m", float(np.median(col("face_rmse_m"))), float(col("face_rmse_m").max()), "")
        add("face_rmse_gravity_m", float(np.median(col("face_rmse_gravity_m"))),
            float(col("face_rmse_gravity_m").max()), "")
        rn = col("ratio_normal")
        add("face_rmse_m / face_rmse_gravity_normal_m", float(np.median(rn)), float(rn.max()), "")
    add("overhang cells flagged (pooled)", of / ot if ot else None, f"{of} of {ot}", ">= 0.95")
    add("overhang false flags (pooled cells)", sum(r["overhang_false"] for r in rows), "", "")
    add("overhang false flags where an overhang covers part of the cell (pooled cells)",
        sum(r["overhang_false_part"] for r in rows), "", "")
    st, sf = sum(r["overhang_seen"] for r in rows), sum(r["overhang_seen_flagged"] for r in rows)
    add("overhang cells flagged, of those a view could show (pooled)", sf / st if st else None, f"{sf} of {st}", "")
    ht, hf = sum(r["overhang_shown"] for r in rows), sum(r["overhang_shown_flagged"] for r in rows)
    add("overhang cells flagged, of those the views show as two surfaces (pooled)", hf / ht if ht else None,
        f"{hf} of {ht}", "")
    add("overhang cells no view shows as two surfaces (pooled)", ot - ht, "", "")
    ot2, of2 = sum(r["overhang_open"] for r in rows), sum(r["overhang_open_flagged"] for r in rows)
    add("overhang cells flagged, of those with air as wide as the gap between the surfaces (pooled)",
        of2 / ot2 if ot2 else None, f"{of2} of {ot2}", "")
    if better.size:
        d = fused_b - better
        add("fused RMS - better agent's (m)", float(np.median(d)), float(d.max()), "<= 0")
    if fused.size:
        for k in ("in2s_recon", "in2s_cliff", "in2s_fused"):
            v = col(k)
            worst = float(v[np.argmax(np.abs(v - 0.945))]) if v.size else None
            add(f"{k} (cells both agents mapped, within 2 sigma)", float(np.median(v)) if v.size else None,
                worst, "0.90-0.99")
    for a in ("recon", "cliff", "fused"):
        n_c, n_in = sum(r[f"cells_{a}"] for r in rows), sum(r[f"within2s_{a}"] for r in rows)
        per = np.array([r[f"within2s_{a}"] / r[f"cells_{a}"] for r in rows if r[f"cells_{a}"]])
        add(f"{a}: all its cells within 2 sigma (pooled; worst scene)", n_in / n_c if n_c else None,
            float(per[np.argmax(np.abs(per - 0.945))]) if per.size else None, "0.90-0.99")
    for a in ("recon", "cliff", "fused"):  # beside a step of the true relief, and elsewhere
        n_s, in_s = sum(r[f"cells_{a}_step"] for r in rows), sum(r[f"within2s_{a}_step"] for r in rows)
        n_o = sum(r[f"cells_{a}"] for r in rows) - n_s
        in_o = sum(r[f"within2s_{a}"] for r in rows) - in_s
        add(f"{a}: cells beside a step (true rise >= overhang gap within 2 cells) within 2 sigma (pooled)",
            in_s / n_s if n_s else None, f"{in_s} of {n_s}", "")
        add(f"{a}: cells elsewhere within 2 sigma (pooled)", in_o / n_o if n_o else None, f"{in_o} of {n_o}", "")
    o_all, o_s = sum(r["out2s_recon"] for r in rows), sum(r["out2s_recon_step"] for r in rows)
    add("recon: cells more than 2 sigma out of the face, of them beside a step (pooled)",
        o_s / o_all if o_all else None, f"{o_s} of {o_all}", "")
    add("views", sum(r["views"] for r in rows), "", ">= 200")
    add("robot/tether points from stereo (truth)", sum(r["team_points_seen"] for r in rows), "", "")
    add("robot/tether points fused after the mask", sum(r["team_points_fused"] for r in rows),
        max(r["team_points_fused"] for r in rows), "0")
    add("robot/tether cells mapped as terrain", sum(r["team_cells_mapped"] for r in rows),
        max(r["team_cells_mapped"] for r in rows), "0")
    return ("## Summary\n\n" + table(summary, ["figure", "median", "worst", "goal"])
            + "\n\n## Scenes\n\n" + table(rows, list(COLUMNS)) + "\n")


def scene(spec: str, seed: int, config: str, n_recon: int, n_cliff: int,
          resolve_cells: float | None = None) -> dict[str, Any]:
    """One scene's figures (module docstring); deterministic per seed."""
    from hil_sim.team.face_scene import FaceScene

    return FaceScene(spec, seed, config, resolve_cells=resolve_cells).measure(n_recon, n_cliff)

