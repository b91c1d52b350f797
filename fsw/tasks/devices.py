"""Device components: one per driver (motors, attitude sensor, mast, cameras), polled once per
frame; the driver's events become executive events, its counters and fault word telemetry.

The drivers (``ctx.res.motors``, ``mast``, ``camera``, opened by ``fsw.drivers.factory``)
never see the executive; each component here is its driver's voice (F Prime: a driver
component per device). Schedule them first in the fast group so every other task of the
frame reads fresh device state. A driver that is not configured is simply absent: its
component runs, polls nothing, and its channels stay empty.
"""

from __future__ import annotations

import math
from typing import ClassVar, Generic, Protocol, TypeVar

from fsw.drivers.camera import CameraDriver
from fsw.drivers.can_motors import CanMotorDriver
from fsw.drivers.imu_can import ImuDriver
from fsw.drivers.mast_serial import MastSerialDriver
from fsw.framework.telemetry import Channel
from fsw.tasks.base import FlightTask
from fsw.tasks.mission_state import restore_into
from fsw.tasks.state_json import JsonObject, floats, get_list, get_opt_float, get_opt_int


class PolledDriver(Protocol):
    def poll(self, now: float) -> None: ...

    def drain_events(self) -> list[tuple[str, dict[str, object]]]: ...


D = TypeVar("D", bound=PolledDriver)


class DeviceTask(FlightTask, Generic[D]):
    """Polls one driver: events out, then :meth:`telemetry`."""

    def setup(self) -> None:
        self.driver: D | None = self.find_driver()

    def find_driver(self) -> D | None:
        raise NotImplementedError

    def run(self, frame: int) -> None:
        drv = self.driver
        if drv is None:
            return
        drv.poll(self.ctx.clock.now())
        for name, args in drv.drain_events():
            self.event(name, **args)
        self.telemetry(drv)

    def telemetry(self, drv: D) -> None:
        raise NotImplementedError


class CanMotorsDevice(DeviceTask[CanMotorDriver]):
    KIND: ClassVar[str] = "can_motors_device"
    RATE_HZ: ClassVar[tuple[float, float]] = (5.0, 50.0)  # its timeouts and moves assume ~10 Hz
    DOC: ClassVar[str] = "Polls the CAN motor-controller driver; its events and telemetry."
    CHANNELS = (
        Channel("faults", "bits", hi=0, doc="CanMotorDriver.FAULTS word"),
        Channel("rx", "frames", doc="valid frames received"),
        Channel("bad", "frames", hi=0, doc="frames refused (checksum, counter, length, unknown id)"),
        Channel("lost", "frames", hi=0, doc="status frames lost (counter jumps)"),
        Channel("tx", "frames"),
        Channel("tx_errors", "count", hi=0),
        Channel("nodes_online", "count", lo=12, doc="motor controllers with a live heartbeat"),
        Channel("axes_faulted", "count", hi=0, doc="motor controllers reporting fault bits"),
    )
    EVENTS = CanMotorDriver.EVENTS

    def find_driver(self) -> CanMotorDriver | None:
        return self.ctx.res.motors

    def telemetry(self, m: CanMotorDriver) -> None:
        self.tlm_record({
            "faults": m.faults, "rx": m.rx_frames, "bad": m.rx_bad, "lost": m.rx_lost,
            "tx": m.tx_frames, "tx_errors": m.tx_errors,
            "nodes_online": sum(1 for s in m.axes.values() if s.t_heartbeat is not None and not s.lost),
            "axes_faulted": sum(1 for s in m.axes.values() if s.faults),
        })


class ImuDevice(DeviceTask[ImuDriver]):
    KIND: ClassVar[str] = "imu_device"
    RATE_HZ: ClassVar[tuple[float, float]] = (5.0, 50.0)  # its timeouts and moves assume ~10 Hz
    DOC: ClassVar[str] = "Polls the attitude-sensor driver (frames arrive on the motor bus); events and telemetry."
    CHANNELS = (
        Channel("faults", "bits", hi=0, doc="ImuDriver.FAULTS word"),
        Channel("roll_deg", "deg", doc="body roll from the attitude sensor (left side up +)"),
        Channel("pitch_deg", "deg", doc="body pitch from the attitude sensor (nose up +)"),
        Channel("sigma_deg", "deg", doc="1-sigma of the attitude (roll and pitch RMS)"),
        Channel("frames", "frames"),
        Channel("bad", "frames", hi=0, doc="attitude frames refused (checksum, counter, length)"),
        Channel("lost", "frames", hi=0, doc="attitude frames lost (counter jumps)"),
    )
    EVENTS = ImuDriver.EVENTS

    def find_driver(self) -> ImuDriver | None:
        return self.ctx.res.imu

    def setup(self) -> None:
        super().setup()
        restore_into(self)  # a resumed mission continues the attitude average (fsw.tasks.mission_state)

    def checkpoint_state(self) -> JsonObject:
        """The driver's averaging window and alive-counter state, so a resumed mission's attitude
        is the one the uninterrupted run would have had."""
        d = self.driver
        if d is None:
            return {}
        return {"samples": [list(s) for s in d.samples], "counter": d.counter, "t_valid": d.t_valid,
                "t_start": d.t_start}

    def restore_state(self, st: JsonObject) -> None:
        d = self.driver
        if d is None or not st:
            return
        samples = [floats(s, "samples[]", 3) for s in get_list(st, "samples")]
        counter = get_opt_int(st, "counter")
        t_valid, t_start = get_opt_float(st, "t_valid"), get_opt_float(st, "t_start")
        d.samples.extend((t, r, p) for t, r, p in samples)
        d.counter, d.t_valid, d.t_start = counter, t_valid, t_start

    def telemetry(self, d: ImuDriver) -> None:
        rec: dict[str, float | int] = {"faults": d.faults, "frames": d.rx_frames, "bad": d.rx_bad,
                                       "lost": d.rx_lost}
        att = d.attitude(self.ctx.clock.now())
        if att is not None:
            rec.update(roll_deg=math.degrees(att.roll), pitch_deg=math.degrees(att.pitch),
                       sigma_deg=math.degrees(math.sqrt(float(att.cov.trace()) / 2)))
        self.tlm_record(rec)


class MastDevice(DeviceTask[MastSerialDriver]):
    KIND: ClassVar[str] = "mast_device"
    RATE_HZ: ClassVar[tuple[float, float]] = (5.0, 50.0)  # its timeouts and moves assume ~10 Hz
    DOC: ClassVar[str] = "Polls the serial mast driver; its events and telemetry."
    CHANNELS = (
        Channel("faults", "bits", hi=0, doc="MastSerialDriver.FAULTS word"),
        Channel("pan_deg", "deg"),
        Channel("tilt_deg", "deg"),
        Channel("lift_m", "m"),
        Channel("crc_errors", "count", hi=0),
        Channel("retransmits", "count"),
        Channel("naks", "count"),
    )
    EVENTS = MastSerialDriver.EVENTS

    def find_driver(self) -> MastSerialDriver | None:
        return self.ctx.res.mast

    def telemetry(self, m: MastSerialDriver) -> None:
        rec: dict[str, float | int] = {"faults": m.faults, "crc_errors": m.decoder.crc_errors,
                                       "retransmits": m.retransmits, "naks": m.naks}
        if m.joints is not None:
            rec.update(pan_deg=math.degrees(m.joints[0]), tilt_deg=math.degrees(m.joints[1]),
                       lift_m=m.joints[2])
        self.tlm_record(rec)


class CameraDevice(DeviceTask[CameraDriver]):
    KIND: ClassVar[str] = "camera_device"
    RATE_HZ: ClassVar[tuple[float, float]] = (5.0, 50.0)  # its timeouts and moves assume ~10 Hz
    DOC: ClassVar[str] = "Polls the stereo camera driver; its events and telemetry."
    CHANNELS = (
        Channel("faults", "bits", hi=0, doc="CameraDriver.FAULTS word"),
        Channel("frames", "count"),
        Channel("timeouts", "count", hi=0),
        Channel("dropouts", "count", hi=0),
    )
    EVENTS = CameraDriver.EVENTS

    def find_driver(self) -> CameraDriver | None:
        return self.ctx.res.camera

    def telemetry(self, c: CameraDriver) -> None:
        self.tlm_record({"faults": c.faults, "frames": c.frames, "timeouts": c.timeouts,
                         "dropouts": c.dropouts})
