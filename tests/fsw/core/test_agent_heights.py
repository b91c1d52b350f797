"""The heights the Cliff-bot plans on from the received map and its own (fsw.core.map.agent_heights)."""

from __future__ import annotations

import numpy as np
import pytest

from fsw.core.map.agent_heights import plan_heights

NAN = np.nan


def test_a_cell_only_one_map_knows_keeps_that_maps_height() -> None:
    received = np.array([[0.10, NAN, NAN]])
    own = np.array([[NAN, 0.20, NAN]])
    got = plan_heights(received, 0.02, own, np.full((1, 3), 1e-4), 0.05, 3.0)
    assert got.z[0, 0] == 0.10 and got.z[0, 1] == 0.20 and np.isnan(got.z[0, 2])
    assert (got.filled, got.fused, got.own_won, got.received_won) == (1, 0, 0, 0)


def test_agreeing_heights_take_their_inverse_variance_mean() -> None:
    sigma_r, bound, v_own = 0.05, 0.03, 0.02 ** 2
    v_r = sigma_r ** 2 + bound ** 2 / 3.0
    got = plan_heights(np.array([[1.00]]), bound, np.array([[1.04]]), np.array([[v_own]]), sigma_r, 3.0)
    want = (1.00 / v_r + 1.04 / v_own) / (1.0 / v_r + 1.0 / v_own)
    assert got.z[0, 0] == pytest.approx(want, abs=1e-12)
    assert got.fused == 1 and got.own_won == got.received_won == 0


def test_disagreeing_heights_keep_the_one_with_the_smaller_variance() -> None:
    """A trench of received heights 0.3 m below the ground behind a lip, its own views at the
    ground to 3 cm: its own stand, not a mean that keeps a third of the trench."""
    received = np.array([[-0.30, 0.0]])
    own = np.array([[0.00, 0.60]])
    var = np.array([[0.03 ** 2, 0.08 ** 2]])  # the second: its own view worse than the received (5 cm)
    got = plan_heights(received, 0.01, own, var, 0.05, 3.0)
    assert got.z[0, 0] == 0.0  # its own, alone
    assert got.z[0, 1] == 0.0  # the received, alone
    assert (got.fused, got.own_won, got.received_won) == (0, 1, 1)


def test_bad_own_variance_never_enters_and_the_received_map_is_not_changed() -> None:
    received = np.array([[0.5, 0.5, 0.5]])
    own = np.array([[0.0, 0.0, 0.0]])
    var = np.array([[NAN, -1.0, np.inf]])
    got = plan_heights(received, 0.01, own, var, 0.05, 3.0)
    assert np.array_equal(got.z, received)
    assert received[0, 0] == 0.5  # the caller's array untouched
    assert (got.filled, got.fused, got.own_won, got.received_won) == (0, 0, 0, 0)
