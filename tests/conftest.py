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

    Every time limit is scaled by :func:`timeout_scale` (the marker put first, so it is the one
    pytest-timeout reads).
    """
    slow: dict[Path, int] = {}
    scale = timeout_scale()
    default = float(config.getoption("timeout", None) or config.getini("timeout") or 0)
    for item in items:
        if item.get_closest_marker("slow") is not None:
            slow[item.path] = slow.get(item.path, 0) + 1
        marker = item.get_closest_marker("timeout")
        limit = marker.kwargs.get("timeout", marker.args[0] if marker.args else None) if marker else None
        method = marker.kwargs.get("method", marker.args[1] if marker and len(marker.args) > 1 else None) \
            if marker else None
        if method is None and getattr(getattr(item, "obj", None), "is_hypothesis_test", False):
            method = "thread"
        limit = default if limit is None else float(limit)
        if limit > 0 and (scale > 1.0 or method is not None):
            item.add_marker(pytest.mark.timeout(limit * scale, method=method), append=False)
    items.sort(key=lambda item: -slow.get(item.path, 0))


def timeout_scale() -> float:
    """How much longer than on an idle machine the tests' time limits are on this one.

    The limits (``timeout`` in pyproject.toml, ``@pytest.mark.timeout``) end a hung test; they
    are set for a machine running the suite alone. On a shared machine a test gets a fraction of
    a core: the 1-minute load per core (at least 1) times 1 + niceness/10 (a ``nice -n 15``
    suite beside un-niced work gets less than its share), at most 30x, or
    ``SAFER_TEST_TIMEOUT_SCALE``. An idle machine keeps the limits as written."""
    env = os.environ.get("SAFER_TEST_TIMEOUT_SCALE")
    if env:
        return max(1.0, float(env))
    try:
        load = os.getloadavg()[0] / (os.cpu_count() or 1)
    except OSError:  # no load average on this platform
        return 1.0
    return min(30.0, max(1.0, load) * (1.0 + max(0, os.nice(0)) / 10.0)) if load > 1.0 else 1.0


def pytest_report_header(config: pytest.Config) -> str:
    return f"time limits x{timeout_scale():.1f} (load and niceness of this machine)"


@pytest.fixture(scope="session")
def viking_map() -> np.ndarray:
    """A 256 x 256 Viking-model Mars map at 2 cm (the world's generator)."""
    from hil_sim.world.mars import viking_heightfield

    return viking_heightfield((256, 256), 0.02, 0.12, seed=5)
