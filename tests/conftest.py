"""Shared fixtures, and ``tests/support`` (helper modules with unique names) on the import path.

The tree mirrors the packages: ``tests/fsw/<layer>/``, ``tests/hil_sim/``, ``tests/ground/``;
end-to-end runs are under ``tests/integration/``.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

import numpy as np
import pytest

os.environ.setdefault("MPLBACKEND", "Agg")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
SUPPORT = Path(__file__).resolve().parent / "support"
sys.path.insert(0, str(SUPPORT))


@pytest.fixture(scope="session")
def viking_map() -> np.ndarray:
    """A 256 x 256 Viking-model Mars map at 2 cm (the world's generator)."""
    from hil_sim.world.mars import viking_heightfield

    return viking_heightfield((256, 256), 0.02, 0.12, seed=5)
