"""A task's focus regions weight the interest function (fsw.core.planning.nbv, docs/algorithm.md §3.4)."""

from __future__ import annotations

import numpy as np
import pytest

from fsw.core.geometry import MapGrid
from fsw.core.planning.nbv import NbvConfig, cell_values, focus_weights

GRID = MapGrid(0.0, 0.0, 0.5, 8, 4)  # x 0..4 m, y 0..2 m


def test_focus_weights_cover_the_regions_cells() -> None:
    w = focus_weights(GRID, ((1.0, 0.0, 2.0, 1.0, 3.0), (1.9, 0.4, 4.0, 2.0, 2.0)))
    assert w.shape == (4, 8)
    # cell centres x = 0.25 + 0.5 i, y = 0.25 + 0.5 j
    assert w[0, 2] == 3.0 and w[1, 3] == 3.0  # inside the first only
    assert w[1, 5] == 2.0 and w[3, 7] == 2.0  # inside the second only
    assert w[0, 0] == 1.0 and w[3, 0] == 1.0  # outside both
    assert (focus_weights(GRID, ()) == 1.0).all()


def test_a_weight_multiplies_the_bits_and_the_interest_the_visibility() -> None:
    pv = np.array([0.8, 0.8, 0.8, 0.8])
    n = np.zeros(4, np.int32)
    bits, new = cell_values(pv, n, 2, np.array([1.0, 1.0, 0.5, 1.0]), weight=np.array([1.0, 3.0, 1.0, 1.5]))
    base, _ = cell_values(pv, n, 2, None)
    assert bits[0] == pytest.approx(base[0])
    assert bits[1] == pytest.approx(3.0 * base[0]) and bits[3] == pytest.approx(1.5 * base[0])
    assert 0.0 < bits[2] < base[0]  # P_V scaled by 0.5: fewer bits (§3.4)
    # an interest above 1 is no weight: it counts as 1
    assert cell_values(pv, n, 2, np.full(4, 3.0))[0].tolist() == pytest.approx(base.tolist())
    # expected new cells are P_V times the stereo's return, whatever the interest (it ranks, it is no probability)
    assert new.tolist() == pytest.approx([0.8, 0.8, 0.8, 0.8])
    assert cell_values(pv, n, 2, None, stereo_return=0.5)[1].tolist() == pytest.approx([0.4] * 4)


@pytest.mark.parametrize("row", [(0.0, 0.0, 1.0), (1.0, 0.0, 0.0, 1.0, 2.0), (0.0, 0.0, 1.0, 1.0, 0.5),
                                 (0.0, 0.0, float("nan"), 1.0, 2.0)])
def test_bad_focus_regions_are_refused(row: tuple[float, ...]) -> None:
    with pytest.raises(ValueError, match="focus region"):
        NbvConfig(focus_regions=(row,))
