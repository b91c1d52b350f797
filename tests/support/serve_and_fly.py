"""The multi-process real-time scenario of tests/integration/test_multiprocess.py (issue 3, item 11;
issue 31, item 3), run by that test in a network namespace with only ``lo`` where the machine can
make one (``python serve_and_fly.py DIR``: exit 0 and a ``FLOWN {json}`` line, or an assertion's
traceback), in the test's own process otherwise.

``safer-hil serve`` plays the hardware; the unchanged flight program connects over CAN through the
bench's hub and a pty, stops the orderly way on SIGTERM, and the same flight build, in this
process, moves a motor and the mast. Every socket the processes open stays on loopback."""

from __future__ import annotations

import io
import json
import math
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import psutil
import pytest
from hil_helpers import only_hw_tasks, read_until
from loopback import NETNS_ENV, family, in_loopback_namespace, off_machine_sockets

from fsw.app import build_executive
from fsw.drivers.factory import close_devices
from fsw.settings import load_settings

BIN = Path(sys.executable).parent


def serve_and_fly(tmp_path: Path) -> dict[str, Any]:
    """The scenario (module docstring); the bench's TRUTH line as a dict. Raises AssertionError."""
    if os.environ.get(NETNS_ENV):
        assert in_loopback_namespace(), "not in a loopback-only namespace"  # nothing but lo to leave by
    flight_cfg = tmp_path / "fsw_hil.toml"
    serve = subprocess.Popen(
        [
            str(BIN / "safer-hil"),
            "serve",
            "--scenario",
            "flat",
            "--can-port",
            "0",
            "--serial",
            "pty",
            "--flight-config",
            str(flight_cfg),
            "--duration",
            "60",
            "--report-period",
            "0",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )
    try:
        head = "".join(read_until(serve, "READY", 120.0))  # returns at READY; the limit only ends a hang
        assert "CAN     udp_hub 127.0.0.1:" in head and "/dev/pts/" in head and flight_cfg.exists()
        # 1) the unchanged flight program connects (events printed by its console task)
        run = subprocess.run(
            [str(BIN / "safer-fsw"), "run", "--config", str(flight_cfg), "--duration", "2.5"],
            capture_output=True,
            text=True,
            timeout=60,
        )
        assert run.returncode == 0, run.stderr
        assert "MAST_ONLINE" in run.stdout and run.stdout.count("CAN_NODE_ONLINE") >= 12
        # 1b) a supervisor's SIGTERM stops it the orderly way (devices closed, figures printed)
        fsw = subprocess.Popen([str(BIN / "safer-fsw"), "run", "--config", str(flight_cfg)],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                               env={**os.environ, "PYTHONUNBUFFERED": "1"})
        try:
            read_until(fsw, "components at", 120.0)
            time.sleep(1.0)  # frames run
            assert off_machine_sockets(family(serve.pid) + family(fsw.pid)) == []
            fsw.send_signal(signal.SIGTERM)
            rest, err = fsw.communicate(timeout=30)
        finally:
            fsw.kill()
        assert fsw.returncode == 0, err
        assert "safer-fsw: interrupted" in rest and "slips" in rest
        # 2) the same flight build, in this process, moves a motor and the mast
        cfg = only_hw_tasks(load_settings(flight_cfg))
        before = _socket_fds()
        exe = build_executive(cfg)
        for task in exe.tasks.values():  # the console task prints every event: keep it out of pytest's streams
            if hasattr(task, "out"):
                task.out = io.StringIO()
        try:
            exe.run_realtime(12)  # controllers and mast heard
            ours = [c for c in psutil.Process().net_connections(kind="inet") if c.fd not in before]
            assert ours and all(c.laddr.ip == "127.0.0.1" and c.raddr.ip == "127.0.0.1" for c in ours), ours
            ok = [exe.commands.dispatch(r).status.name for r in _requests()]
            assert ok == ["OK", "OK"]
            exe.run_realtime(150, stop=lambda: exe.telemetry.get("motion.moves_done") == 2)
            assert exe.telemetry.get("motion.moves_done") == 2
            # Real time beside the other xdist worker: a late frame near the goal lets the bench
            # motor run on at up to the 0.15 m/s drive speed (a fresh-clone run ended at 0.311 m).
            assert exe.telemetry.get("motion.odo_x_m") == pytest.approx(0.3, abs=0.02)
        finally:
            close_devices(exe.ctx.res)
    finally:
        serve.send_signal(signal.SIGINT)
        out, _ = serve.communicate(timeout=20)
    truth = json.loads(next(ln for ln in out.splitlines() if ln.startswith("TRUTH "))[6:])
    assert truth["x_m"] == pytest.approx(0.3, abs=0.03) and abs(truth["y_m"]) < 0.02
    assert truth["pan_deg"] == pytest.approx(20.0, abs=0.5) and truth["tilt_deg"] == pytest.approx(-10.0, abs=0.5)
    assert truth["can_bad"] == 0 and truth["mast_moves"] >= 1 and not math.isnan(truth["x_m"])
    return truth


def _socket_fds() -> set[int]:
    return {c.fd for c in psutil.Process().net_connections(kind="inet")}


def _requests() -> list:  # type: ignore[type-arg]
    from fsw.framework.commands import CommandRequest

    return [
        CommandRequest("motion.DRIVE", {"distance_m": 0.3, "speed_mps": 0.0}, 1),
        CommandRequest("motion.POINT_MAST", {"pan_deg": 20.0, "tilt_deg": -10.0, "lift_m": 0.05}, 2),
    ]


if __name__ == "__main__":
    with tempfile.TemporaryDirectory(prefix="serve-and-fly-") as tmp:
        print("FLOWN " + json.dumps(serve_and_fly(Path(tmp))), flush=True)
