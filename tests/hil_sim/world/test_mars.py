"""The Viking rock model and ``viking_heightfield`` (docs/algorithm.md, "Mars terrain
statistics"): the rock size-frequency law, rock heights, determinism and input checks.

Requirement: issue 3, "What to build" item 1 (mars: terrain from the Viking rock model with
rock coverage k and a seed); the codec's 32 test maps (docs/algorithm.md §6) use it.
"""

from __future__ import annotations

import numpy as np
import pytest

from hil_sim.world.mars import (
    VL1_K,
    VL2_K,
    area_fraction_larger,
    q_of_k,
    rocks_per_m2,
    sample_rock_diameters,
    viking_heightfield,
)


def test_q_of_k_matches_the_model():
    assert q_of_k(0.07) == pytest.approx(1.79 + 0.152 / 0.07)
    assert area_fraction_larger(0.0, VL2_K) == pytest.approx(VL2_K)


@pytest.mark.parametrize("k", [VL1_K, VL2_K])
def test_sampled_rocks_follow_the_cumulative_area_law(k):
    """The area fraction covered by sampled rocks of diameter >= D matches
    F_k(D) = k exp(-q(k) D) (within sampling noise) at several D."""
    rng = np.random.default_rng(1)
    area = 4000.0
    d = sample_rock_diameters(area, k, rng, 0.02, 3.0)
    assert len(d) == pytest.approx(rocks_per_m2(k, 0.02, 3.0) * area, rel=0.05)
    for D in (0.05, 0.2, 0.5):
        covered = np.sum(np.pi * d[d >= D] ** 2 / 4) / area
        expected = area_fraction_larger(D, k) - area_fraction_larger(3.0, k)
        assert covered == pytest.approx(expected, rel=0.15)


def test_viking_heightfield_rocks_and_relief():
    """Rocks stand about D/2 high on rolling ground; more coverage, more rock area."""
    low = viking_heightfield((512, 512), 0.02, 0.0, seed=3, relief_m=0.0)
    assert low.dtype == np.float32 and low.shape == (512, 512)
    assert np.abs(low).max() < 1e-6  # no relief, no rocks: flat
    h1 = viking_heightfield((512, 512), 0.02, VL1_K, seed=3, relief_m=0.0)
    h2 = viking_heightfield((512, 512), 0.02, VL2_K, seed=3, relief_m=0.0)
    frac1, frac2 = (h1 > 0.01).mean(), (h2 > 0.01).mean()
    assert frac1 < frac2
    # Rocks of >= 4 cm cover about F_k(0.04) minus overlaps, and the 1 cm contour trims them.
    assert 0.3 * area_fraction_larger(0.04, VL2_K) < frac2 < 1.1 * area_fraction_larger(0.04, VL2_K)
    # The tallest rock is about half the largest diameter present.
    assert 0.05 < h2.max() < 1.0
    rolling = viking_heightfield((256, 256), 0.02, VL1_K, seed=3, relief_m=0.05)
    assert 0.03 < np.median(np.abs(rolling - np.median(rolling))) / 0.6745 < 0.08


def test_viking_heightfield_is_deterministic_per_seed():
    a = viking_heightfield((128, 96), 0.03, 0.1, seed=7)
    b = viking_heightfield((128, 96), 0.03, 0.1, seed=7)
    c = viking_heightfield((128, 96), 0.03, 0.1, seed=8)
    assert a.shape == (128, 96)
    assert np.array_equal(a, b) and not np.array_equal(a, c)


@pytest.mark.parametrize("kwargs", [
    {"k": -0.1}, {"k": 0.9}, {"k": float("nan")}, {"cell_m": 0.0}, {"shape": (1, 10)},
])
def test_viking_heightfield_rejects_bad_arguments(kwargs):
    args = {"shape": (64, 64), "cell_m": 0.02, "k": 0.07, "seed": 0} | kwargs
    with pytest.raises(ValueError):
        viking_heightfield(**args)
