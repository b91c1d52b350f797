"""Shared checks of the resume tests (tests/integration/test_mission_resume*.py)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from hil_sim.commands.experiment_resume import compare_maps, newest


def same_maps(a: Path, b: Path) -> None:
    """The same mapped cells, counts and misses; elevations equal to rounding (a restarted
    flight computer re-reads the encoders: its odometry may differ from the uninterrupted
    run's accumulated sum by ~1e-13 m, docs/hil.md)."""
    cmp = compare_maps(a, b)
    assert cmp["cells"] == cmp["ref_cells"] and cmp["fraction"] == 1.0, cmp
    ma, mb = newest(a).emap, newest(b).emap
    for name in ("n", "misses", "outliers"):
        np.testing.assert_array_equal(getattr(ma, name), getattr(mb, name))
    np.testing.assert_allclose(mb.z[mb.mapped], ma.z[ma.mapped], rtol=0, atol=1e-9)
