"""Emulated wheel motor controllers: the CAN end of the twelve axes of the true rover.

Each controller behaves as a real one on the bus (frames of ``config/rover.dbc``):

* STATUS every ``status_period_s`` (joint position, velocity, current, Enabled, fault bits,
  alive counter, checksum) and a HEARTBEAT every ``heartbeat_period_s`` (NMT state, alive
  counter, checksum): every frame end-to-end protected (``fsw.comm.e2e``);
* a frame with a bad checksum, set reserved bits or a wrong length is counted and ignored; a
  COMMAND (or an ESTOP release) whose alive counter repeats or jumps beyond ``e2e_max_delta``
  is counted and ignored too -- a stale, duplicated or reordered command never moves a wheel.
  An ESTOP *engage* is obeyed out of sequence too (the safe direction) when its checksum holds
  under the last accepted ESTOP's epoch or an epoch below 16 (a restarted flight computer);
* Enable=1 with no latched fault drives the axis to the set-point; the set-point is clipped
  to the controller's limits and FaultLimit is reported while it is;
* no COMMAND for ``command_timeout_s`` while enabled -> stop, FaultTimeout (latched);
* ESTOP Engage=1 -> every axis stops, FaultEStop (latched); ClearFaults clears latched bits
  once the cause is gone;
* over-current (a stalled wheel) -> stop, FaultOvercurrent (latched); an injected driver
  fault -> FaultDriver while it lasts, the motor coasts;
* bus-off (injected): no reception, no transmission; on return the node boots again.

Frames cross :class:`hil_sim.faults.FaultInjector` in both directions (drop, delay, corrupt).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import can

from fsw.comm.e2e import SequenceChecker
from fsw.comm.rover_can import (
    AXES,
    STATE_BOOTUP,
    STATE_OPERATIONAL,
    STATE_PREOP,
    STATE_STOPPED,
    AxisCommand,
    Bad,
    EStop,
    Heartbeat,
    RoverCan,
)
from fsw.framework.params import param
from hil_sim.faults import FaultInjector
from hil_sim.rover_truth import RoverTruth


@dataclass(frozen=True)
class MotorControllerConfig:
    status_period_s: float = param(0.1, lo=0.005, hi=10.0, units="s")
    heartbeat_period_s: float = param(1.0, lo=0.05, hi=60.0, units="s")
    command_timeout_s: float = param(0.5, lo=0.02, hi=60.0, units="s")
    max_drive_radps: float = param(3.0, lo=0.1, hi=30.0, units="rad/s", doc="drive set-point limit")
    steer_limit_deg: float = param(95.0, lo=1.0, hi=180.0, units="deg", doc="steer set-point limit (+-)")
    shoulder_min_deg: float = param(5.0, lo=-90.0, hi=90.0, units="deg")
    shoulder_max_deg: float = param(55.0, lo=-90.0, hi=90.0, units="deg")
    overcurrent_a: float = param(10.0, lo=0.1, hi=12.7, units="A")
    e2e_max_delta: int = param(3, lo=1, hi=4, doc="largest accepted alive-counter jump of a COMMAND or ESTOP "
                               "(above 4, a 1-3 bit error could move the counter across a freshness epoch)")


class _Axis:
    def __init__(self, name: str, index: int) -> None:
        self.name, self.kind, self.index = name, name.split("_")[0], index
        self.enabled = False
        self.latched: set[str] = set()
        self.limit = False
        self.setpoint = 0.0
        self.t_cmd = -math.inf
        self.state = STATE_BOOTUP
        self.counter = 0
        self.hb_counter = 0
        self.last_cmd_counter: int | None = None


class MotorControllerBank:
    """All twelve controllers on one python-can bus, driving a :class:`RoverTruth`."""

    def __init__(
        self,
        bus: can.BusABC,
        codec: RoverCan,
        rover: RoverTruth,
        cfg: MotorControllerConfig,
        faults: FaultInjector | None = None,
    ) -> None:
        self.bus, self.codec, self.rover, self.cfg = bus, codec, rover, cfg
        self.faults = faults or FaultInjector()
        self.axes = {name: _Axis(name, i % 4) for i, name in enumerate(AXES)}
        self.estop = False
        self._t_status = -math.inf
        self._t_hb = -math.inf
        self._was_off = False
        self._delayed: list[tuple[float, int, int, bytes, bool]] = []  # (due, order, id, data, to_fsw)
        self._order = 0
        self.rx_commands = self.rx_bad = self.rx_other = self.tx_frames = 0
        self.rx_e2e_seq = 0  # frames refused by the alive-counter check (repeated, out of sequence)
        self.fsw_heartbeats = 0
        self._seq_cmd = SequenceChecker(cfg.e2e_max_delta, cfg.command_timeout_s)
        self._seq_other = SequenceChecker(cfg.e2e_max_delta, 2.5 * cfg.heartbeat_period_s)
        self._estop_id = codec.frame_id("ESTOP")
        self._estop_epochs: set[int] = set()  # the epoch of the last accepted ESTOP (and the next)
        self.tap: Callable[[can.Message], None] | None = None  # sees every received frame (a bus logger)
        self.ignore_ids: set[int] = set()  # frames of other devices on the bus (e.g. the IMU's)

    # -- reception --------------------------------------------------------------------------
    def receive(self, now: float) -> None:
        """Drain the bus and act on commands and e-stops (nothing while bus-off)."""
        off = self.faults.bus_off()
        for _ in range(10000):
            try:
                msg = self.bus.recv(timeout=0.0)
            except (can.CanError, OSError, ValueError):  # e.g. an undecodable datagram (udp_hub)
                self.rx_bad += 1
                continue
            if msg is None:
                break
            if self.tap is not None:
                self.tap(msg)
            if off or msg.arbitration_id in self.ignore_ids:
                continue
            axis = self.codec.route.get(msg.arbitration_id, ("", None, None))[1]
            fate, data, delay = self.faults.can_frame(axis, False, bytes(msg.data))
            if fate == "drop":
                continue
            if delay:
                self._queue(now + delay, msg.arbitration_id, data, False)
            else:
                self._on_frame(msg.arbitration_id, data, msg.is_extended_id, now)
        for frame_id, data in self._due(now, to_fsw=False):
            self._on_frame(frame_id, data, False, now)
        if off:
            self._was_off = True

    def _on_frame(self, frame_id: int, data: bytes, extended: bool, now: float) -> None:
        d = self.codec.decode(frame_id, data, extended, epoch=None)  # the checksum: with the freshness below
        if isinstance(d, Bad):
            self.rx_bad += 1
        elif isinstance(d, AxisCommand):
            if self._in_sequence(self._seq_cmd, frame_id, data, now):
                self.rx_commands += 1
                self._on_command(self.axes[d.axis], d, now)
        elif isinstance(d, EStop):
            in_seq = self._in_sequence(self._seq_other, frame_id, data, now)
            if d.engage and (in_seq or self._plausible_engage(frame_id, data)):  # fail-safe: see below
                self.estop = True
                for ax in self.axes.values():
                    ax.enabled = False
                    ax.latched.add("FaultEStop")
            elif in_seq:
                self.estop = False
        elif isinstance(d, Heartbeat) and d.node == "FSW":
            if self._in_sequence(self._seq_other, frame_id, data, now):
                self.fsw_heartbeats += 1
        else:
            self.rx_other += 1  # statuses and heartbeats: our own traffic echoed back

    def _plausible_engage(self, frame_id: int, data: bytes) -> bool:
        """An ESTOP engage out of sequence is still obeyed (stopping is the safe direction) if
        its checksum holds under the epoch of the last accepted ESTOP or FSW heartbeat (a
        repeat) or under an epoch below 16 (a flight computer that restarted): not under any."""
        lay = self.codec.e2e[frame_id]
        epoch = lay.implied_epoch(data)
        return epoch < 16 or epoch in self._estop_epochs

    def _in_sequence(self, seq: SequenceChecker, frame_id: int, data: bytes, now: float) -> bool:
        lay = self.codec.e2e[frame_id]
        verdict, _lost = seq.check_frame(lay, data, now)
        if verdict.accepted and frame_id == self._estop_id:
            self._estop_epochs = {lay.implied_epoch(data), (lay.implied_epoch(data) + 1) % lay.epoch_mod}
        if not verdict.accepted:
            self.rx_e2e_seq += 1
        return verdict.accepted

    def _on_command(self, ax: _Axis, cmd: AxisCommand, now: float) -> None:
        ax.t_cmd = now
        ax.last_cmd_counter = cmd.counter
        if cmd.clear_faults:
            ax.latched.discard("FaultTimeout")
            ax.latched.discard("FaultOvercurrent")
            if not self.estop:
                ax.latched.discard("FaultEStop")
        blocked = bool(ax.latched) or self.estop or self.faults.motor_fault(ax.name) == "driver"
        if not cmd.enable or blocked:
            ax.enabled = False
            ax.state = STATE_STOPPED if blocked else STATE_PREOP
            return
        lo, hi = self._limits(ax.kind)
        ax.limit = not (lo <= cmd.setpoint <= hi)
        ax.setpoint = min(hi, max(lo, cmd.setpoint))
        ax.enabled = True
        ax.state = STATE_OPERATIONAL

    def _limits(self, kind: str) -> tuple[float, float]:
        c = self.cfg
        if kind == "DRIVE":
            return -c.max_drive_radps, c.max_drive_radps
        if kind == "STEER":
            s = math.radians(c.steer_limit_deg)
            return -s, s
        return math.radians(c.shoulder_min_deg), math.radians(c.shoulder_max_deg)

    # -- actuation --------------------------------------------------------------------------
    def actuate(self, now: float) -> None:
        """Timeouts, injected faults and set-points into the rover truth (before it steps)."""
        r = self.rover
        for ax in self.axes.values():
            if ax.enabled and now - ax.t_cmd > self.cfg.command_timeout_s:
                ax.enabled = False
                ax.latched.add("FaultTimeout")
                ax.state = STATE_STOPPED
            mode = self.faults.motor_fault(ax.name)
            if ax.kind == "DRIVE":
                r.stalled[ax.index] = mode == "stall"
                r.drive_fault[ax.index] = mode == "driver"
                if r.drive_current[ax.index] > self.cfg.overcurrent_a:
                    ax.latched.add("FaultOvercurrent")
                    ax.enabled = False
                r.omega_cmd[ax.index] = ax.setpoint if ax.enabled else 0.0
            elif ax.kind == "STEER":
                r.steer_cmd[ax.index] = ax.setpoint if ax.enabled and not mode else r.steer[ax.index]
            else:
                r.shoulder_cmd[ax.index] = ax.setpoint if ax.enabled and not mode else r.shoulder[ax.index]

    # -- transmission -----------------------------------------------------------------------
    def transmit(self, now: float) -> None:
        """Statuses and heartbeats when due, and frames whose injected delay has passed."""
        if self.faults.bus_off():
            return
        if self._was_off:  # back from bus-off: the nodes reboot
            self._was_off = False
            for ax in self.axes.values():
                ax.state = STATE_BOOTUP
            self._t_hb = -math.inf
        if now - self._t_status >= self.cfg.status_period_s - 1e-9:
            self._t_status = now
            for ax in self.axes.values():
                self._send_status(ax, now)
        if now - self._t_hb >= self.cfg.heartbeat_period_s - 1e-9:
            self._t_hb = now
            for ax in self.axes.values():
                ax.hb_counter += 1  # full alive counter (E2E freshness)
                self._emit(ax.name, *self.codec.encode_heartbeat(ax.name, ax.state, ax.hb_counter), now)
                if ax.state == STATE_BOOTUP:
                    ax.state = STATE_PREOP
        for frame_id, data in self._due(now, to_fsw=True):
            self._send(frame_id, data, now)

    def _send_status(self, ax: _Axis, now: float) -> None:
        r, i = self.rover, ax.index
        if ax.kind == "DRIVE":
            pos, vel, cur = r.drive_angle[i], r.omega[i], r.drive_current[i]
        elif ax.kind == "STEER":
            pos, vel, cur = r.steer[i], 0.0, r.steer_current[i]
        else:
            pos, vel, cur = r.shoulder[i], 0.0, r.shoulder_current[i]
        faults = set(ax.latched)
        if ax.limit:
            faults.add("FaultLimit")
        if self.faults.motor_fault(ax.name) == "driver":
            faults.add("FaultDriver")
        ax.counter += 1
        self._emit(
            ax.name,
            *self.codec.encode_status(ax.name, float(pos), float(vel), float(cur), ax.enabled, faults, ax.counter),
            now,
        )

    def _emit(self, axis: str, frame_id: int, data: bytes, now: float) -> None:
        fate, data, delay = self.faults.can_frame(axis, True, data)
        if fate == "drop":
            return
        if delay:
            self._queue(now + delay, frame_id, data, True)
        else:
            self._send(frame_id, data, now)

    def _send(self, frame_id: int, data: bytes, now: float) -> None:
        msg = can.Message(arbitration_id=frame_id, data=data, is_extended_id=False, timestamp=now)
        try:
            self.bus.send(msg)
            self.tx_frames += 1
        except can.CanError:
            pass  # a full or closed bus loses the frame, as on a real wire

    def _queue(self, due: float, frame_id: int, data: bytes, to_fsw: bool) -> None:
        self._order += 1
        self._delayed.append((due, self._order, frame_id, data, to_fsw))

    def _due(self, now: float, to_fsw: bool) -> list[tuple[int, bytes]]:
        ready = sorted(d for d in self._delayed if d[4] == to_fsw and d[0] <= now + 1e-9)
        if ready:
            self._delayed = [d for d in self._delayed if not (d[4] == to_fsw and d[0] <= now + 1e-9)]
        return [(d[2], d[3]) for d in ready]
