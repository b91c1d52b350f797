"""The received map and the Cliff-bot's own views as one map (fsw.core.team.own_views,
docs/algorithm.md §8.1): past a lip its nearer views decide, on level ground the received map stands."""

from __future__ import annotations

import numpy as np

from fsw.core.team.own_views import merge_own, received_variance

CELL = 0.04
E = 0.03  # the codec's bound


def lip_scene() -> tuple[np.ndarray, np.ndarray]:
    """A plateau (rows 0-19, z = 0) and a 75 deg face below it (rows 20-39); the received map
    reads the first 5 rows past the lip 0.2 m high (the plateau carried over the edge)."""
    truth = np.zeros((40, 20))
    truth[20:] = -np.tan(np.radians(75.0)) * CELL * (np.arange(20)[:, None] + 1)
    received = truth.copy()
    received[20:25] += 0.2
    return truth, received


def test_received_variance_grows_with_slope_not_on_level_ground() -> None:
    truth, _ = lip_scene()
    var = received_variance(truth, CELL, E, 0.08)
    assert np.allclose(var[:15], E ** 2 / 3.0)  # level: the codec's error only
    face = np.sqrt(var[25:35])
    assert (face > 0.25).all()  # 75 deg: a horizontal error of 8 cm moves the height ~0.3 m
    var_nan = received_variance(np.where(np.arange(40)[:, None] < 10, np.nan, truth), CELL, E, 0.08)
    assert np.isinf(var_nan[:10]).all() and np.isfinite(var_nan[10:]).all()


def test_own_views_correct_the_band_past_the_lip() -> None:
    truth, received = lip_scene()
    rng = np.random.default_rng(0)
    own = truth + rng.normal(0.0, 0.05, truth.shape)
    own_var = np.full(truth.shape, 0.05 ** 2)
    merged, mine = merge_own(received, own, own_var, CELL, E, 0.08)
    assert mine.all()
    band = slice(20, 25)
    assert np.abs(received[band] - truth[band]).min() >= 0.2 - 1e-9
    d = merged[band] - truth[band]
    assert abs(float(d.mean())) < 0.03 and float(np.sqrt(np.mean(d ** 2))) < 0.06  # its own views decide there
    # on the plateau the received map stands: its own noise moves it by a small share only
    assert np.abs(merged[:15] - truth[:15]).max() < 0.2 * np.abs(own[:15] - truth[:15]).max()


def test_own_cells_fill_unknown_cells_and_leave_the_rest() -> None:
    truth, received = lip_scene()
    received[30:] = np.nan
    own = np.full(truth.shape, np.nan)
    own[32:35, 5:9] = truth[32:35, 5:9]
    own_var = np.where(np.isfinite(own), 0.05 ** 2, np.inf)
    merged, mine = merge_own(received, own, own_var, CELL, E, 0.08)
    assert np.array_equal(merged[32:35, 5:9], truth[32:35, 5:9])
    assert np.array_equal(np.isfinite(merged), np.isfinite(received) | np.isfinite(own))
    assert np.array_equal(merged[:30], received[:30])  # no own cell there: the received map as it came
    assert int(mine.sum()) == 12
