"""Flight driver of the twelve wheel motor controllers on the rover's CAN bus.

python-can ``Bus`` (any interface: ``socketcan`` on the rover, ``virtual`` or ``udp_hub``
on the bench) and the frames of ``config/rover.dbc`` through :mod:`fsw.comm.rover_can`.
The driver only moves bytes and supervises; what to command is the motion task's business.

* ``transmit(now)`` sends an axis its COMMAND frame (the latest setpoint, Enable, a one-shot
  ClearFaults, the axis's own alive counter) in the frame its set-point or Enable changes, with
  a ClearFaults, after a send failure or a bus reopen, and otherwise at least every
  ``command_refresh_s`` (well inside the controllers' command timeout, 0.5 s on the rover: an
  unchanged command is a refresh, not news; 0 sends every axis every frame); and the flight
  computer's heartbeat at its period.
* ``poll(now)`` drains the bus, decodes STATUS and HEARTBEAT frames (end-to-end protection,
  :mod:`fsw.comm.e2e`: checksum and reserved bits in the codec, then the alive counter per
  frame id here -- a repeated counter or a jump beyond ``e2e_max_delta`` is refused, smaller
  jumps count lost frames; the position is unwrapped) and supervises: status
  timeout per axis, heartbeat loss per node, the whole bus silent (bus-off, cable), fault bits
  reported by a controller, send failures. Every finding is a fault bit and an event.
* ``estop(engage)`` broadcasts the emergency stop; while engaged commands go out disabled.

Own frames echoed back by the bus (``udp_multicast`` receives its own traffic, ``udp_hub`` and
``virtual`` when asked) are ignored.
Frames of other devices on the same bus (the attitude sensor, ``fsw.drivers.imu_can``) go to
the callback registered for their id in ``listeners``, with the receive time.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import ClassVar

import can

from fsw.comm.e2e import SequenceChecker
from fsw.comm.rover_can import (
    AXES,
    NMT_STATES,
    POSITION_WRAP_RAD,
    AxisStatus,
    Bad,
    Heartbeat,
    RoverCan,
)
from fsw.drivers.base import DriverBase
from fsw.framework.telemetry import EventDef, Severity

F_BAD_FRAMES, F_TX, F_STATUS_TIMEOUT, F_NODE_LOST = 0x01, 0x02, 0x04, 0x08
F_BUS_SILENT, F_MOTOR, F_ESTOP, F_NO_BUS, F_LOST_FRAMES = 0x10, 0x20, 0x40, 0x80, 0x100
#: faults that make motion unsafe (bad or lost frames alone only degrade)
CRITICAL = F_TX | F_STATUS_TIMEOUT | F_NODE_LOST | F_BUS_SILENT | F_MOTOR | F_ESTOP | F_NO_BUS


@dataclass
class AxisState:
    """What the flight computer knows of one motor controller."""

    position_rad: float = 0.0  # unwrapped
    velocity_radps: float = 0.0
    current_a: float = 0.0
    enabled: bool = False
    faults: frozenset[str] = field(default_factory=frozenset)
    t_status: float | None = None
    t_heartbeat: float | None = None
    nmt_state: int | None = None
    counter: int | None = None
    raw_position: float = 0.0
    timed_out: bool = False
    lost: bool = False


class CanMotorDriver(DriverBase):
    """Commands, status, supervision and e-stop for the motor controllers in ``codec``'s DBC."""

    FAULTS: ClassVar[dict[str, int]] = {
        "bad_frames": F_BAD_FRAMES,
        "tx_error": F_TX,
        "status_timeout": F_STATUS_TIMEOUT,
        "node_lost": F_NODE_LOST,
        "bus_silent": F_BUS_SILENT,
        "motor_fault": F_MOTOR,
        "estop": F_ESTOP,
        "no_bus": F_NO_BUS,
        "lost_frames": F_LOST_FRAMES,
    }
    EVENTS: ClassVar[tuple[EventDef, ...]] = (
        EventDef("CAN_BAD_FRAME", Severity.WARNING_LO, "CAN frame refused ({reason}): {detail}", throttle=5),
        EventDef("CAN_FRAMES_LOST", Severity.WARNING_LO, "{axis}: {lost} status frame(s) lost", throttle=5),
        EventDef(
            "CAN_E2E_SEQUENCE", Severity.WARNING_LO, "{frame} refused: alive counter {verdict} ({counter})", throttle=5
        ),
        EventDef("CAN_TX_ERROR", Severity.WARNING_HI, "CAN send failed: {error}", throttle=5),
        EventDef("CAN_NO_BUS", Severity.WARNING_HI, "CAN bus cannot be opened: {error}", throttle=3),
        EventDef("CAN_NODE_ONLINE", Severity.ACTIVITY_HI, "{axis} heartbeat: {state}"),
        EventDef("CAN_NODE_LOST", Severity.WARNING_HI, "{axis}: no heartbeat for {age_s:.1f} s"),
        EventDef("CAN_STATUS_TIMEOUT", Severity.WARNING_HI, "{axis}: no status for {age_s:.2f} s"),
        EventDef(
            "CAN_BUS_SILENT",
            Severity.WARNING_HI,
            "no valid frame from any controller for {age_s:.2f} s (bus-off, cable or power)",
        ),
        EventDef("CAN_BUS_RECOVERED", Severity.ACTIVITY_HI, "motor controllers heard again"),
        EventDef("MOTOR_FAULT", Severity.WARNING_HI, "{axis} reports {faults}"),
        EventDef("MOTOR_FAULT_CLEARED", Severity.ACTIVITY_HI, "{axis} fault bits clear"),
        EventDef("ESTOP", Severity.WARNING_HI, "emergency stop {action}"),
    )

    def __init__(
        self,
        bus: can.BusABC | None,
        codec: RoverCan,
        *,
        status_timeout_s: float = 0.5,
        heartbeat_timeout_s: float = 2.5,
        heartbeat_period_s: float = 1.0,
        error_hold_s: float = 2.0,
        reconnect_period_s: float = 2.0,
        e2e_max_delta: int = 3,
        command_refresh_s: float = 0.0,
        opener: Callable[[], can.BusABC] | None = None,
    ) -> None:
        super().__init__(error_hold_s)
        self.bus, self.codec, self.opener = bus, codec, opener
        self.status_timeout_s, self.heartbeat_timeout_s = status_timeout_s, heartbeat_timeout_s
        self.heartbeat_period_s, self.reconnect_period_s = heartbeat_period_s, reconnect_period_s
        self.axes: dict[str, AxisState] = {a: AxisState() for a in AXES}
        self.setpoints: dict[str, float | None] = {a: None for a in AXES}  # None -> Enable=0
        self.estopped = False
        self._clear_once = False
        self.command_refresh_s = command_refresh_s
        self._tx_counter = dict.fromkeys(AXES, 0)  # alive counter per COMMAND frame id (E2E: +1 a frame)
        # per axis: (setpoint, enable, time) of the last COMMAND sent; None = send at the next transmit
        self._tx_last: dict[str, tuple[float, bool, float] | None] = dict.fromkeys(AXES)
        self._estop_counter = 0
        self._t_hb_sent: float | None = None
        self._t_start: float | None = None
        self._t_any_rx: float | None = None
        self._t_reopen = -1e9
        self._hb_counter = 0
        # alive-counter state per frame id; a silence longer than the timeout re-initialises it
        self._seq_status = SequenceChecker(e2e_max_delta, status_timeout_s)
        self._seq_heartbeat = SequenceChecker(e2e_max_delta, heartbeat_timeout_s)
        self.rx_frames = self.rx_bad = self.rx_lost = self.rx_echo = self.rx_e2e_seq = 0
        self.listeners: dict[int, Callable[[bytes, float], None]] = {}  # frame id -> another driver
        self.tx_frames = self.tx_errors = 0
        if bus is None:
            self._set(F_NO_BUS)

    # -- commands ---------------------------------------------------------------------------
    def set_setpoint(self, axis: str, value: float | None) -> None:
        """rad/s for DRIVE axes, rad for STEER and SHOULDER; ``None`` disables the axis."""
        if axis not in self.setpoints:
            raise KeyError(f"unknown axis {axis!r}")
        self.setpoints[axis] = value

    def clear_faults(self) -> None:
        """Send ClearFaults once with the next commands (controllers clear their latched bits)."""
        self._clear_once = True

    def estop(self, engage: bool, now: float) -> None:
        self.estopped = engage
        self._set(F_ESTOP, engage)
        self._send_estop(now)
        self._event("ESTOP", action="engaged" if engage else "released")
        if not engage:
            self._clear_once = True

    def transmit(self, now: float) -> None:
        """Send the COMMAND frames due (changed, one-shot ClearFaults, or older than
        ``command_refresh_s``) and, when due, the heartbeat (and a held e-stop)."""
        if self.bus is None:
            return
        clear, self._clear_once = self._clear_once, False
        refresh = self.command_refresh_s - 1e-9
        last_sent, counters, encode = self._tx_last, self._tx_counter, self.codec.encode_command
        for axis, sp in self.setpoints.items():
            enable = sp is not None and not self.estopped
            value = sp or 0.0
            last = last_sent[axis]
            if not clear and last is not None and last[0] == value and last[1] is enable and now - last[2] < refresh:
                continue
            counter = counters[axis] = counters[axis] + 1  # full alive counter (E2E freshness)
            sent = self._send(*encode(axis, value, enable, clear, counter), now)
            last_sent[axis] = (value, enable, now) if sent else None  # a failed send is retried next frame
        if self._t_hb_sent is None or now - self._t_hb_sent >= self.heartbeat_period_s:
            self._t_hb_sent = now
            self._hb_counter += 1
            self._send(*self.codec.encode_heartbeat("FSW", 5 if not self.estopped else 4, self._hb_counter), now)
            if self.estopped:
                self._send_estop(now)  # repeat while engaged: a controller that rebooted learns it

    def _send_estop(self, now: float) -> None:
        self._estop_counter += 1
        self._send(*self.codec.encode_estop(self.estopped, self._estop_counter), now)

    def _send(self, frame_id: int, data: bytes, now: float) -> bool:
        if self.bus is None:
            return False
        try:
            self.bus.send(can.Message(arbitration_id=frame_id, data=data, is_extended_id=False), timeout=0.05)
            self.tx_frames += 1
            return True
        except (can.CanError, OSError) as exc:
            self.tx_errors += 1
            self._hold(F_TX, now)
            self._event("CAN_TX_ERROR", error=f"{type(exc).__name__}: {exc}")
            return False

    # -- reception and supervision ---------------------------------------------------------------
    def poll(self, now: float, max_frames: int = 1000) -> None:
        """Drain received frames and update faults; call once per frame before using ``axes``."""
        self.last_poll_s = now
        if self._t_start is None:
            self._t_start = now
        self._expire_holds(now)
        if self.bus is None:
            self._try_reopen(now)
            return
        for _ in range(max_frames):
            try:
                msg = self.bus.recv(timeout=0.0)
            except (can.CanError, OSError, ValueError) as exc:
                self._bad(now, "receive", f"{type(exc).__name__}: {exc}")
                continue
            if msg is None:
                break
            if msg.is_error_frame or msg.is_remote_frame:
                self._bad(now, "error_frame" if msg.is_error_frame else "remote_frame", f"id 0x{msg.arbitration_id:X}")
                continue
            self._on_frame(bytes(msg.data), msg.arbitration_id, msg.is_extended_id, now)
        self._supervise(now)

    def _on_frame(self, data: bytes, frame_id: int, extended: bool, now: float) -> None:
        listener = None if extended else self.listeners.get(frame_id)
        if listener is not None:
            listener(data, now)
            return
        d = self.codec.decode(frame_id, data, extended, epoch=None)  # the checksum: with the freshness below
        if isinstance(d, Bad):
            self._bad(now, d.reason, d.detail)
            return
        if isinstance(d, AxisStatus):
            if not self._in_sequence(self._seq_status, frame_id, data, now, d.axis):
                return
            self._on_status(d, now)
        elif isinstance(d, Heartbeat) and d.node != "FSW":
            if not self._in_sequence(self._seq_heartbeat, frame_id, data, now, None):
                return
            st = self.axes[d.node]
            if st.lost or st.t_heartbeat is None or st.nmt_state != d.state:
                self._event("CAN_NODE_ONLINE", axis=d.node, state=NMT_STATES.get(d.state, str(d.state)))
            st.lost = False
            st.t_heartbeat, st.nmt_state = now, d.state
            self._t_any_rx = now
        else:
            self.rx_echo += 1  # our own commands, heartbeat or e-stop echoed back
            return
        self.rx_frames += 1

    def _in_sequence(self, seq: SequenceChecker, frame_id: int, data: bytes, now: float, axis: str | None) -> bool:
        """The E2E freshness check (counter and checksum); a refused frame is counted (``rx_bad``,
        ``rx_e2e_seq``) and evented."""
        layout = self.codec.e2e[frame_id]
        verdict, lost = seq.check_frame(layout, data, now)
        counter = layout.counter(data)
        if lost and axis is not None:
            self.rx_lost += lost
            self._hold(F_LOST_FRAMES, now)
            self._event("CAN_FRAMES_LOST", axis=axis, lost=lost)
        if verdict.accepted:
            return True
        self.rx_bad += 1
        self.rx_e2e_seq += 1
        self._hold(F_BAD_FRAMES, now)
        name = self.codec.e2e[frame_id].name
        self._event("CAN_E2E_SEQUENCE", frame=name, verdict=verdict.value, counter=counter)
        return False

    def _on_status(self, s: AxisStatus, now: float) -> None:
        st = self.axes[s.axis]
        if st.counter is not None:
            delta = (s.position_rad - st.raw_position + POSITION_WRAP_RAD / 2) % POSITION_WRAP_RAD
            st.position_rad += delta - POSITION_WRAP_RAD / 2
        else:
            st.position_rad = s.position_rad
        st.raw_position, st.counter = s.position_rad, s.counter
        st.velocity_radps, st.current_a, st.enabled = s.velocity_radps, s.current_a, s.enabled
        if s.faults != st.faults:
            if s.faults:
                self._event("MOTOR_FAULT", axis=s.axis, faults=",".join(sorted(s.faults)))
            else:
                self._event("MOTOR_FAULT_CLEARED", axis=s.axis)
        st.faults = s.faults
        if st.timed_out:
            st.timed_out = False
        st.t_status = now
        self._t_any_rx = now

    def _bad(self, now: float, reason: str, detail: str) -> None:
        self.rx_bad += 1
        self._hold(F_BAD_FRAMES, now)
        self._event("CAN_BAD_FRAME", reason=reason, detail=detail)

    def _supervise(self, now: float) -> None:
        assert self._t_start is not None
        last_any = self._t_any_rx if self._t_any_rx is not None else self._t_start
        silent = now - last_any > self.status_timeout_s
        if silent and not self.has(F_BUS_SILENT):
            self._event("CAN_BUS_SILENT", age_s=now - last_any)
        elif not silent and self.has(F_BUS_SILENT):
            self._event("CAN_BUS_RECOVERED")
        self._set(F_BUS_SILENT, silent)
        any_timeout = any_lost = any_fault = False
        for axis, st in self.axes.items():
            age = now - (st.t_status if st.t_status is not None else self._t_start)
            if age > self.status_timeout_s:
                if not st.timed_out and not silent:
                    self._event("CAN_STATUS_TIMEOUT", axis=axis, age_s=age)
                st.timed_out = True
            any_timeout |= st.timed_out
            hb_age = now - (st.t_heartbeat if st.t_heartbeat is not None else self._t_start)
            if hb_age > self.heartbeat_timeout_s and not st.lost:
                st.lost = True
                self._event("CAN_NODE_LOST", axis=axis, age_s=hb_age)
            any_lost |= st.lost
            any_fault |= bool(st.faults)
        self._set(F_STATUS_TIMEOUT, any_timeout)
        self._set(F_NODE_LOST, any_lost)
        self._set(F_MOTOR, any_fault)

    def _try_reopen(self, now: float) -> None:
        if self.opener is None or now - self._t_reopen < self.reconnect_period_s:
            return
        self._t_reopen = now
        try:
            self.bus = self.opener()
        except Exception as exc:  # noqa: BLE001 - any backend failure is a device fault, not a crash
            self._event("CAN_NO_BUS", error=f"{type(exc).__name__}: {exc}")
            return
        self._set(F_NO_BUS, False)
        self._t_start = now
        self._tx_last = dict.fromkeys(AXES)  # a new bus: every axis's command goes out at once

    # -- views ------------------------------------------------------------------------------
    def faulted_axes(self) -> dict[str, list[str]]:
        return {a: sorted(s.faults) for a, s in self.axes.items() if s.faults}

    def close(self) -> None:
        if self.bus is not None:
            try:
                self.bus.shutdown()
            finally:
                self.bus = None
