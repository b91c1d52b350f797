"""``safer-hil experiment reduction``: the paper's Figures 12 and 13 and the codec comparison.

docs/algorithm.md §6 (and "Mars terrain statistics"). ``--maps`` Viking-model Mars maps
(``hil_sim.world.mars.viking_heightfield``) with rock coverage ``k`` spread evenly over the
Viking Lander 1 to 2 values (0.07 .. 0.16), each reduced for several wheel diameters
chosen so that ``dH = (max - min elevation) / wheel diameter`` takes the values ``--dh``.
For every (map, dH): leaves, the reduction factor before the lossless stage (cells per
leaf), the container bytes after it, realised max and RMS error. At ``--compare-dh`` the
standard codecs are run **at the realised max error of ours** (``e``):

* JPEG-LS near-lossless (imagecodecs): elevations quantised to steps of ``2e`` then lossless
  JPEG-LS (the issue's baseline), and the best of JPEG-LS NEAR = 0..3 with steps
  ``2e / (2 NEAR + 1)`` (a stronger variant);
* zstd level 19 on the quantised raster, and quantise + row delta + zstd 19;
* OpenCV's lossless JPEG 2000 on the quantised raster;
* zstd 19 on the raw float32 map (lossless reference).

Writes ``reduction.csv``, ``codecs.csv``, ``report.md``, ``fig12_reduction.png`` and
``fig13_transmitted.png`` into ``--out``.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import Any

from hil_sim.results import command_line, write_results

HELP = "Figure 12/13: quadtree reduction vs dH on 32 Mars maps, and bytes vs standard codecs"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--maps", type=int, default=32, help="number of Mars maps")
    p.add_argument("--size", type=int, default=512, help="map side, cells")
    p.add_argument("--cell-m", type=float, default=0.02, help="cell size, m")
    p.add_argument("--k-range", type=float, nargs=2, default=(0.07, 0.16), metavar=("LO", "HI"),
                   help="rock coverage k spread over this range (Viking Lander 1 .. 2)")
    p.add_argument("--dh", type=float, nargs="+", default=[1, 2, 3, 4, 6, 8, 12, 16],
                   help="terrain variation / wheel diameter values")
    p.add_argument("--compare-dh", type=float, default=8.0, help="dH of the codec comparison")
    p.add_argument("--seed", type=int, default=0, help="seed of map 0 (map i uses seed + i)")
    p.add_argument("--config", default=None, help="flight config for [codec] (default config/fsw.toml)")
    p.add_argument("--out", type=Path, default=Path("out/experiments/reduction"), help="output dir")


def baselines(z: Any, e: float) -> dict[str, tuple[int, float]]:
    """Bytes and realised max error of the standard codecs at max error ``e``."""
    import cv2
    import imagecodecs
    import numpy as np
    import zstandard

    zmin = float(z.min())
    out: dict[str, tuple[int, float]] = {}

    def quant(step: float) -> Any:
        return np.rint((z.astype(np.float64) - zmin) / step).astype(np.uint16)

    def err(codes: Any, step: float) -> float:
        return float(np.abs(codes.astype(np.float64) * step + zmin - z).max())

    step = 2 * e * (1 - 1e-6)
    c = quant(step)
    jls = imagecodecs.jpegls_encode(c, level=0)
    out["jpegls_q2e"] = (len(jls), err(imagecodecs.jpegls_decode(jls), step))
    best = out["jpegls_q2e"]
    for near in (1, 2, 3):
        st = step / (2 * near + 1)
        enc = imagecodecs.jpegls_encode(quant(st), level=near)
        cand = (len(enc), err(imagecodecs.jpegls_decode(enc), st))
        if cand[1] <= e and cand[0] < best[0]:
            best = cand
    out["jpegls_best_near"] = best
    zc = zstandard.ZstdCompressor(level=19)
    small = c.astype(np.uint8) if c.max() < 256 else c
    out["zstd19_quant"] = (len(zc.compress(small.tobytes())), err(c, step))
    delta = np.diff(c.astype(np.int16), axis=1, prepend=np.int16(0))
    out["quant_delta_zstd19"] = (len(zc.compress(delta.astype(np.int16).tobytes())), err(c, step))
    ok, j2k = cv2.imencode(".jp2", c)
    back = cv2.imdecode(j2k, cv2.IMREAD_UNCHANGED)
    out["jpeg2000_lossless_quant"] = (len(j2k), err(back, step) if back is not None else float("nan"))
    out["zstd19_raw_float32"] = (len(zc.compress(z.astype(np.float32).tobytes())), 0.0)
    return out


def run(args: argparse.Namespace) -> int:
    import csv

    import numpy as np

    from fsw.core.codec.mapcodec import CodecConfig, encode_map
    from fsw.framework.params import ConfigError, build, load_toml
    from fsw.settings import DEFAULT_CONFIG
    from hil_sim.cliffbot_receiver import write_figure13
    from hil_sim.world.mars import viking_heightfield

    cfg_path = args.config or str(DEFAULT_CONFIG)
    try:
        codec = build(CodecConfig, load_toml(cfg_path).get("codec", {}), cfg_path, "codec")
    except ConfigError as exc:
        print(f"safer-hil: error: {exc}")
        return 2
    if args.maps < 1 or args.size < 8 or not all(d > 0 for d in args.dh):
        print("safer-hil: error: need --maps >= 1, --size >= 8 and positive --dh values")
        return 2
    args.out.mkdir(parents=True, exist_ok=True)
    ks = np.linspace(args.k_range[0], args.k_range[1], args.maps)
    dhs = sorted(set(args.dh) | {args.compare_dh})
    rows, comp = [], []
    fig13 = None
    t0 = time.perf_counter()
    for i, k in enumerate(ks):
        z = viking_heightfield((args.size, args.size), args.cell_m, float(k), args.seed + i)
        relief = float(z.max() - z.min())
        for dh in dhs:
            wheel = relief / dh
            res = {}
            for rule in ("entropy", "bound"):
                c = CodecConfig(**{**vars(codec), "split_rule": rule})
                tic = time.perf_counter()
                enc = encode_map(z, cell_m=args.cell_m, wheel_diameter_m=wheel, cfg=c)
                res[rule] = (enc, time.perf_counter() - tic)
            enc, dt = res[codec.split_rule]
            alt = res["bound" if codec.split_rule == "entropy" else "entropy"][0]
            rows.append({"map": i, "k": round(float(k), 4), "seed": args.seed + i,
                         "relief_m": round(relief, 4), "dH": dh, "wheel_m": round(wheel, 5),
                         "bound_m": codec.error_bound_wheels * wheel,
                         "leaves": enc.tree.n_leaves, "reduction": round(enc.tree.reduction_factor, 2),
                         "btd_bytes": enc.tree.btd_bytes(), "bytes": len(enc.data),
                         "max_error_m": enc.max_error_m, "rms_error_m": round(enc.rms_error_m, 6),
                         "encode_ms": round(dt * 1e3, 1), "reduction_alt_rule": round(alt.tree.reduction_factor, 2),
                         "bytes_alt_rule": len(alt.data)})
            if dh == args.compare_dh:
                base = baselines(z, enc.max_error_m)
                comp.append({"map": i, "k": round(float(k), 4), "max_error_m": enc.max_error_m,
                             "ours": len(enc.data), f"ours_{alt_name(codec)}": len(alt.data),
                             **{f"{n}": b for n, (b, _) in base.items()},
                             **{f"{n}_err_m": err for n, (_, err) in base.items()}})
                if fig13 is None:
                    from fsw.core.codec.mapcodec import decode_map

                    fig13 = (z, decode_map(enc.data).z, enc, dh)
        print(f"map {i + 1}/{args.maps} k={k:.3f} relief={relief:.2f} m "
              f"({time.perf_counter() - t0:.0f} s)", flush=True)
    _write_csv(args.out / "reduction.csv", rows, csv)
    _write_csv(args.out / "codecs.csv", comp, csv)
    if fig13 is not None:
        z, zt, enc, dh = fig13
        write_figure13(z, zt, args.out / "fig13_transmitted.png",
                       f"dH = {dh:g}: reduction {enc.tree.reduction_factor:.1f}x, {len(enc.data)} bytes, "
                       f"max error {enc.max_error_m:.3f} m")
    _fig12(rows, dhs, args.out / "fig12_reduction.png", codec.split_rule)
    report = _report(rows, comp, dhs, codec, args)
    (args.out / "report.md").write_text(report)
    print(report)
    print(f"wrote {args.out}/reduction.csv, codecs.csv, report.md, fig12_reduction.png, fig13_transmitted.png")
    write_results("reduction", command_line("reduction"), report,
                  [args.out / "fig12_reduction.png", args.out / "fig13_transmitted.png"])
    return 0


def alt_name(codec: Any) -> str:
    return "bound_rule" if codec.split_rule == "entropy" else "entropy_rule"


def _write_csv(path: Path, rows: list[dict[str, Any]], csv: Any) -> None:
    if not rows:
        return
    with path.open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)


def _fig12(rows: list[dict[str, Any]], dhs: list[float], path: Path, rule: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    fig, ax = plt.subplots(figsize=(7, 4.5))
    for key, label, color in (("reduction", "configured split rule", "C0"),
                              ("reduction_alt_rule", "the other split rule", "C1")):
        data = [[r[key] for r in rows if r["dH"] == d] for d in dhs]
        med = [np.median(x) for x in data]
        lo = [np.min(x) for x in data]
        hi = [np.max(x) for x in data]
        name = rule if key == "reduction" else ("bound" if rule == "entropy" else "entropy")
        desc = {"entropy": "entropy rule (paper Eq. 1-2) + bound", "bound": "bound rule only"}[name]
        ax.errorbar(dhs, med, yerr=[np.subtract(med, lo), np.subtract(hi, med)], fmt="o-",
                    capsize=4, color=color, label=f"{desc} ({label}): median, min-max over maps")
    ax.axhline(10, color="gray", ls=":", lw=1)
    ax.annotate("paper: ~10x at dH = 8", (8, 10), textcoords="offset points", xytext=(5, -14),
                color="gray")
    ax.set_yscale("log")
    ax.set_xlabel("dH = terrain variation / wheel diameter")
    ax.set_ylabel("data reduction factor (cells / leaves)")
    ax.set_title("Figure 12: reduction before the lossless stage, Viking-model Mars maps")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _report(rows: list[dict[str, Any]], comp: list[dict[str, Any]], dhs: list[float],
            codec: Any, args: argparse.Namespace) -> str:
    import numpy as np

    lines = [f"# Map reduction on {args.maps} Viking-model Mars maps "
             f"({args.size}x{args.size} cells of {args.cell_m} m, k {args.k_range[0]}..{args.k_range[1]})",
             "", f"Codec: split rule `{codec.split_rule}`, leaf value `{codec.leaf_value}`, "
             f"bound {codec.error_bound_wheels} wheel diameter(s), lattice step "
             f"{codec.quant_step_fraction} x bound, zstd {codec.zstd_level}.", "",
             "| dH | reduction median | p10 | p90 | min | max | bytes median | max error / bound (max) "
             f"| {alt_name(codec)} reduction median | encode ms median |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for d in dhs:
        sel = [r for r in rows if r["dH"] == d]
        red = np.array([r["reduction"] for r in sel])
        ratio = max(r["max_error_m"] / r["bound_m"] for r in sel)
        lines.append(f"| {d:g} | {np.median(red):.1f} | {np.percentile(red, 10):.1f} | "
                     f"{np.percentile(red, 90):.1f} | {red.min():.1f} | {red.max():.1f} | "
                     f"{np.median([r['bytes'] for r in sel]):.0f} | {ratio:.4f} | "
                     f"{np.median([r['reduction_alt_rule'] for r in sel]):.1f} | "
                     f"{np.median([r['encode_ms'] for r in sel]):.0f} |")
    if comp:
        names = [k for k in comp[0] if k not in ("map", "k", "max_error_m") and not k.endswith("_err_m")]
        ours = np.array([c["ours"] for c in comp], float)
        lines += ["", f"## Bytes on the link at dH = {args.compare_dh:g}, at our realised max error "
                  f"(median {np.median([c['max_error_m'] for c in comp]):.4f} m)", "",
                  "| codec | median bytes | median ratio to ours | maps where ours is smaller | "
                  "worst realised max error / ours |", "|---|---|---|---|---|"]
        for n in names:
            b = np.array([c[n] for c in comp], float)
            errs = [c.get(f"{n}_err_m", c["max_error_m"]) / c["max_error_m"] for c in comp]
            wins = "-" if n == "ours" else f"{int((ours < b).sum())}/{len(comp)}"
            lines.append(f"| {n} | {np.median(b):.0f} | {np.median(b / ours):.2f} | {wins} | "
                         f"{max(errs):.4f} |")
    return "\n".join(lines) + "\n"
