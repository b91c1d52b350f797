"""Quadtree of interest regions: entropy (Eq. 1-2), split rule, decimation, BTD (issue 6, item 1)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fsw.core.codec.quadtree import EntropyPyramid, build_quadtree, decimate, lowpass, tree_depth

WHEEL = 0.2


def _tree(z, **kw):
    args = dict(wheel_diameter_m=WHEEL, cell_m=0.02, error_bound_m=WHEEL, lowpass_sigma_cells=0.0,
                decimation_height_m=0.0)
    args.update(kw)
    return build_quadtree(np.asarray(z, np.float32), **args)


def test_entropy_matches_equations_1_and_2():
    """Issue 6, item 1: H = -sum q_k log2 q_k with q_k = f_k / N, per quad, every level."""
    rng = np.random.default_rng(0)
    bins = rng.integers(0, 5, (16, 16)).astype(np.int64)
    known = rng.random((16, 16)) > 0.2
    pyr = EntropyPyramid(bins, known)
    for lv in range(1, 5):
        h = pyr.level(lv)
        s = 1 << lv
        for iy in range(16 // s):
            for ix in range(16 // s):
                b = bins[iy * s:(iy + 1) * s, ix * s:(ix + 1) * s][known[iy * s:(iy + 1) * s, ix * s:(ix + 1) * s]]
                f = np.bincount(b) if b.size else np.zeros(1)
                q = f[f > 0] / max(1, b.size)
                assert h[iy, ix] == pytest.approx(-(q * np.log2(q)).sum(), abs=1e-9)


def test_flat_and_within_one_bin_is_one_leaf():
    """Issue 6, item 1: relief within one wheel diameter carries no information: one value."""
    assert _tree(np.zeros((64, 64))).n_leaves == 1
    ramp = np.linspace(0.0, 0.15, 64)[None, :].repeat(64, 0)
    assert _tree(ramp).n_leaves == 1


def test_a_rock_is_resolved_and_the_flat_ground_is_not():
    """Issue 6, item 1: the quad holding a rock splits down to it, the rest stays coarse."""
    z = np.zeros((128, 128), np.float32)
    z[100:104, 20:24] = 0.8  # a 8 cm wide, 0.8 m tall block (4 wheel diameters)
    t = _tree(z)
    lid = t.leaf_id_map()
    assert t.n_leaves < 40
    rock_leaves = np.unique(lid[100:104, 20:24])
    assert (t.leaf_level[rock_leaves] <= 2).all()
    assert t.leaf_level.max() >= 5  # big leaves elsewhere


def test_paper_rule_splits_when_a_child_is_more_informative():
    """Issue 6, item 1: split iff the entropy of any sub-quad exceeds the quad's (Eq. 1-2)."""
    z = np.zeros((4, 4), np.float32)
    z[0, 0] = 0.25  # one cell one bin up: parent H small, its child quad's H larger
    assert _tree(z, split_rule="entropy", error_bound_m=1.0).n_leaves == 4
    assert _tree(z, split_rule="bound", error_bound_m=1.0).n_leaves == 1


def test_leaf_bounds_are_feasible_and_cover_the_original():
    """Issue 6, item 3: every leaf's [lo, hi] holds values within the bound of all its cells."""
    rng = np.random.default_rng(4)
    z = np.cumsum(np.cumsum(rng.normal(0, 0.01, (100, 90)), 0), 1).astype(np.float32)
    z[rng.random(z.shape) < 0.05] = np.nan
    t = _tree(z, error_bound_m=0.05, quant_step_m=0.025)
    lid = t.leaf_id_map()
    known = np.isfinite(z)
    assert t.leaf_known[lid][known].all(), "a known cell is always in a known leaf"
    assert not (t.leaf_known[lid] & ~known).any(), "a known leaf never holds an unknown cell"
    lo, hi = t.leaf_lo_m[lid][known], t.leaf_hi_m[lid][known]
    assert (lo <= hi + 1e-12).all()
    assert (np.abs(lo - z[known]) <= 0.05 + 1e-9).all() and (np.abs(hi - z[known]) <= 0.05 + 1e-9).all()


def test_decimation_removes_pebbles_but_keeps_tall_narrow_rocks():
    """Issue 6, item 1 (§6.2): features narrower than the wheel and low are removed; tall stay."""
    p = np.zeros((64, 64))
    p[10, 10] = 0.05  # pebble: narrow, low
    p[40:42, 40:42] = 0.5  # spike: narrow but taller than the clearance
    d = decimate(p, footprint_cells=10, max_height_m=0.1)
    assert d[10, 10] == pytest.approx(0.0)
    assert d[40, 40] == pytest.approx(0.5)


def test_lowpass_keeps_unknown_and_smooths_noise():
    """Issue 6, item 1 (§6.1): NaN-aware low-pass."""
    rng = np.random.default_rng(1)
    z = rng.normal(0, 0.1, (64, 64))
    z[5:9, 5:9] = np.nan
    s = lowpass(z, 1.5)
    assert np.array_equal(np.isnan(s), np.isnan(z))
    assert np.nanstd(s) < 0.5 * np.nanstd(z)


def test_depth_and_reduction_factor(viking_map):
    """Issue 6, item 1: base transmission data; reduction = cells / leaves."""
    assert tree_depth((256, 256)) == 8 and tree_depth((257, 3)) == 9 and tree_depth((1, 1)) == 0
    t = _tree(viking_map, wheel_diameter_m=0.06, error_bound_m=0.06, lowpass_sigma_cells=1.0,
              decimation_height_m=0.03)
    assert t.reduction_factor == pytest.approx(256 * 256 / t.n_leaves)
    assert t.btd_bytes() == 9 * t.n_leaves
    # every cell is covered by exactly one leaf
    area = (4.0 ** t.leaf_level.astype(float)).sum()
    assert area >= 256 * 256 and math.isclose(area, 256 * 256)
