"""``safer-hil bench stereo-real``: the flight stereo against ground-truth disparity on real
Middlebury pairs and on rendered pairs (issue 14, item 4; docs/algorithm.md §4, §1.2).

For each real pair (shipped inside scikit-image, a dev dependency; ``hil_sim.lab.stereo_eval``)
it prints, for plain OpenCV SGBM_3WAY (same block size and disparity range) and for the
flight matcher with the configured filters: the density (pixels with truth that get a
disparity), the 2-px error rate, and for the flight matcher the share of errors within
2 sigma of its per-pixel sigma and of the constant ``sigma_disparity_px``. Then the same
2-sigma figures on rendered pairs (lab pit with a textureless patch, cliff foot). Targets:
density >= 0.9 x plain, 2-px errors <= plain, 90-99 % within 2 sigma on both.
``--plot PNG`` writes the sigma calibration figure (real and rendered).
"""

from __future__ import annotations

import argparse

HELP = "stereo on real Middlebury pairs and rendered pairs against ground truth (density, errors, sigma)"
DENSITY_RATIO_MIN = 0.9
WITHIN_2SIGMA = (0.90, 0.99)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--config", default=None, help="flight config (default config/fsw.toml)")
    p.add_argument("--views", type=int, default=3, help="rendered views per scenario (lab, cliff)")
    p.add_argument("--seed", type=int, default=0, help="world and camera-noise seed of the renders")
    p.add_argument("--plot", default=None, metavar="PNG",
                   help="write the sigma calibration figure here (e.g. docs/img/stereo_sigma.png)")


def _verdict(ok: bool) -> str:
    return "meets" if ok else "MISSES"


def run(args: argparse.Namespace) -> int:
    import sys
    from pathlib import Path

    import numpy as np

    from fsw.framework.params import ConfigError
    from fsw.settings import DEFAULT_CONFIG, load_settings
    from hil_sim.lab import stereo_eval as se

    if not 1 <= args.views <= 10:
        print("safer-hil bench stereo-real: --views must be 1..10", file=sys.stderr)
        return 2
    try:
        cfg = load_settings(args.config or DEFAULT_CONFIG).stereo
        real = se.middlebury_pairs()
    except (ConfigError, se.RealDataMissing) as err:
        print(f"safer-hil bench stereo-real: {err}", file=sys.stderr)
        return 2
    lo, hi = WITHIN_2SIGMA
    print(f"SGBM {cfg.mode}, block {cfg.block_size_px} px, {cfg.num_disparities_px} disparities; "
          f"gates: NCC >= {cfg.min_ncc:g} ({cfg.ncc_window_px} px), spread <= "
          f"{cfg.max_spread_px:g} px; sigma = sqrt({cfg.sigma_floor_px:g}^2 + "
          f"({cfg.sigma_ls_gain:g} sLS)^2 + {cfg.sigma_spread_gain:g}^2 excess spread^2)")
    panels = []
    for pair in real:
        plain = se.score(pair, cfg, se.plain_sgbm(pair, cfg))
        dm = se.matcher_for(pair, cfg).match(pair.left, pair.right)
        ours = se.score(pair, cfg, dm.disparity_px, dm.sigma_px)
        const = se.score(pair, cfg, dm.disparity_px,
                         np.full(pair.left.shape, cfg.sigma_disparity_px))
        ratio = ours.density / plain.density
        print(f"{pair.name}:")
        print(f"  plain SGBM_3WAY   density {100 * plain.density:5.1f} %   > 2 px "
              f"{100 * plain.bad2:5.2f} %   RMS (<= 2 px) {plain.rms_good_px:.3f} px")
        print(f"  flight matcher    density {100 * ours.density:5.1f} %   > 2 px "
              f"{100 * ours.bad2:5.2f} %   RMS (<= 2 px) {ours.rms_good_px:.3f} px")
        print(f"  density ratio {ratio:.3f} ({_verdict(ratio >= DENSITY_RATIO_MIN)} >= "
              f"{DENSITY_RATIO_MIN}); 2-px errors {_verdict(ours.bad2 <= plain.bad2)} <= plain")
        print(f"  within 2 sigma: per-pixel sigma {100 * ours.within_2sigma:.1f} % "
              f"({_verdict(lo <= ours.within_2sigma <= hi)} {100 * lo:.0f}-{100 * hi:.0f} %); "
              f"constant {cfg.sigma_disparity_px:g} px {100 * const.within_2sigma:.1f} %")
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
    if args.plot:
        try:
            Path(args.plot).parent.mkdir(parents=True, exist_ok=True)
            se.sigma_figure(args.plot, panels)
        except (OSError, ValueError) as exc:
            print(f"safer-hil bench stereo-real: cannot write {args.plot}: {exc}", file=sys.stderr)
            return 2
        print(f"wrote {args.plot}")
    return 0
