"""Shared checks of the resume tests (tests/integration/test_mission_resume*.py)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from hil_sim.lab.experiments.experiment_resume import compare_maps, newest
from hil_sim.mission.mission_report import strip_wall_clock
from hil_sim.mission.mission_run import run_mission
from hil_sim.mission.run_spec import MissionExistsError, RunSpec

# The bench's per-station bookkeeping of the map-quality report (which stations this process saw)
# is not part of the flight state: a resumed process only sees the stations after the restart.
BENCH_ONLY = {"stations", "pairs", "seam_m", "seam_max_m"}


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


def assert_same(a: object, b: object, path: str = "") -> None:
    """Equal summaries: the same keys, counts and strings; floats within 1e-9 (relative). The
    resumed run's odometry differs from the uninterrupted one by ~1e-13 m (the encoder baseline
    is re-read after the restart), which registration carries to ~1e-12."""
    if isinstance(a, dict) and isinstance(b, dict):
        keys = set(a) | set(b)
        if path.endswith("map_quality"):
            keys -= BENCH_ONLY
        for k in keys:
            assert k in a and k in b, f"{path}.{k} missing"
            assert_same(a[k], b[k], f"{path}.{k}")
    elif isinstance(a, list) and isinstance(b, list):
        assert len(a) == len(b), f"{path}: {len(a)} != {len(b)} items"
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            assert_same(x, y, f"{path}[{i}]")
    elif isinstance(a, float) and isinstance(b, float):
        assert a == pytest.approx(b, rel=1e-9, abs=1e-12, nan_ok=True), f"{path}: {a} != {b}"
    else:
        assert a == b, f"{path}: {a!r} != {b!r}"


def run_reference(spec: RunSpec) -> dict[str, Any]:
    """The uninterrupted run the resumed ones are compared with (in ``spec.out``)."""
    ref = run_mission(spec)
    assert ref["final_state"] == "DONE" and len(ref["steps"]) == spec.steps + 1
    return ref


def stop_and_resume(ref_spec: RunSpec, ref: dict[str, Any], out: Path) -> None:
    """The mission of ``ref_spec`` stopped inside step 2 (after step 1's record, before step 2's
    first) in ``out``, then resumed: it ends with the uninterrupted run's map and summary (every
    layer bit-identical; records, frames and sim time equal)."""
    assert ref_spec.out is not None and ref_spec.steps >= 2
    stop_s = ref["steps"][1]["sim_s"] + 1.0
    cut = RunSpec(ref_spec.scenario, ref_spec.method, steps=ref_spec.steps, seed=ref_spec.seed, transmit=False,
                  out=out)
    part = run_mission(cut, max_sim_s=stop_s)
    assert part["final_state"] not in ("DONE", "SAFE") and len(part["steps"]) == 2
    assert newest(out).state["mission"]["step"] == 2  # type: ignore[operator]
    with pytest.raises(MissionExistsError):
        run_mission(cut)  # never over an existing mission without being told
    done = run_mission(cut, mode="resume")
    same = {"files": None}
    assert_same(strip_wall_clock(done) | same, strip_wall_clock(ref) | same)
    assert done["map_rmse_m"] == pytest.approx(ref["map_rmse_m"], abs=1e-9)
    same_maps(ref_spec.out, out)
