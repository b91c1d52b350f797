"""``safer-hil bench stereo-real``: the flight stereo against ground-truth disparity on real
Middlebury pairs and on rendered pairs (issue 14, item 4; docs/algorithm.md §4, §1.2).

For each real pair (shipped inside scikit-image, a dev dependency; ``hil_sim.lab.stereo_eval``)
it prints, for plain OpenCV SGBM_3WAY (same block size and disparity range) and for the
flight matcher with the configured filters: the density (pixels with truth that get a
disparity), the 2-px error rate, and for the flight matcher the share of errors within
2 sigma of its per-pixel sigma and of the constant ``sigma_disparity_px``. Then the same
2-sigma figures on rendered pairs (lab pit with a textureless patch, cliff foot). Targets:
density >= 0.9 x plain, 2-px errors <= plain, 90-99 % within 2 sigma on both.
The real pair is also scored as a drifted rig would deliver it (issue 30 item 4): the right
image one row lower (target as above) and with another exposure and noise (0.8x + 12 DN,
3 DN; density >= 0.85 x plain), with and without the flight's drift correction
(``fsw.core.stereo.rig_drift``). The table goes to ``docs/results/stereo-real.md``
(``hil_sim.lab.results``) unless ``--no-results``.
``--plot PNG`` writes the sigma calibration figure (real and rendered).
"""

from __future__ import annotations

import argparse

HELP = "stereo on real Middlebury pairs and rendered pairs against ground truth (density, errors, sigma)"
DENSITY_RATIO_MIN = 0.9
#: least density ratio to plain SGBM per condition of ``stereo_eval.CONDITIONS`` (issue 30 item 4)
CONDITION_RATIO_MIN = (DENSITY_RATIO_MIN, DENSITY_RATIO_MIN, 0.85)
WITHIN_2SIGMA = (0.90, 0.99)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--config", default=None, help="flight config (default config/fsw.toml)")
    p.add_argument("--views", type=int, default=3, help="rendered views per scenario (lab, cliff)")
    p.add_argument("--seed", type=int, default=0, help="world and camera-noise seed of the renders")
    p.add_argument("--no-results", action="store_true",
                   help="print only; do not write docs/results/stereo-real.md")
    p.add_argument("--plot", default=None, metavar="PNG",
                   help="write the sigma calibration figure here (e.g. docs/img/stereo_sigma.png)")


def _command(args: argparse.Namespace) -> str:
    """The command line that reproduces this run (for the results file)."""
    import shlex

    words = ["safer-hil", "bench", "stereo-real", "--views", str(args.views), "--seed", str(args.seed)]
    words += ["--config", args.config] if args.config else []
    words += ["--plot", args.plot] if args.plot else []
    return shlex.join(words)


def _verdict(ok: bool) -> str:
    return "meets" if ok else "MISSES"


def run(args: argparse.Namespace) -> int:
    import dataclasses
    import sys
    from pathlib import Path

    import numpy as np

    from fsw.framework.params import ConfigError
    from fsw.settings import DEFAULT_CONFIG, load_settings
    from hil_sim.lab import stereo_eval as se
    from hil_sim.lab.results import markdown_table, write_results

    if not 1 <= args.views <= 10:
        print("safer-hil bench stereo-real: --views must be 1..10", file=sys.stderr)
        return 2
    try:
        cfg = load_settings(args.config or DEFAULT_CONFIG).stereo
        real = se.middlebury_pairs()
    except (ConfigError, se.RealDataMissing) as exc:
        print(f"safer-hil bench stereo-real: {exc}", file=sys.stderr)
        return 2
    lo, hi = WITHIN_2SIGMA
    print(f"SGBM {cfg.mode}, block {cfg.block_size_px} px, {cfg.num_disparities_px} disparities; "
          f"gates: NCC >= {cfg.min_ncc:g} ({cfg.ncc_window_px} px), spread <= "
          f"{cfg.max_spread_px:g} px; sigma = sqrt({cfg.sigma_floor_px:g}^2 + "
          f"({cfg.sigma_ls_gain:g} sLS)^2 + {cfg.sigma_spread_gain:g}^2 excess spread^2)")
    panels, rows = [], []
    uncorrected = dataclasses.replace(cfg, drift_correction=False)
    for base in real:
        for cond, ratio_min in zip(se.CONDITIONS, CONDITION_RATIO_MIN, strict=True):
            pair = se.perturbed(base, cond, args.seed)
            plain = se.score(pair, cfg, se.plain_sgbm(pair, cfg))
            dm = se.matcher_for(pair, cfg).match(pair.left, pair.right)
            ours = se.score(pair, cfg, dm.disparity_px, dm.sigma_px)
            const = se.score(pair, cfg, dm.disparity_px,
                             np.full(pair.left.shape, cfg.sigma_disparity_px))
            raw = se.score(pair, cfg, se.matcher_for(pair, uncorrected).match(pair.left, pair.right).disparity_px)
            ratio = ours.density / plain.density
            al = dm.alignment
            print(f"{pair.name}:")
            print(f"  plain SGBM_3WAY   density {100 * plain.density:5.1f} %   > 2 px "
                  f"{100 * plain.bad2:5.2f} %   RMS (<= 2 px) {plain.rms_good_px:.3f} px")
            print(f"  flight matcher    density {100 * ours.density:5.1f} %   > 2 px "
                  f"{100 * ours.bad2:5.2f} %   RMS (<= 2 px) {ours.rms_good_px:.3f} px")
            print(f"  without drift correction: density {100 * raw.density:5.1f} %   > 2 px "
                  f"{100 * raw.bad2:5.2f} %")
            print(f"  drift measured: vertical offset {al.dv_px:+.2f} px, roll {al.roll_px_per_px:+.2e} px/px "
                  f"({al.matches} matches; corrected: {al.corrected}), gain {al.gain:.3f}, offset "
                  f"{al.offset_dn:+.1f} DN, noise ratio {al.noise_ratio:.2f} (smoothed: {al.denoised})")
            bad2_ok = ours.bad2 <= plain.bad2
            print(f"  density ratio {ratio:.3f} ({_verdict(ratio >= ratio_min)} >= "
                  f"{ratio_min}); 2-px errors {_verdict(bad2_ok)} <= plain")
            print(f"  within 2 sigma: per-pixel sigma {100 * ours.within_2sigma:.1f} % "
                  f"({_verdict(lo <= ours.within_2sigma <= hi)} {100 * lo:.0f}-{100 * hi:.0f} %); "
                  f"constant {cfg.sigma_disparity_px:g} px {100 * const.within_2sigma:.1f} %")
            rows.append({"pair": base.name.split(" (")[0], "right image": cond,
                         "SGBM density": plain.density, "SGBM > 2 px": plain.bad2,
                         "flight density": ours.density, "flight > 2 px": ours.bad2,
                         "density ratio": ratio, "target": f">= {ratio_min}" + ("" if cond == se.CONDITIONS[2]
                                                                                 else ", > 2 px <= SGBM"),
                         "met": "yes" if ratio >= ratio_min and (bad2_ok or cond == se.CONDITIONS[2]) else "NO",
                         "within 2 sigma": ours.within_2sigma,
                         "uncorrected density": raw.density, "uncorrected > 2 px": raw.bad2,
                         "offset px": al.dv_px, "gain": al.gain})
            if cond == se.CONDITIONS[0]:
                err, sig = se.errors_and_sigmas(pair, cfg)
                panels.append((f"real: {pair.name}", err, sig))
    errs, sigs = [], []
    for pair in se.rendered_pairs(args.views, args.seed):
        dm = se.matcher_for(pair, cfg).match(pair.left, pair.right)
        ours = se.score(pair, cfg, dm.disparity_px, dm.sigma_px)
        const = se.score(pair, cfg, dm.disparity_px,
                         np.full(pair.left.shape, cfg.sigma_disparity_px))
        print(f"{pair.name:14s} density {100 * ours.density:5.1f} %  > 2 px {100 * ours.bad2:5.2f} %"
              f"  within 2 sigma {100 * ours.within_2sigma:5.1f} % (constant "
              f"{100 * const.within_2sigma:5.1f} %)")
        e, s = se.errors_and_sigmas(pair, cfg)
        errs.append(e)
        sigs.append(s)
    err, sig = np.concatenate(errs), np.concatenate(sigs)
    within = float(np.mean(np.abs(err) <= 2 * sig))
    print(f"rendered, all views: {err.size} px, within 2 sigma {100 * within:.1f} % "
          f"({_verdict(lo <= within <= hi)} {100 * lo:.0f}-{100 * hi:.0f} %)")
    panels.append(("rendered: lab pit and cliff foot", err, sig))
    rows.append({"pair": "rendered lab pit and cliff foot, all views", "right image": "as rendered",
                 "flight density": None, "within 2 sigma": within, "target": f"within 2 sigma {lo:g}-{hi:g}",
                 "met": "yes" if lo <= within <= hi else "NO"})
    if args.plot:
        try:
            Path(args.plot).parent.mkdir(parents=True, exist_ok=True)
            se.sigma_figure(args.plot, panels)
        except (OSError, ValueError) as exc:
            print(f"safer-hil bench stereo-real: cannot write {args.plot}: {exc}", file=sys.stderr)
            return 2
        print(f"wrote {args.plot}")
    if not args.no_results:
        cols = ["pair", "right image", "SGBM density", "SGBM > 2 px", "flight density", "flight > 2 px",
                "density ratio", "target", "met", "within 2 sigma", "uncorrected density", "uncorrected > 2 px",
                "offset px", "gain"]
        write_results("stereo-real", _command(args),
                      markdown_table(rows, cols), [Path(args.plot)] if args.plot else [], kind="bench")
    return 0
