"""A lockstep run's .tlog is the same, byte for byte, every time (docs/architecture.md, "The cyclic executive",
budgets, overruns, slips): budgets, overruns, slips and every timing channel and event are measured on the
stepped clock, the records are stamped with the bench's Unix time, and what the work cost on this
computer is kept apart (``Task.host``), out of the telemetry."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from fsw.comm.mavlink_tlog import read_tlog
from fsw.drivers.resources import Resources
from fsw.settings import load_settings
from hil_sim.bench import LockstepBench
from hil_sim.world import load_scenario

FRAMES = 250  # the first views of the panorama: pairs taken, stereo, fusion and map previews as slack jobs


def _flown_tlog(path: Path) -> bytes:
    world = load_scenario("lab", 0)
    cfg = load_settings()
    cfg = dataclasses.replace(cfg, map=world.map_grid)
    with LockstepBench(cfg, world, seed=0, quiet=True, resources=Resources(mavlink_tlog=str(path))) as b:
        b.run(FRAMES)
        jobs = b.exe.jobs.completed
        b.exe.tasks["mavlink"].close()  # flush and close the .tlog
    assert jobs > 0, "the run must time slack jobs"
    return path.read_bytes()


@pytest.mark.slow
def test_two_identical_lockstep_runs_write_the_same_tlog(tmp_path: Path) -> None:
    a = _flown_tlog(tmp_path / "a.tlog")
    b = _flown_tlog(tmp_path / "b.tlog")
    records, damaged = read_tlog(tmp_path / "a.tlog")
    assert damaged is None and len(records) > 100
    assert a == b
