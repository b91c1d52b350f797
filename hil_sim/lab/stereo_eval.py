"""Stereo against ground-truth disparity: real Middlebury pairs and rendered pairs (issue 14).

Everything here may look at the truth; nothing here is flight code. The flight side is
``fsw.core.stereo.stereo`` and ``fsw.core.stereo.stereo_quality`` (docs/algorithm.md §4, §1.2).

**Real pairs.** No package on the index ships the Middlebury 2014 files themselves
(``stereo-mideval`` holds only a downloader). scikit-image ships one Middlebury 2014 pair with
its ground truth inside its wheel: "Motorcycle", reduced to 741x500, left and right image
and the left disparity (``skimage.data.stereo_motorcycle``, no download). It is loaded at
run time from the installed package (a dev/test dependency); nothing is copied into the repo.

**Rendered pairs.** Views of the lab pit (with the 1 m textureless patch of
``PERCEPTION_LAB``) and of the cliff, with the disparity ``f B / Z`` from the rendered depth.

The figures per pair (:class:`StereoScore`): the share of the pixels with ground truth that
get a disparity (density), the share of those off by more than 2 px, and the share whose
error lies within 2 sigma of the per-pixel sigma. Pixels in the left ``num_disparities``
columns, which no matcher can match with that range, are not counted for anyone.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from fsw.core.geometry import CameraConfig
from fsw.core.stereo.stereo import StereoConfig, StereoMatcher

F64 = NDArray[np.float64]
U8 = NDArray[np.uint8]


@dataclass(frozen=True)
class TruthPair:
    """A rectified pair with the left image's true disparity (NaN: unknown)."""

    name: str
    left: U8
    right: U8
    disparity_px: F64


@dataclass(frozen=True)
class StereoScore:
    """One matcher on one pair, against the truth."""

    density: float  # returned pixels / pixels with truth (matchable columns)
    bad2: float  # returned pixels with |error| > 2 px
    within_2sigma: float  # returned pixels with |error| <= 2 sigma (NaN: no sigma)
    rms_good_px: float  # RMS error of the returned pixels with |error| <= 2 px
    returned: int


class RealDataMissing(RuntimeError):
    """The package that ships the real pairs is not installed."""


def middlebury_pairs() -> list[TruthPair]:
    """The real rectified pairs with ground truth that the installed packages ship."""
    try:
        from skimage import data
    except ImportError as err:  # a dev/test dependency
        raise RealDataMissing("scikit-image is not installed (pip install -e '.[dev]')") from err
    left, right, disp = data.stereo_motorcycle()
    gray = [np.ascontiguousarray(cv2.cvtColor(im, cv2.COLOR_RGB2GRAY)) for im in (left, right)]
    truth = np.where(np.isfinite(disp), disp, np.nan).astype(np.float64)
    return [TruthPair("Middlebury 2014 Motorcycle (scikit-image, 741x500)", gray[0], gray[1],
                      truth)]


#: the drifted-rig conditions of ``bench stereo-real`` (issue 30 item 4): name and what it does to the right image
CONDITIONS = ("as recorded", "right image 1 px lower", "right exposure 0.8x + 12 DN, 3 DN noise")


def perturbed(pair: TruthPair, condition: str, seed: int = 0) -> TruthPair:
    """``pair`` with its right image changed as a drifted rig would: shifted one row down (a
    rectification that drifted) or with another exposure and more noise (a camera of its own gain)."""
    r = pair.right
    if condition == CONDITIONS[0]:
        return pair
    if condition == CONDITIONS[1]:
        right = np.ascontiguousarray(np.vstack([r[:1], r[:-1]]))
    elif condition == CONDITIONS[2]:
        noise = np.random.default_rng(seed).normal(0.0, 3.0, r.shape)
        right = np.clip(np.rint(0.8 * r.astype(np.float64) + 12.0 + noise), 0, 255).astype(np.uint8)
    else:
        raise ValueError(f"unknown condition {condition!r}; one of {', '.join(CONDITIONS)}")
    return TruthPair(f"{pair.name}, {condition}", pair.left, right, pair.disparity_px)


def rendered_pairs(views: int = 3, seed: int = 0) -> list[TruthPair]:
    """Rendered pairs of the lab pit (textureless patch in view) and the cliff foot."""
    from fsw.settings import DEFAULT_CONFIG, load_settings
    from hil_sim.lab.perception_eval import PERCEPTION_LAB, pit_view_poses
    from hil_sim.render import StereoRenderer
    from hil_sim.world import load_scenario

    cfg = load_settings(DEFAULT_CONFIG)
    fb = cfg.camera.focal_px * cfg.camera.baseline_m
    out = []
    for spec in (PERCEPTION_LAB, "cliff"):
        world = load_scenario(spec, seed)
        rend = StereoRenderer(world, cfg.camera, world.noise_sigma, seed=seed)
        for i, pose in enumerate(pit_view_poses(world, cfg.mast, views, seed=1)):
            left, right = rend.render(pose)
            with np.errstate(divide="ignore", invalid="ignore"):
                truth = fb / rend.render_depth(pose).astype(np.float64)
            out.append(TruthPair(f"{world.name} view {i}", left, right, truth))
    return out


def matcher_for(pair: TruthPair, cfg: StereoConfig) -> StereoMatcher:
    """The flight matcher for a pair of any size (the camera only fixes the image shape)."""
    h, w = pair.left.shape
    return StereoMatcher(cfg, CameraConfig(width_px=w, height_px=h))


def plain_sgbm(pair: TruthPair, cfg: StereoConfig) -> F64:
    """OpenCV SGBM_3WAY with the same block size and disparity range and OpenCV's usual
    smoothness (P1 = 8 and P2 = 32 per window pixel), no other filter."""
    bs = cfg.block_size_px
    sgbm = cv2.StereoSGBM.create(minDisparity=cfg.min_disparity_px,
                                 numDisparities=cfg.num_disparities_px, blockSize=bs,
                                 P1=8 * bs * bs, P2=32 * bs * bs,
                                 mode=cv2.StereoSGBM_MODE_SGBM_3WAY)
    raw = sgbm.compute(pair.left, pair.right)
    d = raw.astype(np.float64) / cv2.StereoMatcher_DISP_SCALE
    d[raw < cfg.min_disparity_px * cv2.StereoMatcher_DISP_SCALE] = np.nan
    return d


def scored_mask(pair: TruthPair, cfg: StereoConfig) -> NDArray[np.bool_]:
    """Pixels that count: truth known and a partner possible within the disparity range."""
    mask = np.isfinite(pair.disparity_px)
    mask[:, : cfg.min_disparity_px + cfg.num_disparities_px] = False
    return mask


def score(pair: TruthPair, cfg: StereoConfig, disp: F64, sigma: F64 | None = None) -> StereoScore:
    """Density, 2-px error rate and 2-sigma coverage of ``disp`` on ``pair``."""
    mask = scored_mask(pair, cfg)
    ret = mask & np.isfinite(disp)
    err = np.abs(disp[ret] - pair.disparity_px[ret])
    n = int(ret.sum())
    if n == 0:
        return StereoScore(0.0, math.nan, math.nan, math.nan, 0)
    within = math.nan if sigma is None else float(np.mean(err <= 2.0 * sigma[ret]))
    good = err[err <= 2.0]
    return StereoScore(n / max(1, int(mask.sum())), float(np.mean(err > 2.0)), within,
                       float(np.sqrt(np.mean(good**2))) if good.size else math.nan, n)


def errors_and_sigmas(pair: TruthPair, cfg: StereoConfig) -> tuple[F64, F64]:
    """Signed disparity error and predicted sigma of the flight matcher's returned pixels."""
    dm = matcher_for(pair, cfg).match(pair.left, pair.right)
    ret = scored_mask(pair, cfg) & np.isfinite(dm.disparity_px)
    return dm.disparity_px[ret] - pair.disparity_px[ret], dm.sigma_px[ret]


def sigma_figure(path: str, panels: list[tuple[str, F64, F64]]) -> None:
    """PNG of the per-pixel disparity sigma against the actual error, one column per panel
    ``(title, error_px, sigma_px)``: per bin of predicted sigma, the share of errors within 1
    and 2 sigma against a Gaussian's 68 and 95 % (top), and the histogram of ``error / sigma``
    against the unit normal (bottom)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import FormatStrFormatter, NullFormatter

    fig, axes = plt.subplots(2, len(panels), figsize=(5.0 * len(panels), 8.0), squeeze=False)
    for col, (title, err, sig) in enumerate(panels):
        ax = axes[0, col]
        edges = np.quantile(sig, np.linspace(0.0, 1.0, 21))
        idx = np.clip(np.searchsorted(edges, sig, side="right") - 1, 0, len(edges) - 2)
        bins = range(len(edges) - 1)
        xs = [float(np.median(sig[idx == b])) for b in bins]
        for k, ref, colour in ((1.0, 0.683, "C0"), (2.0, 0.954, "C3")):
            ys = [100 * float(np.mean(np.abs(err[idx == b]) <= k * sig[idx == b])) for b in bins]
            ax.plot(xs, ys, "o-", color=colour, label=f"|error| <= {k:g} sigma, per sigma bin")
            ax.axhline(100 * ref, color=colour, ls=":", lw=1)
        ax.set_xscale("log")
        ax.xaxis.set_minor_formatter(NullFormatter())
        ax.xaxis.set_major_formatter(FormatStrFormatter("%g"))
        ax.set_ylim(0, 100)
        ax.set_xlabel("predicted disparity sigma (px), bins of 5 % of the pixels")
        ax.set_ylabel("share of the bin's pixels (%); dotted: a Gaussian's")
        within = 100.0 * float(np.mean(np.abs(err) <= 2.0 * sig))
        ax.set_title(f"{title}\n{err.size} px, {within:.1f} % within 2 sigma, "
                     f"{100 * np.mean(np.abs(err) > 2.0):.2f} % > 2 px", fontsize=9)
        ax.legend(fontsize=8, loc="lower right")
        ax = axes[1, col]
        ax.hist(np.clip(err / sig, -6, 6), bins=np.linspace(-6, 6, 73), density=True,
                color="C0", alpha=0.7, label="error / sigma (clipped to +-6)")
        g = np.linspace(-6, 6, 200)
        ax.plot(g, np.exp(-0.5 * g * g) / math.sqrt(2 * math.pi), "k-", label="unit normal")
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)
