"""The ground under the Cliff-bot's body is known by contact, and its height where the map does not know
it (fsw.core.team.contact_ground)."""

from __future__ import annotations

import numpy as np

from fsw.core.geometry import MapGrid
from fsw.core.team.contact_ground import body_height, fill_under_body
from fsw.core.team.tether import TetherConfig, anchor_points, tether_state

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


# -- the ground height under the body where the map does not know it -------------------------------

SLOPE = np.radians(70.0)


def _lip(slope: float = SLOPE) -> tuple[np.ndarray, MapGrid, np.ndarray]:
    """A plateau at 0 m ending at y = 0 in a face (70 deg); the tethers' exits 0.3 m above it."""
    grid = MapGrid(-2.5, -2.0, 0.05, 100, 80)
    _, y = grid.centers()
    z = np.where(y > 0, 0.0, np.maximum(np.tan(slope) * y, -3.0)).astype(np.float64)
    cfg = TetherConfig()
    return z, grid, anchor_points(z, grid, np.array([[-1.5, 1.5], [1.5, 1.5]]), cfg)


def _paid_out(z: np.ndarray, grid: MapGrid, anchors: np.ndarray, xy: np.ndarray) -> tuple[float, float]:
    st = tether_state(z, grid, anchors, xy, TetherConfig())
    assert st is not None
    return st.lengths_m


def test_a_thin_ring_gives_way_to_the_tethers_on_the_plateau_by_the_lip() -> None:
    z, grid, anchors = _lip(np.radians(85.0))
    body = np.array([0.0, 0.4])  # on the plateau, 0.4 m from the lip
    X, Y = grid.centers()
    d = np.hypot(X - body[0], Y - body[1])
    seen = np.where(d > 1.0, z, np.nan)  # the map does not know the ground round the body ...
    face = (d < 0.5) & (Y < 0.0) & (np.abs(X) < 0.1)
    seen[face] = z[face]  # ... but for a few face cells below the lip (seed 3's ring)
    assert 0 < face.sum() < 12 and np.median(z[face]) < -0.4  # the median of the ring: far too low
    h, how = body_height(seen, grid, body, anchors, TetherConfig(), lengths=_paid_out(z, grid, anchors, body))
    assert how == "tethers" and abs(h) < 0.03, (h, how)
    # without the tethers' lengths, the thin ring is all there is, and says so
    assert body_height(seen, grid, body, anchors, TetherConfig())[1] == "thin ring"


def test_on_the_face_the_tethers_over_the_lip_give_the_height_and_a_full_ring_its_median() -> None:
    z, grid, anchors = _lip()
    body = np.array([0.2, -0.6])  # on the face, the tethers over the lip
    X, Y = grid.centers()
    d = np.hypot(X - body[0], Y - body[1])
    seen = np.where(d > 0.6, z, np.nan)
    n = np.array([0.0, -np.tan(SLOPE), 1.0]) / np.hypot(np.tan(SLOPE), 1.0)  # the face's (the attitude's)
    h, how = body_height(seen, grid, body, anchors, TetherConfig(), lengths=_paid_out(z, grid, anchors, body),
                         normal=n)
    truth = float(np.tan(SLOPE) * body[1])
    assert how == "tethers" and abs(h - truth) < 0.03, (h, truth)
    ring = np.where(d > 0.3, z, np.nan)  # a ring all round within 0.5 m
    h, how = body_height(ring, grid, body, anchors, TetherConfig(), lengths=None)
    assert how == "ring" and abs(h - truth) < 0.1
