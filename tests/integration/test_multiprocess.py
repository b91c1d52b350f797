"""Multi-process real-time mode: ``safer-hil serve`` plays the hardware, the flight software
connects over CAN through the bench's hub and a pty with unchanged code (issue 3, item 11,
done-when 4). Every socket the processes open stays on loopback; where this machine can make a
network namespace with only ``lo``, the scenario runs in one (issue 31, item 3).

The scenario (tests/support/serve_and_fly.py) runs once for both tests: in such a namespace when
one can be made (it checks there everything it checks here, and that ``lo`` is all there is),
in this process otherwise (the second test then skips, as it did when it ran the first again)."""

from __future__ import annotations

import json
import os
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
from loopback import NETNS_ENV, run_in_loopback_namespace
from serve_and_fly import serve_and_fly

REPO = Path(__file__).resolve().parents[2]
SCENARIO = Path(__file__).resolve().parents[1] / "support" / "serve_and_fly.py"
pytestmark = pytest.mark.timeout(900)  # real time beside a loaded machine: the scenario's own limits end a hang


@dataclass
class Flown:
    truth: dict[str, Any]
    where: str  # "namespace": a fresh network namespace with only lo; "here": this process's
    log: str  # the namespace run's output (for a failure's message)


@pytest.fixture(scope="module")
def flown(tmp_path_factory: pytest.TempPathFactory) -> Flown:
    if not os.environ.get(NETNS_ENV):  # not already inside one (make unit-loopback sets it up itself)
        done = run_in_loopback_namespace([sys.executable, str(SCENARIO)], timeout_s=600, cwd=str(REPO))
        if done is not None:
            log = done.stdout[-3000:] + done.stderr[-3000:]
            assert done.returncode == 0, log
            line = next((ln for ln in done.stdout.splitlines() if ln.startswith("FLOWN ")), None)
            assert line is not None, log
            return Flown(json.loads(line[6:]), "namespace", log)
    return Flown(serve_and_fly(tmp_path_factory.mktemp("flown")), "here", "")


@pytest.mark.slow
def test_serve_and_flight_processes_move_a_motor_and_the_mast(flown: Flown) -> None:
    """The flight program connects, stops on SIGTERM, and the same build moves a motor 0.3 m and
    points the mast (the scenario's own checks; the bench's truth checked again here)."""
    t = flown.truth
    assert t["x_m"] == pytest.approx(0.3, abs=0.03) and abs(t["y_m"]) < 0.02, flown.log
    assert t["pan_deg"] == pytest.approx(20.0, abs=0.5) and t["tilt_deg"] == pytest.approx(-10.0, abs=0.5)
    assert t["can_bad"] == 0 and t["mast_moves"] >= 1


@pytest.mark.slow
def test_the_bench_needs_no_interface_but_loopback(flown: Flown) -> None:
    """Issue 31, done-when 1: the scenario in a fresh network namespace with only ``lo`` up
    (no route to any other network: a datagram or group join meant for one fails there)."""
    if os.environ.get(NETNS_ENV):
        pytest.skip("already inside the namespace")
    if flown.where != "namespace":
        pytest.skip("no network namespace here (needs root and unshare)")
    assert "FLOWN " in flown.log  # the namespace run finished: it asserted lo was its only interface
