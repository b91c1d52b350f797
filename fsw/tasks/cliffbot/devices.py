"""The Cliff-bot's device task: its CAN bus to the Anchorbots' winches, its wheels and IMU.

Thin: every activation it takes the frames waiting on the bus (``res.team_can``, a bench's
end, or ``[cliffbot_bus]`` opened here) into the sans-I/O
:class:`~fsw.drivers.cliffbot_devices.CliffbotDevices` (E2E and alive-counter checks; a bad
frame is counted and ignored), publishes the statuses, and puts the mission's latest commands
(winch rates, enable, clear-faults, wheel rates; ``config/team.dbc``) on the bus. Without a
bus it runs and says so once (the mission then stops: no status).
"""

from __future__ import annotations

from typing import ClassVar

import can

from fsw.comm.team.team_can import WINCHES
from fsw.drivers.cliffbot_devices import CliffbotDevices
from fsw.framework.telemetry import Channel, EventDef, Severity
from fsw.tasks.base import FlightTask
from fsw.tasks.cliffbot.messages import CB_COMMANDS, CB_STATUS, DeviceStatus
from fsw.tasks.cliffbot_mission import Commands

MAX_FRAMES = 256  # frames taken per activation (a babbling bus cannot stall the frame)


class CliffbotDevicesTask(FlightTask):
    KIND: ClassVar[str] = "cliffbot_devices"
    RATE_HZ: ClassVar[tuple[float, float]] = (5.0, 50.0)  # the winches time out after 0.5 s without a command
    DOC: ClassVar[str] = "Cliff-bot team bus: winch, wheel and IMU statuses in, winch and wheel commands out."
    CHANNELS = (
        Channel("winch_a_m", "m", doc="tether A paid out"),
        Channel("winch_b_m", "m", doc="tether B paid out"),
        Channel("tension_a_n", "N"),
        Channel("tension_b_n", "N"),
        Channel("bad_frames", "count", hi=0, doc="frames refused (E2E, length, counter)"),
        Channel("stale", doc="devices whose status stopped"),
    )
    EVENTS = (
        EventDef("NO_BUS", Severity.WARNING_HI, "no team CAN bus: {error}"),
        EventDef("BUS_ERROR", Severity.WARNING_LO, "team CAN bus: {error}", throttle=5),
        EventDef("BAD_FRAME", Severity.WARNING_LO, "frame refused: {reason}", throttle=5),
    )

    def setup(self) -> None:
        self.dev = CliffbotDevices(timeout_s=self.ctx.cfg.cliffbot_bus.status_timeout_s)
        self.bus: can.BusABC | None = self.ctx.res.team_can
        if self.bus is None:
            bus_cfg = self.ctx.cfg.cliffbot_bus
            if bus_cfg.can_interface == "none":
                self.event("NO_BUS", error="[cliffbot_bus] can_interface = none")
            else:
                from fsw.drivers.can_inproc import open_bus

                try:
                    self.bus = open_bus(interface=bus_cfg.can_interface, channel=bus_cfg.can_channel)
                except (OSError, ValueError, can.CanError) as exc:
                    self.event("NO_BUS", error=f"{type(exc).__name__}: {exc}")
        self.commands = self.subscribe(CB_COMMANDS, depth=1)
        self._bad = 0

    def run(self, frame: int) -> None:
        now = self.ctx.clock.now()
        frames: list[tuple[int, bytes]] = []
        if self.bus is not None:
            try:
                for _ in range(MAX_FRAMES):
                    msg = self.bus.recv(timeout=0.0)
                    if msg is None:
                        break
                    frames.append((int(msg.arbitration_id), bytes(msg.data)))
            except can.CanError as exc:
                self.event("BUS_ERROR", error=str(exc))
        self.dev.receive(frames, now)
        if self.dev.bad_frames > self._bad:
            self._bad = self.dev.bad_frames
            self.event("BAD_FRAME", reason=self.dev.last_bad)
        self.publish(CB_STATUS, DeviceStatus(self.dev, now))
        cmd: Commands | None = self.commands.latest()
        if cmd is not None and self.bus is not None:
            for fid, data in self.dev.commands(cmd.rates_mps, cmd.enable, cmd.clear_faults, cmd.wheels_radps):
                try:
                    self.bus.send(can.Message(arbitration_id=fid, data=data, is_extended_id=False))
                except can.CanError as exc:
                    self.event("BUS_ERROR", error=str(exc))
        self._telemetry(now)

    def _telemetry(self, now: float) -> None:
        for w, key in zip(WINCHES, ("a", "b"), strict=True):
            st = self.dev.winch.get(w)
            if st is not None:
                self.tlm(f"winch_{key}_m", st.paid_out_m)
                self.tlm(f"tension_{key}_n", st.tension_n)
        self.tlm("bad_frames", self.dev.bad_frames)
        self.tlm("stale", ",".join(self.dev.stale(now)))
