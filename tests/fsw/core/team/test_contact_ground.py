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


def test_the_body_mapped_as_a_box_takes_the_ring_plane_and_a_lip_in_the_ring_does_not_tilt_it() -> None:
    """The RECON-bot maps the Cliff-bot's box where it stands; a lip cuts a quarter of the ring:
    the box's cells within ``body_m`` become the ground (the plateau's plane), the face stays."""
    truth = _plane()
    x, y = GRID.centers()
    z = truth.copy()
    box = (np.abs(x - 1.2) <= 0.22) & (np.abs(y - 1.2) <= 0.3)
    z[box] = truth[box] + 0.35  # the body's top
    z[(np.abs(x - 1.45) <= 0.15) & (np.abs(y - 1.2) <= 0.3)] = np.nan  # its shadow
    face = (x > 1.6) & (y < 1.0)
    z[face] = truth[face] - 0.8  # below the lip
    out, n = fill_under_body(z, GRID, np.array([1.2, 1.2]), 0.38, body_m=0.48)
    under = np.hypot(x - 1.2, y - 1.2) <= 0.38
    assert n > int(box.sum()) // 2
    assert np.allclose(out[under & ~face], truth[under & ~face], atol=1e-6)  # box and shadow: the ground
    assert np.array_equal(out[face], z[face])  # the face below the lip is never changed
    np.testing.assert_array_equal(out[~under & ~box], z[~under & ~box])
    # without the body's radius the box stays (only unknown cells are filled within radius_m)
    kept, _ = fill_under_body(z, GRID, np.array([1.2, 1.2]), 0.38, body_m=0.0)
    assert (kept[box & ~under] == z[box & ~under]).all()


def test_a_ring_as_coarse_as_the_received_map_fills_only_within_the_bound_it_is_given() -> None:
    """A received map quantised in 6 cm steps is not flat within 3 cm, but is within half a
    0.12 m codec bound."""
    z = _hidden(np.round(_plane() / 0.06) * 0.06, (1.2, 1.2), 0.35)
    assert fill_under_body(z, GRID, np.array([1.2, 1.2]), 0.38, max_rms_m=0.01)[1] == 0
    assert fill_under_body(z, GRID, np.array([1.2, 1.2]), 0.38, max_rms_m=0.06)[1] == int(np.isnan(z).sum())
