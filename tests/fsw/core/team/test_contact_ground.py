"""The ground under the Cliff-bot's body is known by contact (fsw.core.team.contact_ground)."""

from __future__ import annotations

import numpy as np

from fsw.core.geometry import MapGrid
from fsw.core.team.contact_ground import fill_under_body

GRID = MapGrid(0.0, 0.0, 0.04, 60, 60)


def _plane() -> np.ndarray:
    x, y = GRID.centers()
    return 0.1 * x - 0.05 * y + 0.3


def _hidden(z: np.ndarray, xy: tuple[float, float], r: float) -> np.ndarray:
    x, y = GRID.centers()
    out = z.copy()
    out[np.hypot(x - xy[0], y - xy[1]) <= r] = np.nan
    return out


def test_the_hidden_disc_under_the_body_takes_the_ring_plane_and_known_cells_stay() -> None:
    truth = _plane()
    z = _hidden(truth, (1.2, 1.2), 0.35)
    filled, n = fill_under_body(z, GRID, np.array([1.2, 1.2]), 0.38)
    assert n == int(np.isnan(z).sum()) > 0
    assert np.allclose(filled, truth, atol=1e-9)
    known = np.isfinite(z)
    assert np.array_equal(filled[known], z[known])


def test_a_ring_that_is_not_a_plane_or_mostly_unknown_fills_nothing() -> None:
    rough = _hidden(_plane() + np.where(GRID.centers()[0] > 1.2, 0.3, 0.0), (1.2, 1.2), 0.35)  # a step
    out, n = fill_under_body(rough, GRID, np.array([1.2, 1.2]), 0.38)
    assert n == 0 and np.array_equal(np.isnan(out), np.isnan(rough))
    half = _hidden(_plane(), (1.2, 1.2), 0.35)
    half[:, :30] = np.nan  # the ring known on one side only
    out, n = fill_under_body(half, GRID, np.array([1.2, 1.2]), 0.38)
    assert n == 0 and np.array_equal(np.isnan(out), np.isnan(half))


def test_bad_positions_and_edges_of_the_map_are_harmless() -> None:
    z = _hidden(_plane(), (0.05, 0.05), 0.35)
    for xy in ([np.nan, 1.0], [np.inf, 0.0], [50.0, 50.0], [0.05, 0.05]):
        out, n = fill_under_body(z, GRID, np.array(xy), 0.38)
        assert out.shape == z.shape and np.isfinite(out[np.isfinite(z)]).all()
