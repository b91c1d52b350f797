"""Issue 7, done-when 3: MAVProxy connects to the flight software's UDP port and sees its
heartbeat; MAVProxy's own .tlog reads back with our reader. Issue 29: with the project's module
(``module load ground.mavproxy.safer``) MAVProxy names the modes.

MAVProxy is not a dependency (its wheel pulls opencv-python next to our
opencv-python-headless, and vtk): the test runs when ``mavproxy.py`` is on PATH or named by
``SAFER_MAVPROXY``, e.g. from a separate venv (docs/ground.md, "MAVProxy")."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import time
from pathlib import Path

import ground_demo
import pytest
from ground_demo import RoverThread, free_udp_port, write_config

from fsw.comm.mavlink_tlog import read_tlog
from fsw.settings import load_settings

ROOT = Path(__file__).resolve().parents[2]
MAVPROXY = os.environ.get("SAFER_MAVPROXY") or shutil.which("mavproxy.py")


@pytest.mark.slow
@pytest.mark.skipif(not MAVPROXY, reason="mavproxy.py not installed (set SAFER_MAVPROXY=/path/to/mavproxy.py)")
def test_mavproxy_sees_the_rover(tmp_path: Path, key_file: Path, demo_kind: None) -> None:
    """Issue 7, done-when 3."""
    port = free_udp_port()
    cfg = load_settings(write_config(tmp_path / "rover.toml", {"url": f"udpout:127.0.0.1:{port}",
                                                               "key_file": str(key_file)}))
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    proc = subprocess.Popen([str(MAVPROXY), f"--master=udpin:127.0.0.1:{port}", "--non-interactive",
                             "--state-basedir", str(tmp_path), "--cmd=module load ground.mavproxy.safer"],
                            cwd=tmp_path, text=True, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    try:
        time.sleep(2.0)  # MAVProxy loads its modules
        with RoverThread(ground_demo.build(cfg), step_s=0.1):  # real-time pace
            time.sleep(4.0)
    finally:
        proc.terminate()
        out, _ = proc.communicate(timeout=20)
    assert "Detected vehicle 1:1" in out and "online system 1" in out, out[-2000:]
    assert "AP: demo.STATE: mission state" in out  # long STATUSTEXT reassembled by MAVProxy
    # the project's module names the modes (MAVProxy's own announcement and the module's line)
    assert "Loaded module ground.mavproxy.safer" in out, out[-2000:]
    assert re.search(r"Mode (INIT|SELECT|MOVE)\b", out) and "recon (system 1): mode INIT -> SELECT" in out
    assert "Mode(0x" not in out
    records, note = read_tlog(tmp_path / "mav.tlog")
    assert note is None and len(records) > 20
