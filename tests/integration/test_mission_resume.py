"""Issue 12, item 1: resumable missions (bench level: stop or SIGKILL, resume, compare).

Method 5 here, both ways of stopping against one uninterrupted reference run (a module fixture:
the same mission, so it runs once); Method 1's raster plan in test_mission_resume_raster.py (its
own file, so the two test workers share the slow resume tests)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest
from resume_checks import run_reference, same_maps, stop_and_resume

from hil_sim.lab.experiments.experiment_resume import LAYERS, newest, resume_cmd, run_cmd
from hil_sim.mission.mission_run import RunSpec, run_mission

pytestmark = pytest.mark.req("12.1")
SEED = 3


@pytest.fixture(scope="module")
def reference(tmp_path_factory: pytest.TempPathFactory) -> tuple[RunSpec, dict[str, Any]]:
    """The uninterrupted Method 5 run (lab, 2 steps) both resume tests compare with."""
    spec = RunSpec("lab", "5", steps=2, seed=SEED, transmit=False, out=tmp_path_factory.mktemp("m5") / "ref")
    return spec, run_reference(spec)


@pytest.mark.slow
def test_stopped_mission_resumes_to_the_uninterrupted_result(reference: tuple[RunSpec, dict[str, Any]],
                                                             tmp_path: Path) -> None:
    """A run stopped after step 1 and resumed ends with the uninterrupted run's map and summary
    (every layer bit-identical; records, frames and sim time equal)."""
    spec, ref = reference
    stop_and_resume(spec, ref, tmp_path / "cut")


@pytest.mark.slow
def test_sigkill_mid_mission_then_resume(reference: tuple[RunSpec, dict[str, Any]], tmp_path: Path) -> None:
    """The done-when in short: a `safer-hil run` process is SIGKILLed once step 1's checkpoint
    exists; `--resume` finishes the mission from that step with the same map as an uninterrupted
    run of the same seed. Killing the resumed process again right away (during its start-up)
    loses nothing either."""
    spec, _ = reference
    assert spec.out is not None
    mission = ["--scenario", spec.scenario, "--method", spec.method, "--steps", str(spec.steps),
               "--seed", str(spec.seed), "--no-transmit"]
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
    same_maps(spec.out, out)
    done = subprocess.run(resume_cmd(out), capture_output=True, text=True, timeout=120)
    assert done.returncode == 0 and "has finished" in done.stdout  # not flown again


def test_resume_refusals_are_one_line_and_exit_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """No manifest, a malformed manifest, only corrupt checkpoints: one line, exit 2."""
    from hil_sim.cli import main

    def one_line() -> str:
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and err.startswith("safer-hil run: "), err
        return err

    assert main(["run", "--resume", str(tmp_path / "nothing")]) == 2
    assert "no mission to resume" in one_line()
    out = tmp_path / "bad"
    (out / "checkpoints").mkdir(parents=True)
    (out / "run.json").write_text('{"schema": 1, "spec": {"scenario": "lab"}}')
    assert main(["run", "--resume", str(out)]) == 2  # manifest lacks keys
    assert "unreadable" in one_line()
    (out / "run.json").write_text(
        '{"schema": 1, "spec": {"scenario": "lab", "method": "5", "steps": 1, "seed": 0, '
        '"config": "config/fsw.toml", "transmit": false, "out": "x"}}'
    )
    (out / "checkpoints" / "map_0000000001.ckpt").write_bytes(b"SAFERMAP garbage")
    with pytest.raises(ValueError, match="no usable checkpoint"):
        run_mission(RunSpec("lab", "5", 1, 0, transmit=False, out=out), mode="resume")
    capsys.readouterr()
    assert main(["run", "--resume", str(out)]) == 2
    assert "no usable checkpoint" in one_line()


def test_layers_cover_the_checkpoint_format() -> None:
    from fsw.core.map import checkpoint

    assert tuple(n for n, _ in checkpoint._ARRAYS) == LAYERS


if __name__ == "__main__":  # pragma: no cover
    sys.exit(pytest.main([__file__, "-x", "-q"]))
