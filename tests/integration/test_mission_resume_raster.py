"""Issue 12, item 1: a Method 1 (raster) mission stopped and resumed (its own file, so the two
test workers share the slow resume tests; Method 5 and SIGKILL in test_mission_resume.py)."""

from __future__ import annotations

from pathlib import Path

import pytest
from resume_checks import run_reference, stop_and_resume

from hil_sim.mission.mission_run import RunSpec

pytestmark = pytest.mark.req("12.1")


@pytest.mark.slow
def test_stopped_raster_mission_resumes_to_the_uninterrupted_result(tmp_path: Path) -> None:
    """A Method 1 run stopped after step 1 and resumed ends with the uninterrupted run's map and
    summary: the raster plan continues rather than being re-planned from where the rover stands."""
    spec = RunSpec("lab", "1", steps=2, seed=3, transmit=False, out=tmp_path / "ref")
    stop_and_resume(spec, run_reference(spec), tmp_path / "cut")
