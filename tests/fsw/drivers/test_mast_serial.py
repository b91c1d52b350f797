"""The flight mast driver against the emulated mast controller over a pty and socket:// (issue 3, items 6, 9)."""

from __future__ import annotations

import math
import time
from collections.abc import Iterator

import pytest
import serial
from hil_helpers import cfg

from fsw.comm import serial_frames as sf
from fsw.drivers import mast_serial as ms
from hil_sim.faults import FaultInjector
from hil_sim.hw.mast_controller import MastController, MastControllerConfig
from hil_sim.hw.ports import PtyDevicePort, TcpDevicePort
from hil_sim.mast_truth import MastTruth, MastTruthConfig


class Line:
    def __init__(self, transport: str) -> None:
        self.faults = FaultInjector(3)
        if transport == "pty":
            self.dev: PtyDevicePort | TcpDevicePort = PtyDevicePort()
            url = self.dev.path  # type: ignore[union-attr]
        else:
            self.dev = TcpDevicePort()
            url = self.dev.url  # type: ignore[union-attr]
        self.port = serial.serial_for_url(url, timeout=0, write_timeout=0.1)
        self.mast = MastTruth(cfg().mast, MastTruthConfig(), 0)
        self.ctrl = MastController(self.dev, self.mast, MastControllerConfig(), self.faults)
        self.drv = ms.MastSerialDriver(self.port, ack_timeout_s=0.3, retries=3)
        self.t = 0.0
        self.events: list[str] = []

    def step(self, n: int = 1, dt: float = 0.1, device_on: bool = True) -> None:
        for _ in range(n):
            self.t += dt
            self.faults.update(self.t)
            time.sleep(0.004)
            if device_on:
                self.ctrl.receive(self.t)
                self.ctrl.actuate()
                self.mast.step(dt)
                self.ctrl.transmit(self.t)
            time.sleep(0.004)
            self.drv.poll(self.t)
            self.events += [n for n, _ in self.drv.drain_events()]

    def close(self) -> None:
        self.port.close()
        self.dev.close()


@pytest.fixture(params=["pty", "tcp"])
def line(request: pytest.FixtureRequest) -> Iterator[Line]:
    ln = Line(request.param)
    yield ln
    ln.close()


def test_move_is_acked_and_reported(line: Line) -> None:
    """Issue 3 item 6: ACK of moves, joint-angle reports."""
    line.step(2)
    assert "MAST_ONLINE" in line.events and line.drv.joints is not None
    line.drv.move(math.radians(20), math.radians(-10), 0.05)
    line.step(15)
    assert line.drv.acks == 1 and line.drv.last_result == "ack" and not line.drv.busy
    pan, tilt, lift = line.drv.joints  # type: ignore[misc]
    assert math.degrees(pan) == pytest.approx(20, abs=0.01) and math.degrees(tilt) == pytest.approx(-10, abs=0.01)
    assert lift == pytest.approx(0.05, abs=1e-5) and line.drv.at_target and line.drv.fault_names() == []


def test_out_of_limits_move_is_nakked(line: Line) -> None:
    line.step(1)
    line.drv.move(math.radians(175), 0.0, 0.0)  # pan limit is 170 deg
    line.step(3)
    assert "MAST_NAK" in line.events and line.drv.has(ms.F_NAK) and line.drv.last_result == "nak: out of limits"
    assert line.ctrl.naks == 1 and line.mast.target[0] == 0.0


def test_garbage_on_the_line_is_skipped(line: Line) -> None:
    """The parser resyncs on garbage; bad bytes are counted and evented, never raised."""
    line.step(1)
    line.dev.write(b"\xa5\x5a\x07garbage\x00\xff" + sf.encode_frame(9, 0x83, b"\x01\x02"))  # bad length STATE
    line.step(3)
    assert "MAST_BAD_FRAME" in line.events and line.drv.decoder.garbage_bytes > 0
    assert line.drv.has(ms.F_BAD_FRAMES)
    line.drv.move(0.1, 0.0, 0.0)
    line.step(5)
    assert line.drv.last_result == "ack"


def test_noise_costs_retries_not_commands(line: Line) -> None:
    """Corrupted frames are NAKed (bad CRC) or time out; the driver retransmits until ACKed."""
    line.step(1)
    line.faults.inject("serial_noise", start_s=line.t, duration_s=0.35, rate=0.5)  # then a clean line
    line.drv.move(math.radians(5), 0.0, 0.0)
    line.step(40)
    assert line.drv.last_result == "ack" and line.drv.retransmits >= 1
    assert line.drv.decoder.crc_errors + line.ctrl.decoder.crc_errors + line.drv.decoder.garbage_bytes > 0
    assert abs(math.degrees(line.drv.joints[0]) - 5) < 0.01  # type: ignore[index]


def test_dead_device_gives_no_ack_and_silence(line: Line) -> None:
    line.step(2)
    line.drv.move(0.2, 0.0, 0.0)
    line.step(20, device_on=False)
    assert "MAST_NO_ACK" in line.events and "MAST_SILENT" in line.events
    assert line.drv.has(ms.F_NO_ACK) and line.drv.has(ms.F_SILENT) and line.drv.retransmits == 3
