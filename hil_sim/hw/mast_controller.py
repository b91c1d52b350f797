"""Emulated mast controller: the serial end of the 3-DOF mast (:class:`hil_sim.mast_truth.MastTruth`).

Speaks :mod:`fsw.comm.serial_frames` as the device: MOVE within the joint limits is ACKed and
starts the joints slewing, outside them it is NAKed (OUT_OF_LIMITS); STOP holds and is ACKed;
QUERY is answered with STATE; CLEAR_FAULT is ACKed. A frame with a bad CRC or length is
NAKed with whatever sequence number could be read; an unknown type is NAKed; garbage between
frames is skipped by the parser's resync. STATE goes out every ``state_period_s`` with the
encoder angles and flags (moving, at target, fault, limit). A stalled mast (injected) sets the
fault flag and refuses MOVEs (NAK FAULTED) until the stall is gone and CLEAR_FAULT arrives.
Serial noise and disconnects are applied by the fault injector to the bytes in both directions.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from fsw.comm import serial_frames as sf
from fsw.framework.params import param
from hil_sim.faults import FaultInjector
from hil_sim.mast_truth import MastTruth


@dataclass(frozen=True)
class MastControllerConfig:
    state_period_s: float = param(0.1, lo=0.01, hi=10.0, units="s", doc="STATE report period")
    at_target_tol_deg: float = param(0.05, lo=0.0, hi=10.0, units="deg")


class MastController:
    """Device side of the mast serial line."""

    def __init__(
        self, port: Any, mast: MastTruth, cfg: MastControllerConfig, faults: FaultInjector | None = None
    ) -> None:
        self.port, self.mast, self.cfg = port, mast, cfg
        self.faults = faults or FaultInjector()
        self.decoder = sf.FrameDecoder()
        self._seq = 0
        self._t_state = -math.inf
        self.fault_latched = False
        self.limit_hit = False
        self.acks = self.naks = self.moves = 0
        self.port_errors = 0

    def _send(self, msg: sf.Message) -> None:
        self._seq = (self._seq + 1) & 0xFF
        data = self.faults.serial_bytes(sf.encode_message(msg, self._seq))
        if data and self.port is not None:
            try:
                self.port.write(data)
            except Exception:  # noqa: BLE001 - a gone host (closed pty/socket) is not our crash
                self.port_errors += 1

    def _nak(self, seq: int, typ: int, reason: int) -> None:
        self.naks += 1
        self._send(sf.Nak(seq, typ, reason))

    def _ack(self, seq: int, typ: int) -> None:
        self.acks += 1
        self._send(sf.Ack(seq, typ))

    def receive(self, now: float) -> None:
        """Read and answer what the flight computer sent."""
        if self.port is None:
            return
        try:
            data = self.port.read(4096)
        except Exception:  # noqa: BLE001 - see _send
            self.port_errors += 1
            return
        data = self.faults.serial_bytes(data)
        for item in self.decoder.feed(data):
            if isinstance(item, sf.FrameError):
                self._nak(item.seq, item.type, sf.NAK_BAD_CRC if item.reason == "bad_crc" else sf.NAK_BAD_LENGTH)
                continue
            self._on_frame(item)

    def _on_frame(self, frame: sf.Frame) -> None:
        msg = sf.parse_message(frame)
        if isinstance(msg, sf.FrameError):
            reason = sf.NAK_UNKNOWN_TYPE if msg.reason == "unknown_type" else sf.NAK_BAD_LENGTH
            self._nak(frame.seq, frame.type, reason)
        elif isinstance(msg, sf.Move):
            if self.fault_latched:
                self._nak(frame.seq, frame.type, sf.NAK_FAULTED)
            elif not self.mast.mast.within_limits(msg.pan_rad, msg.tilt_rad, msg.lift_m, tol=2e-6):
                self.limit_hit = True
                self._nak(frame.seq, frame.type, sf.NAK_OUT_OF_LIMITS)
            else:
                self.limit_hit = False
                self.moves += 1
                self.mast.set_target(msg.pan_rad, msg.tilt_rad, msg.lift_m)
                self._ack(frame.seq, frame.type)
        elif isinstance(msg, sf.Stop):
            self.mast.hold()
            self._ack(frame.seq, frame.type)
        elif isinstance(msg, sf.Query):
            self._send(self._state())
        elif isinstance(msg, sf.ClearFault):
            if not self.faults.mast_stalled():
                self.fault_latched = False
            self._ack(frame.seq, frame.type)
        else:  # ACK/NAK/STATE are not for the device
            self._nak(frame.seq, frame.type, sf.NAK_UNKNOWN_TYPE)

    def actuate(self) -> None:
        """Apply injected stalls before the truth steps."""
        stalled = self.faults.mast_stalled()
        self.mast.stalled = stalled
        if stalled and self.mast.moving:
            self.fault_latched = True
            self.mast.hold()

    def _state(self) -> sf.MastState:
        m = self.mast
        tol = math.radians(self.cfg.at_target_tol_deg)
        at = all(abs(a - b) <= t for a, b, t in zip(m.q, m.target, (tol, tol, 1e-4), strict=True))
        flags = (
            (sf.STATE_MOVING * m.moving)
            | (sf.STATE_AT_TARGET * at)
            | (sf.STATE_FAULT * self.fault_latched)
            | (sf.STATE_LIMIT * self.limit_hit)
        )
        return sf.MastState(*m.encoder, flags)

    def transmit(self, now: float) -> None:
        """Periodic STATE report."""
        if now - self._t_state >= self.cfg.state_period_s - 1e-9:
            self._t_state = now
            self._send(self._state())
