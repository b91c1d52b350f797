"""Tether statics (docs/algorithm.md §8): the taut path over the ground, equilibrium, forward kinematics."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fsw.core.geometry import MapGrid
from fsw.core.team.tether import TetherConfig, anchor_points, statics, tether_path, tether_state, upper_hull
from fsw.core.team.tether_settle import settle

SLOPE = math.radians(75.0)


def cliff(drop_m: float = 3.0, cell: float = 0.03) -> tuple[np.ndarray, MapGrid]:
    """A plateau (z = 0) for y > 0, a 75 deg face down to -drop_m, a level floor below."""
    grid = MapGrid(-3.0, -3.0, cell, 200, 184)
    _, y = grid.centers()
    z = np.where(y > 0, 0.0, np.maximum(math.tan(SLOPE) * y, -drop_m))
    return z.astype(np.float32), grid


def test_upper_hull_is_the_taut_string() -> None:
    s = np.array([0.0, 1.0, 2.0, 3.0, 4.0])
    h = np.array([0.0, -1.0, 1.0, -1.0, 0.0])  # a hump in the middle: the one contact
    assert upper_hull(s, h).tolist() == [0, 2, 4]
    assert upper_hull(s, -np.abs(h)).tolist() == [0, 4]  # nothing above the chord: straight


def test_tether_goes_over_the_lip() -> None:
    z, grid = cliff()
    cfg = TetherConfig()
    anchor = np.array([0.0, 1.5, 0.3])
    bot = np.array([0.0, -0.3, math.tan(SLOPE) * -0.3 + 0.15])
    p = tether_path(z, grid, anchor, bot, cfg)
    assert len(p.contacts) >= 1
    lip = p.contacts[np.argmin(np.abs(p.contacts[:, 1]))]
    assert abs(lip[1]) < 2 * grid.cell and abs(lip[2]) < math.tan(SLOPE) * grid.cell
    expected = np.linalg.norm(anchor - lip) + np.linalg.norm(bot - lip)
    assert p.length_m == pytest.approx(expected, abs=0.03)
    assert p.length_m > np.linalg.norm(anchor - bot)  # the lip lengthens it
    assert p.pull[2] > 0.9  # hanging below the lip, the pull is nearly straight up


def test_equilibrium_symmetric_and_slack() -> None:
    z, grid = cliff()
    cfg = TetherConfig()
    anchors = anchor_points(z, grid, np.array([[-1.5, 1.5], [1.5, 1.5]]), cfg)
    mid = tether_state(z, grid, anchors, np.array([0.0, -0.4]), cfg)
    assert mid is not None and mid.statics.ok, mid
    t1, t2 = mid.statics.tensions_n
    assert t1 == pytest.approx(t2, rel=0.05)
    # Weight shared by two tethers and the face: each tension below the weight, the sum above
    # the weight's along-face part.
    w = cfg.mass_kg * cfg.gravity_mps2
    assert t1 < w and t1 + t2 > 0.8 * w * math.sin(SLOPE)
    # Far to one side of both anchors the tethers pull sideways the same way: one goes slack.
    side = tether_state(z, grid, anchors, np.array([2.8, -0.6]), cfg)
    assert side is not None and not side.statics.ok and side.statics.reason in ("slack", "over-tension")


def test_statics_refuses_a_degenerate_pull() -> None:
    u = np.array([1.0, 0.0, 0.0])
    st = statics(u, -u, np.array([0.0, 1.0, 0.0]), TetherConfig())
    assert not st.ok and st.reason == "degenerate"


@pytest.mark.parametrize("xy", [(0.0, -0.3), (-0.6, -0.5), (0.7, -0.2)])
def test_settle_inverts_the_tether_lengths(xy: tuple[float, float]) -> None:
    z, grid = cliff()
    cfg = TetherConfig()
    anchors = anchor_points(z, grid, np.array([[-1.5, 1.5], [1.5, 1.5]]), cfg)
    truth = tether_state(z, grid, anchors, np.array(xy), cfg)
    assert truth is not None
    got = settle(z, grid, anchors, truth.lengths_m, np.array(xy) + np.array([0.15, 0.1]), cfg)
    assert got is not None
    assert np.hypot(*(got[0] - np.array(xy))) < 2 * grid.cell


def test_anchor_on_unknown_ground_is_refused() -> None:
    z, grid = cliff()
    z[150:, :] = np.nan
    with pytest.raises(ValueError, match="does not know"):
        anchor_points(z, grid, np.array([[0.0, 1.8]]), TetherConfig())
