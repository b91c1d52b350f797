"""Flight driver of the 3-DOF mast controller on a serial line (pyserial).

Speaks the framed protocol of :mod:`fsw.comm.serial_frames`. Commands (MOVE, STOP,
CLEAR_FAULT) go out stop-and-wait: one outstanding, retransmitted after ``ack_timeout_s``
up to ``retries`` times (also at once on a NAK for a bad CRC); a NAK for any other reason or
no ACK after the retries is a fault and an event. STATE reports (sent by the controller at
its own rate) give the joint angles; none for ``state_timeout_s`` is a fault (cable, power).
Line noise is counted and evented, never raised. A port that fails (or cannot be opened) is
closed and re-opened every ``reconnect_period_s`` when the driver was given an opener.

The port is anything with pyserial's ``read(n)`` (non-blocking, ``timeout=0``), ``write(b)``
and ``close()``: a ``serial.Serial``, a ``serial_for_url`` port (``socket://``, ``loop://``)
or the bench's in-memory pair.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import ClassVar, Protocol

import serial

from fsw.comm import serial_frames as sf
from fsw.drivers.base import DriverBase
from fsw.framework.telemetry import EventDef, Severity

F_BAD_FRAMES, F_NAK, F_NO_ACK, F_SILENT, F_PORT, F_CONTROLLER = 0x01, 0x02, 0x04, 0x08, 0x10, 0x20
CRITICAL = F_NO_ACK | F_SILENT | F_PORT | F_CONTROLLER


class SerialPort(Protocol):
    def read(self, size: int = 1) -> bytes: ...
    def write(self, data: bytes) -> int | None: ...
    def close(self) -> None: ...


@dataclass
class _Pending:
    seq: int
    type: int
    frame: bytes
    deadline: float
    tries: int


class MastSerialDriver(DriverBase):
    """Commands with ACK/retry, joint reports and supervision of the mast controller."""

    FAULTS: ClassVar[dict[str, int]] = {
        "bad_frames": F_BAD_FRAMES,
        "nak": F_NAK,
        "no_ack": F_NO_ACK,
        "silent": F_SILENT,
        "port": F_PORT,
        "controller": F_CONTROLLER,
    }
    EVENTS: ClassVar[tuple[EventDef, ...]] = (
        EventDef("MAST_BAD_FRAME", Severity.WARNING_LO, "mast serial: {reason} (seq {seq})", throttle=5),
        EventDef("MAST_NAK", Severity.WARNING_LO, "mast refused {type} seq {seq}: {reason}", throttle=5),
        EventDef("MAST_RETRY", Severity.WARNING_LO, "mast {type} seq {seq}: retry {n} of {max}", throttle=5),
        EventDef("MAST_NO_ACK", Severity.WARNING_HI, "mast {type} seq {seq}: no ACK after {n} tries"),
        EventDef("MAST_SILENT", Severity.WARNING_HI, "mast: no state report for {age_s:.1f} s"),
        EventDef("MAST_ONLINE", Severity.ACTIVITY_HI, "mast controller reporting"),
        EventDef("MAST_PORT_ERROR", Severity.WARNING_HI, "mast port {port}: {error}", throttle=3),
        EventDef("MAST_CONTROLLER_FAULT", Severity.WARNING_HI, "mast controller reports fault (flags 0x{flags:02X})"),
        EventDef("MAST_CONTROLLER_OK", Severity.ACTIVITY_HI, "mast controller fault clear"),
    )

    def __init__(
        self,
        port: SerialPort | None,
        *,
        ack_timeout_s: float = 0.3,
        retries: int = 3,
        state_timeout_s: float = 1.0,
        error_hold_s: float = 2.0,
        reconnect_period_s: float = 2.0,
        opener: Callable[[], SerialPort] | None = None,
        name: str = "mast",
    ) -> None:
        super().__init__(error_hold_s)
        self.port, self.opener, self.name = port, opener, name
        self.ack_timeout_s, self.retries = ack_timeout_s, retries
        self.state_timeout_s, self.reconnect_period_s = state_timeout_s, reconnect_period_s
        self.decoder = sf.FrameDecoder()
        self._seq = 0
        self._pending: _Pending | None = None
        self._queue: deque[sf.Message] = deque(maxlen=4)
        self.joints: tuple[float, float, float] | None = None  # pan, tilt (rad), lift (m)
        self.flags = 0
        self.t_state: float | None = None
        self._t_start: float | None = None
        self._t_reopen = -1e9
        self.acks = self.naks = self.retransmits = self.no_acks = 0
        self.tx_bytes = self.rx_bytes = 0
        self._seen_bad = 0
        self._read_failures = 0
        self.last_result: str = ""  # "ack", "nak: ...", "no_ack" of the last finished command
        if port is None:
            self._set(F_PORT)

    # -- commands ---------------------------------------------------------------------------
    def move(self, pan_rad: float, tilt_rad: float, lift_m: float) -> None:
        """Queue a MOVE; a newer MOVE replaces one still waiting in the queue."""
        if not all(math.isfinite(v) for v in (pan_rad, tilt_rad, lift_m)):
            raise ValueError("mast move needs finite joint values")
        self._queue = deque((m for m in self._queue if not isinstance(m, sf.Move)), maxlen=4)
        self._queue.append(sf.Move(pan_rad, tilt_rad, lift_m))

    def stop(self) -> None:
        self._queue.clear()
        self._queue.append(sf.Stop())

    def clear_fault(self) -> None:
        self._queue.append(sf.ClearFault())

    @property
    def busy(self) -> bool:
        """A command is outstanding or queued."""
        return self._pending is not None or bool(self._queue)

    @property
    def moving(self) -> bool:
        return bool(self.flags & sf.STATE_MOVING)

    @property
    def at_target(self) -> bool:
        return bool(self.flags & sf.STATE_AT_TARGET)

    # -- I/O --------------------------------------------------------------------------------
    def poll(self, now: float) -> None:
        """Read and handle what arrived, run timeouts/retries and send the next command."""
        self.last_poll_s = now
        if self._t_start is None:
            self._t_start = now
        self._expire_holds(now)
        if self.port is None:
            self._try_reopen(now)
        if self.port is not None:
            try:
                data = self._read()
                self._read_failures = 0
            except Exception as exc:  # noqa: BLE001 - SerialException/OSError: a device fault
                self._read_failures += 1
                if self._read_failures >= 3:  # one empty-but-ready read can be a pty race
                    self._port_failed(now, exc)
                data = b""
            if data:
                self.rx_bytes += len(data)
                for item in self.decoder.feed(data):
                    self._on_item(item, now)
        self._timeouts(now)
        if self._pending is None and self._queue and self.port is not None:
            self._send_new(self._queue.popleft(), now)
        self._supervise(now)

    def _read(self) -> bytes:
        port = self.port
        assert port is not None
        if isinstance(port, serial.Serial):  # a tty: read exactly what the driver has queued
            n = port.in_waiting
            return port.read(n) if n else b""
        return port.read(4096)

    def _on_item(self, item: sf.Frame | sf.FrameError, now: float) -> None:
        if isinstance(item, sf.FrameError):
            self._bad(now, item.reason, item.seq)
            return
        msg = sf.parse_message(item)
        if isinstance(msg, sf.FrameError):
            self._bad(now, msg.reason, msg.seq)
        elif isinstance(msg, sf.MastState):
            if self.t_state is None or self.has(F_SILENT):
                self._event("MAST_ONLINE")
            self.joints = (msg.pan_rad, msg.tilt_rad, msg.lift_m)
            fault = bool(msg.flags & sf.STATE_FAULT)
            if fault != self.has(F_CONTROLLER):
                self._event("MAST_CONTROLLER_FAULT" if fault else "MAST_CONTROLLER_OK", flags=msg.flags)
            self._set(F_CONTROLLER, fault)
            self.flags, self.t_state = msg.flags, now
        elif isinstance(msg, sf.Ack):
            p = self._pending
            if p is not None and msg.seq == p.seq and msg.type == p.type:
                self.acks += 1
                self._pending = None
                self.last_result = "ack"
                self._set(F_NO_ACK | F_NAK, False)
        elif isinstance(msg, sf.Nak):
            self._on_nak(msg, now)
        else:
            self._bad(now, f"unexpected {type(msg).__name__}", item.seq)

    def _on_nak(self, msg: sf.Nak, now: float) -> None:
        p = self._pending
        self.naks += 1
        reason = sf.NAK_REASONS.get(msg.reason, f"reason {msg.reason}")
        if p is None or msg.seq != p.seq:
            return  # a NAK of a frame we no longer wait for (or of line noise)
        if msg.reason == sf.NAK_BAD_CRC:
            self._retry(p, now)
            return
        self._pending = None
        self.last_result = f"nak: {reason}"
        self._hold(F_NAK, now)
        self._event("MAST_NAK", type=sf.TYPE_NAMES.get(p.type, p.type), seq=p.seq, reason=reason)

    def _timeouts(self, now: float) -> None:
        p = self._pending
        if p is not None and now >= p.deadline:
            self._retry(p, now)

    def _retry(self, p: _Pending, now: float) -> None:
        tname = sf.TYPE_NAMES.get(p.type, p.type)
        if p.tries > self.retries:
            self._pending = None
            self.no_acks += 1
            self.last_result = "no_ack"
            self._set(F_NO_ACK)
            self._event("MAST_NO_ACK", type=tname, seq=p.seq, n=p.tries)
            return
        self.retransmits += 1
        self._event("MAST_RETRY", type=tname, seq=p.seq, n=p.tries, max=self.retries)
        p.tries += 1
        p.deadline = now + self.ack_timeout_s
        self._write(p.frame, now)

    def _send_new(self, msg: sf.Message, now: float) -> None:
        self._seq = (self._seq + 1) & 0xFF
        frame = sf.encode_message(msg, self._seq)
        self._pending = _Pending(self._seq, frame[4], frame, now + self.ack_timeout_s, 1)
        self._write(frame, now)

    def _write(self, data: bytes, now: float) -> None:
        if self.port is None:
            return
        try:
            self.port.write(data)
            self.tx_bytes += len(data)
        except Exception as exc:  # noqa: BLE001 - SerialException/OSError/timeout: a device fault
            self._port_failed(now, exc)

    def _bad(self, now: float, reason: str, seq: int) -> None:
        self._hold(F_BAD_FRAMES, now)
        self._event("MAST_BAD_FRAME", reason=reason, seq=seq)

    def _supervise(self, now: float) -> None:
        assert self._t_start is not None
        age = now - (self.t_state if self.t_state is not None else self._t_start)
        silent = age > self.state_timeout_s
        if silent and not self.has(F_SILENT):
            self._event("MAST_SILENT", age_s=age)
        self._set(F_SILENT, silent)
        garbage = self.decoder.garbage_bytes
        if garbage > self._seen_bad:  # noise between frames: counted, held as bad frames
            self._seen_bad = garbage
            self._hold(F_BAD_FRAMES, now)

    def _port_failed(self, now: float, exc: BaseException) -> None:
        self._event("MAST_PORT_ERROR", port=self.name, error=f"{type(exc).__name__}: {exc}")
        self._set(F_PORT)
        try:
            if self.port is not None:
                self.port.close()
        except Exception:  # noqa: BLE001, S110 - closing a broken port may fail too
            pass
        self.port = None
        self._t_reopen = now

    def _try_reopen(self, now: float) -> None:
        if self.opener is None or now - self._t_reopen < self.reconnect_period_s:
            return
        self._t_reopen = now
        try:
            self.port = self.opener()
        except Exception as exc:  # noqa: BLE001 - an absent device is a fault, not a crash
            self._event("MAST_PORT_ERROR", port=self.name, error=f"{type(exc).__name__}: {exc}")
            return
        self._set(F_PORT, False)

    def counters(self) -> dict[str, int]:
        d = self.decoder
        return {
            "acks": self.acks,
            "naks": self.naks,
            "retransmits": self.retransmits,
            "no_acks": self.no_acks,
            "crc_errors": d.crc_errors,
            "length_errors": d.length_errors,
            "garbage_bytes": d.garbage_bytes,
            "frames": d.frames,
        }

    def close(self) -> None:
        if self.port is not None:
            self.port.close()
            self.port = None


def move_progress(
    mast: MastSerialDriver,
    goal: tuple[float, float, float],
    elapsed_s: float,
    tolerance_rad: float,
    lift_tolerance_m: float,
    timeout_s: float,
) -> str:
    """``"arrived"``, ``"moving"`` or why the mast move failed (faults, NAK, no ACK, timeout)."""
    if mast.faults & CRITICAL:
        return "mast faults: " + ",".join(mast.fault_names())
    if mast.last_result.startswith(("nak", "no_ack")) and not mast.busy:
        return mast.last_result
    if elapsed_s > timeout_s:
        return f"not at target after {timeout_s:.0f} s"
    q = mast.joints
    if q is None or mast.busy:
        return "moving"
    near = abs(q[0] - goal[0]) <= tolerance_rad and abs(q[1] - goal[1]) <= tolerance_rad
    return "arrived" if near and abs(q[2] - goal[2]) <= lift_tolerance_m else "moving"
