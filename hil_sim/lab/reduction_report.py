"""Tables and figures of ``safer-hil experiment reduction`` (issue 25; docs/quadtree.md):
the CSV files, Figure 12 (reduction factor against dH), Figure 13 (original and transmitted
map with the obstacles outlined) and the markdown report."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any


def write_csv(path: Path, rows: list[dict[str, Any]]) -> None:
    import csv

    if not rows:
        return
    with path.open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)


def fig12(rows: list[dict[str, Any]], dhs: list[float], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    fig, ax = plt.subplots(figsize=(7, 4.5))
    for key, desc, color in (("reduction", "hazard-preserving (relief and steps >= w kept)", "C0"),
                             ("reduction_height_only", "height bound only (loses obstacles)", "C1")):
        data = [[r[key] for r in rows if r["dH"] == d] for d in dhs]
        med = [np.median(x) for x in data]
        lo = [np.min(x) for x in data]
        hi = [np.max(x) for x in data]
        ax.errorbar(dhs, med, yerr=[np.subtract(med, lo), np.subtract(hi, med)], fmt="o-",
                    capsize=4, color=color, label=f"{desc}: median, min-max over maps")
    ax.axhline(10, color="gray", ls=":", lw=1)
    ax.annotate("paper: ~10x at dH = 8", (8, 10), textcoords="offset points", xytext=(5, -14), color="gray")
    ax.set_yscale("log")
    ax.set_xlabel("dH = terrain variation / wheel diameter")
    ax.set_ylabel("data reduction factor (cells / leaves)")
    ax.set_title(f"Figure 12: reduction before the lossless stage, {len(rows) // max(1, len(dhs))} Viking-model maps")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def fig13(z: Any, zd: Any, wheel: float, cell: float, stats: dict[str, Any], title: str, path: Path,
          disc_m: float) -> None:
    """Original and transmitted map side by side, the hazards (relief >= w over ``disc_m`` or a
    step >= w within one wheel diameter) outlined in each. ``stats``: reduction, bytes, max_error_m."""
    from fsw.core.codec.hazard import relief, step
    from hil_sim.cliffbot_receiver import write_figure13

    def hazards(m: Any) -> Any:
        return (relief(m, cell, disc_m) >= wheel) | (step(m, cell, wheel) >= wheel)

    write_figure13(z, zd, path, f"{title}: reduction {stats['reduction']:.1f}x, {stats['bytes']} bytes, "
                   f"max error {stats['max_error_m']:.3f} m",
                   outlines=(hazards(z), hazards(zd)), cell_m=cell,
                   outline_label=f"hazard: relief or step >= wheel {wheel:.3f} m")


def report_md(rows: list[dict[str, Any]], maps: list[dict[str, Any]], dhs: list[float], codec: Any,
            args: argparse.Namespace) -> str:
    import numpy as np

    def count(kind: str) -> int:
        return sum(m["kind"] == kind for m in maps)

    lines = [f"# Map reduction: {args.maps} Viking-model maps ({args.size}x{args.size} cells of {args.cell_m} m, "
             f"k {args.k_range[0]}..{args.k_range[1]}), {'no' if args.no_dem else 'the'} DEM sample, "
             f"{count('mission')} mission maps ({args.mission_steps}-step method-{args.mission_method} missions), "
             f"{count('file')} map files and {count('mission-like')} mission-like maps", "",
             f"Codec: hazard rule {'on' if codec.hazard else 'off'} (relief disc {codec.relief_disc_m} m, threshold "
             f"{codec.hazard_relief_wheels} wheel, step disc {codec.step_disc_wheels} wheel, support rise "
             f"{codec.support_rise_fraction} x bound), split rule `{codec.split_rule}`, "
             f"leaf value `{codec.leaf_value}`, height bound {codec.error_bound_wheels} wheel diameter(s), "
             f"zstd {codec.zstd_level}. Obstacle: connected "
             f"cells whose relief (white top-hat over the {codec.relief_disc_m} m disc) is >= the wheel diameter w; "
             "kept if the decoded relief, max over its footprint, is >= w. Maps other than the Viking ones use "
             f"the receiving rover's wheel ([codec] receiver_wheel_diameter_m = {codec.receiver_wheel_diameter_m} m; "
             "0: the [rover] wheel). Mission maps: the RECON-bot's fused stereo map at the end of a short mission "
             "(holes where unmapped). Mission-like: the world's truth on the flight grid plus noise.", ""]
    if rows:
        lines += ["## Figure 12: reduction factor (cells / leaves) against dH", "",
                  "| dH | reduction median | p10 | p90 | min | max | bytes median | max error / bound (worst) "
                  "| obstacles >= w kept | >= 2w kept | height-only rule: reduction median | bytes median |",
                  "|---|---|---|---|---|---|---|---|---|---|---|---|"]
        for d in dhs:
            sel = [r for r in rows if r["dH"] == d]
            red = np.array([r["reduction"] for r in sel])
            ratio = max(r["max_error_m"] / r["bound_m"] for r in sel)
            n, kept = sum(r["obst"] for r in sel), sum(r["kept"] for r in sel)
            n2, kept2 = sum(r["obst_2w"] for r in sel), sum(r["kept_2w"] for r in sel)
            lines.append(f"| {d:g} | {np.median(red):.1f} | {np.percentile(red, 10):.1f} | "
                         f"{np.percentile(red, 90):.1f} | {red.min():.1f} | {red.max():.1f} | "
                         f"{np.median([r['bytes'] for r in sel]):.0f} | {ratio:.4f} | {kept}/{n} | {kept2}/{n2} | "
                         f"{np.median([r['reduction_height_only'] for r in sel]):.1f} | "
                         f"{np.median([r['bytes_height_only'] for r in sel]):.0f} |")
        at = [r["reduction"] for r in rows if r["dH"] == 8]
        if at:
            lines += ["", f"Reduction factor at dH = 8: median {np.median(at):.1f}x over {len(at)} maps "
                      f"(min {min(at):.1f}x, max {max(at):.1f}x); the paper reports about 10x (Figure 12).", ""]
    if maps:
        def tot(sel: list[dict[str, Any]], a: str, b: str) -> str:
            n, k = sum(m[a] for m in sel), sum(m[b] for m in sel)
            return f"{k}/{n} ({100.0 * k / n:.1f} %)" if n else "0/0"

        def drop(sel: list[dict[str, Any]]) -> str:
            m = min(sel, key=lambda m: m["max_step_decoded_m"] - m["max_step_m"])
            return f"{m['max_step_m']:.3f} / {m['max_step_decoded_m']:.3f}"

        lines += ["", "## Hazard check per map set", "",
                  "| maps | obstacles >= w kept | >= 2w kept | height-only rule: >= w kept | >= 2w kept "
                  "| obstacles in the decoded map only (height-only) "
                  "| worst peak relief loss, m | worst height error / bound | worst relief loss on hazards, m "
                  "(bound) | worst relief loss on any cell / its bound | worst position error, cells "
                  "| step cells kept (worst map) | worst step loss, m (slack) | largest drop: input / decoded, "
                  "worst map | bytes: ours / JPEG-LS at equal "
                  "hazards, median | maps where ours is smaller | ours / JPEG-LS keeping >= 99 %, median "
                  "| maps where ours is smaller |",
                  "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
        for kind in ("viking", "dem", "mission", "file", "mission-like"):
            sel = [m for m in maps if m["kind"] == kind]
            if not sel:
                continue
            ratio = np.median([m["bytes"] / m["jls_hazard_bytes"] for m in sel])
            ratio99 = np.median([m["bytes"] / m["jls_99_bytes"] for m in sel])
            lines.append(
                f"| {kind} ({len(sel)}) | {tot(sel, 'obst', 'kept')} | {tot(sel, 'obst_2w', 'kept_2w')} | "
                f"{tot(sel, 'obst', 'kept_height_only')} | {tot(sel, 'obst_2w', 'kept_2w_height_only')} | "
                f"{sum(m['new_obstacles'] for m in sel)} ({sum(m['new_obstacles_height_only'] for m in sel)}) | "
                f"{max(m['worst_peak_loss_m'] for m in sel):.4f} | "
                f"{max(m['max_error_m'] / m['bound_m'] for m in sel):.4f} | "
                f"{max(m['worst_relief_loss_m'] for m in sel):.4f} ({max(m['relief_loss_bound_m'] for m in sel):g}) | "
                f"{max(m['worst_relief_loss_any_m'] / m['relief_loss_any_bound_m'] for m in sel):.4f} | "
                f"{max(m['position_error_cells'] for m in sel):g} | {min(m['step_kept'] for m in sel):.4f} | "
                f"{max(m['worst_step_loss_m'] for m in sel):.4f} ({max(m['step_slack_m'] for m in sel):.4f}) | "
                f"{drop(sel)} | "
                f"{ratio:.2f} | {sum(m['bytes'] < m['jls_hazard_bytes'] for m in sel)}/{len(sel)} | "
                f"{ratio99:.2f} | {sum(m['bytes'] < m['jls_99_bytes'] for m in sel)}/{len(sel)} |")
        lines += ["", "## Per map", "",
                  "| map | wheel m | obstacles >= w: in / kept (height-only) | >= 2w: in / kept (height-only) "
                  "| worst peak loss m (height-only) | max error / bound | steps kept | worst step loss m "
                  "| reduction | bytes | height-only bytes | JPEG-LS bytes at equal hazards (NEAR mm) "
                  "| JPEG-LS keeping >= 99 % (NEAR mm) | JPEG-LS at the bound: bytes, >= w kept |",
                  "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
        for m in maps:
            lines.append(
                f"| {m['map']} | {m['wheel_m']:.3f} | {m['obst']} / {m['kept']} ({m['kept_height_only']}) | "
                f"{m['obst_2w']} / {m['kept_2w']} ({m['kept_2w_height_only']}) | {m['worst_peak_loss_m']:.3f} "
                f"({m['worst_peak_loss_height_only_m']:.3f}) | {m['max_error_m'] / m['bound_m']:.3f} | "
                f"{m['step_kept']:.3f} | {m['worst_step_loss_m']:.3f} | {m['reduction']:.1f} | {m['bytes']} | "
                f"{m['bytes_height_only']} | {m['jls_hazard_bytes']} ({m['jls_hazard_near_mm']:g}) | "
                f"{m['jls_99_bytes']} ({m['jls_99_near_mm']:g}) | {m['jls_bound_bytes']}, {m['jls_bound_kept']} |")
    return "\n".join(lines) + "\n"

