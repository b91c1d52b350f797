"""Issue 12, item 1: a `safer-hil run` process SIGKILLed mid-mission resumes to the
uninterrupted result (its own file, so the two test workers share the slow resume tests)."""

from __future__ import annotations

import os
import signal
import subprocess
import time
from pathlib import Path

import pytest
from resume_checks import same_maps

from hil_sim.commands.experiment_resume import newest, resume_cmd, run_cmd

pytestmark = pytest.mark.req("12.1")


@pytest.mark.slow
def test_sigkill_mid_mission_then_resume(tmp_path: Path) -> None:
    """The done-when in short: a `safer-hil run` process is SIGKILLed once step 1's checkpoint
    exists; `--resume` finishes the mission from that step with the same map as an uninterrupted
    run of the same seed. Killing the resumed process again right away (during its start-up)
    loses nothing either."""
    mission = ["--scenario", "lab", "--method", "5", "--steps", "2", "--seed", "5", "--no-transmit"]
    ref = subprocess.run(run_cmd(tmp_path / "ref", *mission), capture_output=True, timeout=600)
    assert ref.returncode == 0, ref.stdout[-500:]
    out = tmp_path / "killed"
    proc = subprocess.Popen(run_cmd(out, *mission), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            start_new_session=True)
    t0 = time.monotonic()
    while (st := newest(out).state) is None or st["mission"]["step"] < 1:
        assert proc.poll() is None and time.monotonic() - t0 < 300, "no step-1 checkpoint"
        time.sleep(0.05)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    again = subprocess.run(run_cmd(out, *mission), capture_output=True, text=True)
    assert again.returncode == 2 and "holds a mission" in again.stderr and len(again.stderr.strip().splitlines()) == 1
    proc = subprocess.Popen(resume_cmd(out), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            start_new_session=True)
    time.sleep(0.5)
    os.killpg(proc.pid, signal.SIGKILL)  # during its start-up
    proc.wait()
    res = subprocess.run(resume_cmd(out), capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, res.stderr[-500:]
    assert not list((out / "checkpoints").glob(".map_*.tmp"))
    same_maps(tmp_path / "ref", out)
    done = subprocess.run(resume_cmd(out), capture_output=True, text=True, timeout=120)
    assert done.returncode == 0 and "has finished" in done.stdout  # not flown again
