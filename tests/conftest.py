"""Shared fixtures, and ``tests/support`` (helper modules with unique names) on the import path.

The tree mirrors the packages: ``tests/fsw/<layer>/``, ``tests/hil_sim/``, ``tests/ground/``;
end-to-end runs are under ``tests/integration/``.
"""

from __future__ import annotations

import os
import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest

os.environ.setdefault("MPLBACKEND", "Agg")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
# Experiment commands run by tests write their result files here, never into docs/results.
os.environ["SAFER_RESULTS_DIR"] = tempfile.mkdtemp(prefix="safer-results-")
SUPPORT = Path(__file__).resolve().parent / "support"
sys.path.insert(0, str(SUPPORT))


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Files with ``slow`` tests run first, the most slow tests first (stable otherwise).

    ``make unit`` runs ``-n 2 --dist loadfile --no-loadscope-reorder``: the two workers take
    whole files in this order, so the long files start early and the many short ones fill in
    behind them, and both workers finish close together. (xdist's default order, the files
    with the most tests first, left the one-test end-to-end files for last: a long pole.)

    Hypothesis tests time out by pytest-timeout's ``thread`` method (stacks dumped, the
    process ended): the default ``signal`` method raises ``pytest.fail`` inside the running
    example, Hypothesis takes that for a failure of the example and replays it, the replay
    does not time out and draws further, and the timeout is reported as
    ``FlakyStrategyDefinition`` ("the second run drew more data than the first run").
    """
    slow: dict[Path, int] = {}
    for item in items:
        if item.get_closest_marker("slow") is not None:
            slow[item.path] = slow.get(item.path, 0) + 1
        if getattr(getattr(item, "obj", None), "is_hypothesis_test", False) \
                and item.get_closest_marker("timeout") is None:
            item.add_marker(pytest.mark.timeout(method="thread"))
    items.sort(key=lambda item: -slow.get(item.path, 0))


@pytest.fixture(scope="session")
def viking_map() -> np.ndarray:
    """A 256 x 256 Viking-model Mars map at 2 cm (the world's generator)."""
    from hil_sim.world.mars import viking_heightfield

    return viking_heightfield((256, 256), 0.02, 0.12, seed=5)
