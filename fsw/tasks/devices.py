"""Polls the device drivers once per frame: their events become executive events, their
counters and fault words telemetry.

The drivers (resources ``motors``, ``mast``, ``camera`` made by ``fsw.drivers.factory``)
never see the executive; this task is their voice. Schedule it first in the fast group so
every other task of the frame reads fresh device state. A driver that is not configured is
simply absent: its channels stay empty.
"""

from __future__ import annotations

import math
from typing import Any, ClassVar

from fsw.drivers.camera import CameraDriver
from fsw.drivers.can_motors import CanMotorDriver
from fsw.drivers.imu_can import ImuDriver
from fsw.drivers.mast_serial import MastSerialDriver
from fsw.executive.task import Task
from fsw.executive.telemetry import Channel

DRIVERS = (("motors", CanMotorDriver), ("imu", ImuDriver), ("mast", MastSerialDriver), ("camera", CameraDriver))


class DevicesTask(Task):
    KIND: ClassVar[str] = "devices"
    DOC: ClassVar[str] = "Polls the CAN motor and attitude, serial mast and camera drivers; events and telemetry."
    CHANNELS = (
        Channel("can_faults", "bits", hi=0, doc="CanMotorDriver.FAULTS word"),
        Channel("can_rx", "frames", doc="valid frames received"),
        Channel("can_bad", "frames", hi=0, doc="frames refused (checksum, length, unknown id)"),
        Channel("can_lost", "frames", hi=0, doc="status frames lost (counter jumps)"),
        Channel("can_tx", "frames"),
        Channel("can_tx_errors", "count", hi=0),
        Channel("nodes_online", "count", lo=12, doc="motor controllers with a live heartbeat"),
        Channel("axes_faulted", "count", hi=0, doc="motor controllers reporting fault bits"),
        Channel("imu_faults", "bits", hi=0, doc="ImuDriver.FAULTS word"),
        Channel("imu_roll_deg", "deg", doc="body roll from the attitude sensor (left side up +)"),
        Channel("imu_pitch_deg", "deg", doc="body pitch from the attitude sensor (nose up +)"),
        Channel("imu_sigma_deg", "deg", doc="1-sigma of the attitude (roll and pitch RMS)"),
        Channel("imu_frames", "frames"),
        Channel("imu_bad", "frames", hi=0, doc="attitude frames refused (checksum, length)"),
        Channel("imu_lost", "frames", hi=0, doc="attitude frames lost (counter jumps)"),
        Channel("mast_faults", "bits", hi=0, doc="MastSerialDriver.FAULTS word"),
        Channel("mast_pan_deg", "deg"),
        Channel("mast_tilt_deg", "deg"),
        Channel("mast_lift_m", "m"),
        Channel("mast_crc_errors", "count", hi=0),
        Channel("mast_retransmits", "count"),
        Channel("mast_naks", "count"),
        Channel("cam_faults", "bits", hi=0, doc="CameraDriver.FAULTS word"),
        Channel("cam_frames", "count"),
        Channel("cam_timeouts", "count", hi=0),
        Channel("cam_dropouts", "count", hi=0),
    )
    EVENTS = CanMotorDriver.EVENTS + ImuDriver.EVENTS + MastSerialDriver.EVENTS + CameraDriver.EVENTS

    def setup(self) -> None:
        res = self.ctx.resources
        self.drivers: list[tuple[str, Any]] = [(k, res[k]) for k, cls in DRIVERS if isinstance(res.get(k), cls)]

    def run(self, frame: int) -> None:
        now = self.ctx.clock.now()
        for key, drv in self.drivers:
            drv.poll(now)
            for name, args in drv.drain_events():
                self.event(name, **args)
            getattr(self, f"_tlm_{key}")(drv)

    def _tlm_motors(self, m: CanMotorDriver) -> None:
        self.tlm("can_faults", m.faults)
        self.tlm("can_rx", m.rx_frames)
        self.tlm("can_bad", m.rx_bad)
        self.tlm("can_lost", m.rx_lost)
        self.tlm("can_tx", m.tx_frames)
        self.tlm("can_tx_errors", m.tx_errors)
        self.tlm("nodes_online", sum(1 for s in m.axes.values() if s.t_heartbeat is not None and not s.lost))
        self.tlm("axes_faulted", sum(1 for s in m.axes.values() if s.faults))

    def _tlm_imu(self, d: ImuDriver) -> None:
        self.tlm("imu_faults", d.faults)
        self.tlm("imu_frames", d.rx_frames)
        self.tlm("imu_bad", d.rx_bad)
        self.tlm("imu_lost", d.rx_lost)
        att = d.attitude(self.ctx.clock.now())
        if att is not None:
            self.tlm("imu_roll_deg", math.degrees(att.roll))
            self.tlm("imu_pitch_deg", math.degrees(att.pitch))
            self.tlm("imu_sigma_deg", math.degrees(math.sqrt(float(att.cov.trace()) / 2)))

    def _tlm_mast(self, m: MastSerialDriver) -> None:
        self.tlm("mast_faults", m.faults)
        if m.joints is not None:
            self.tlm("mast_pan_deg", math.degrees(m.joints[0]))
            self.tlm("mast_tilt_deg", math.degrees(m.joints[1]))
            self.tlm("mast_lift_m", m.joints[2])
        self.tlm("mast_crc_errors", m.decoder.crc_errors)
        self.tlm("mast_retransmits", m.retransmits)
        self.tlm("mast_naks", m.naks)

    def _tlm_camera(self, c: CameraDriver) -> None:
        self.tlm("cam_faults", c.faults)
        self.tlm("cam_frames", c.frames)
        self.tlm("cam_timeouts", c.timeouts)
        self.tlm("cam_dropouts", c.dropouts)
