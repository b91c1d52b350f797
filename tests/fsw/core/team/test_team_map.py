"""The map the Cliff-bot plans on: the received map and its own fused by variance
(fsw.core.team.team_map; docs/algorithm.md §8, "Fusion from several agents", §1.1)."""

from __future__ import annotations

import math

import numpy as np

from fsw.core.team.team_map import merge_received

E = 0.03  # the codec's bound: a received cell's variance floor e^2 / 3


def _one(zr: float, zo: float, sigma_o: float, e: float = E) -> tuple[float, bool, bool]:
    m = merge_received(np.array([[zr]]), e, np.array([[zo]]), np.array([[sigma_o ** 2]]), 3.0)
    return float(m.z[0, 0]), bool(m.fused[0, 0]), bool(m.disputed[0, 0])


def test_within_the_gate_the_heights_are_weighed_by_their_variances() -> None:
    vr = E * E / 3.0
    z, fused, disputed = _one(1.0, 1.02, 0.02)
    assert fused and not disputed
    assert math.isclose(z, (0.02 ** 2 * 1.0 + vr * 1.02) / (0.02 ** 2 + vr))
    assert 1.0 < z < 1.02


def test_a_received_cell_off_beyond_both_variances_takes_its_own_nearer_height() -> None:
    # the RECON-bot's height past the lip 15 cm over the ground; its own view 2 cm sigma
    z, fused, disputed = _one(1.15, 1.0, 0.02)
    assert disputed and not fused and z == 1.0


def test_a_cell_one_map_knows_takes_its_height_and_an_exact_received_map_wins() -> None:
    zr = np.array([[1.0, np.nan, np.nan, 2.0]])
    zo = np.array([[np.nan, 0.5, np.nan, 2.5]])
    m = merge_received(zr, E, zo, np.full(zo.shape, 1e-4), 3.0)
    assert m.z[0, 0] == 1.0 and m.z[0, 1] == 0.5 and np.isnan(m.z[0, 2])
    assert m.own_only.tolist() == [[False, True, False, False]] and m.disputed[0, 3] and m.z[0, 3] == 2.5
    exact = merge_received(zr, 0.0, zo, np.full(zo.shape, 1e-4), 3.0)  # no bound: the received map as sent
    assert exact.z[0, 3] == 2.0 and not exact.disputed.any() and not exact.fused.any()
    bad = merge_received(zr, math.nan, zo, np.full(zo.shape, np.inf), 3.0)  # no variance: not its own measurement
    assert bad.z[0, 3] == 2.0 and np.isnan(bad.z[0, 1])
