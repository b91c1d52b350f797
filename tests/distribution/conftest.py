"""Fixtures of the map distribution tests (issue 6)."""

from __future__ import annotations

import numpy as np
import pytest


@pytest.fixture(scope="session")
def viking_map() -> np.ndarray:
    """A 256 x 256 Viking-model Mars map at 2 cm (the world engineer's generator)."""
    from hil_sim.world.mars import viking_heightfield

    return viking_heightfield((256, 256), 0.02, 0.12, seed=5)
