"""The device components (fsw/tasks/devices.py) on a stepped clock: the drivers' faults become
events and telemetry at the times their timeouts say (issue 11, item 5). The camera driver's
path is in test_camera.py."""

from __future__ import annotations

from collections.abc import Iterator

import can
import pytest
from task_rig import TaskRig, task_config

from fsw.comm.rover_can import RoverCan
from fsw.drivers import can_motors, mast_serial
from fsw.drivers.can_motors import CanMotorDriver
from fsw.drivers.factory import dbc_path
from fsw.drivers.mast_serial import MastSerialDriver
from fsw.drivers.resources import Resources

CFG = task_config(("can_drv", "can_motors_device"), ("mast_drv", "mast_device"), ("cam_drv", "camera_device"))


class SilentPort:
    """A serial port that accepts every write and never answers."""

    def read(self, size: int = 1) -> bytes:
        return b""

    def write(self, data: bytes) -> int:
        return len(data)

    def close(self) -> None:
        pass


@pytest.fixture
def bus(request: pytest.FixtureRequest) -> Iterator[can.BusABC]:
    b = can.Bus(interface="virtual", channel=f"test-devices-{request.node.name}")
    yield b
    b.shutdown()


def test_silent_controllers_and_mast_raise_their_faults_on_time(bus: can.BusABC) -> None:
    motors = CanMotorDriver(bus, RoverCan(dbc_path(CFG.devices)), status_timeout_s=0.5, heartbeat_timeout_s=2.5)
    rig = TaskRig(CFG, Resources(motors=motors, mast=MastSerialDriver(SilentPort(), state_timeout_s=1.0)))
    rig.run(5)
    assert rig.tlm("can_drv.faults") == 0 and rig.tlm("mast_drv.faults") == 0
    rig.run(10)  # t = 1.4 s
    assert rig.tlm("can_drv.faults") & can_motors.F_BUS_SILENT
    assert not rig.tlm("can_drv.faults") & can_motors.F_NODE_LOST
    assert rig.tlm("mast_drv.faults") == mast_serial.F_SILENT
    assert len(rig.events("can_drv.CAN_BUS_SILENT")) == 1 and len(rig.events("mast_drv.MAST_SILENT")) == 1
    rig.run(15)  # t = 2.9 s: past the heartbeat timeout
    assert rig.tlm("can_drv.faults") & can_motors.F_NODE_LOST
    assert len(rig.events("can_drv.CAN_NODE_LOST")) == len(motors.axes)
    assert rig.tlm("can_drv.nodes_online") == 0 and rig.tlm("can_drv.axes_faulted") == 0
    assert rig.task("can_drv").exceptions == 0 and rig.task("mast_drv").exceptions == 0


def test_absent_drivers_leave_their_channels_empty() -> None:
    rig = TaskRig(CFG, Resources())
    rig.run(3)
    for name in ("can_drv", "mast_drv", "cam_drv"):
        assert rig.tlm(f"{name}.faults") is None
        assert rig.task(name).exceptions == 0 and rig.task(name).activations == 3
