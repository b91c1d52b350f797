"""Delivery is a fact (issue 26, item 2): a mission stopped after its last step's checkpoint
and resumed sends the map; a map that cannot be delivered never ends the mission DONE."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import time
from pathlib import Path
from typing import Any

import pytest

from fsw.settings import DEFAULT_CONFIG
from hil_sim.faults import FaultSpec
from hil_sim.lab.experiments.experiment_resume import newest, resume_cmd, run_cmd
from hil_sim.mission.mission_run import RunSpec, run_mission

pytestmark = pytest.mark.req("26.2")
STEPS = 0  # the panorama only: the shortest mission that maps and transmits
LAST = STEPS + 1  # the mission's step counter once the last step's checkpoint is written


def _delivered(s: dict[str, Any]) -> None:
    assert s["final_state"] == "DONE"
    assert s["map_transfer"] == "delivered" and s["map_delivered"] is True
    assert s["cliffbot"]["decoded"] and s["cliffbot"]["map_id"] == 1


@pytest.mark.slow
def test_sigkill_after_the_last_checkpoint_then_resume_delivers(tmp_path: Path) -> None:
    """The issue's case: a `safer-hil run` process SIGKILLed once the last step's checkpoint
    exists (mapping over; the transfer not begun or cut); `--resume` sends the map again and
    exits 0 with it delivered, within seconds, not a timeout."""
    out = tmp_path / "killed"
    proc = subprocess.Popen(run_cmd(out, "--scenario", "lab", "--steps", str(STEPS), "--seed", "3"),
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    t0 = time.monotonic()
    while (st := newest(out).state) is None or st["mission"]["step"] < LAST:
        assert proc.poll() is None and time.monotonic() - t0 < 300, "no last-step checkpoint"
        time.sleep(0.02)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    res = subprocess.run(resume_cmd(out), capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, res.stderr[-500:]
    summary = json.loads((out / "summary.json").read_text())
    _delivered(summary)
    assert summary["transfer_s"] is not None and summary["transfer_s"] < 30.0
    assert newest(out).state["mission"]["phase"] == "DONE"


@pytest.mark.slow
def test_a_map_that_cannot_be_delivered_ends_the_mission_in_safe_not_done(tmp_path: Path) -> None:
    """The Cliff-bot never hears (a radio outage for good): after ``transmit_timeout_s`` the
    mission says so (event UNDELIVERED, SAFE with the reason) and summary.json has it."""
    text = DEFAULT_CONFIG.read_text()
    assert "\ntransmit_timeout_s = " in text
    cfg = tmp_path / "fsw.toml"
    cfg.write_text(text.replace("\ntransmit_timeout_s = ", "\ntransmit_timeout_s = 20.0 #", 1))
    spec = RunSpec("lab", "5", steps=STEPS, seed=3, config=str(cfg), transmit=True, out=tmp_path / "run",
                   faults=(FaultSpec("radio_outage", start_s=0.0),))
    events: list[Any] = []
    s = run_mission(spec, on_bench=events.append)
    assert s["final_state"] == "SAFE" and s["final_state"] != "DONE"
    assert s["map_delivered"] is False and s["map_transfer"] == "timeout"
    assert s["safe_reason"] == "map not delivered (timeout)"
    assert s["cliffbot"] is None or not s["cliffbot"].get("decoded")
    history = [e.name for e in events[0].exe.ctx.events.history]
    assert "mission.UNDELIVERED" in history and "mission.SAFE" in history
    state = newest(tmp_path / "run").state
    assert state is not None and state["mission"]["phase"] == "SAFE"  # a resume tries again
