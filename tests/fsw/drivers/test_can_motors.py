"""Back-to-back: the flight CAN motor driver against the emulated controllers (issue 3, items 5, 9).

One test class, run over python-can ``virtual`` and ``udp_hub`` (two processes' buses through the
bench's hub on 127.0.0.1, issue 31; once with the flight bus echoing its own frames, as
``udp_multicast`` does), python-can's own habit for backends. Time is a simulated clock; over
``udp_hub`` each half step waits until the hub has relayed every frame sent.
"""

from __future__ import annotations

import contextlib
import itertools
import math
import time
from collections.abc import Iterator

import can
import pytest
from hil_helpers import cfg

from fsw.comm.rover_can import AXES, RoverCan
from fsw.drivers import can_motors as cm
from hil_sim.hw.can_hub import CanHub
from hil_sim.hw.motor_controllers import MotorControllerBank, MotorControllerConfig
from hil_sim.rover_truth import FlatTerrain, RoverTruth, RoverTruthConfig

_chan = itertools.count()


class Rig:
    def __init__(self, backend: str) -> None:
        self.hub: CanHub | None = None
        if backend == "virtual":
            chan = f"b2b-{next(_chan)}"
            self.sim_bus, self.fsw_bus = can.Bus(interface="virtual", channel=chan), can.Bus(interface="virtual",
                                                                                            channel=chan)
        else:
            self.hub = CanHub().start()
            self.sim_bus = can.Bus(interface="udp_hub", channel=self.hub.channel)
            self.fsw_bus = can.Bus(interface="udp_hub", channel=self.hub.channel,
                                   receive_own_messages=backend == "udp_hub_echo")
            self.settle()
        codec = RoverCan()
        f = cfg()
        self.rover = RoverTruth(FlatTerrain(), f.rover, RoverTruthConfig(slip_noise_sigma=0.0), 0)
        self.sim = MotorControllerBank(self.sim_bus, codec, self.rover, MotorControllerConfig())
        self.drv = cm.CanMotorDriver(self.fsw_bus, codec)
        self.t = 0.0
        self.events: list[tuple[str, dict]] = []

    def step(self, n: int = 1, dt: float = 0.1, fsw_tx: bool = True, sim_on: bool = True) -> None:
        for _ in range(n):
            if fsw_tx:
                self.drv.transmit(self.t)
            self.settle()
            self.t += dt
            if sim_on:
                self.sim.receive(self.t)
                self.sim.actuate(self.t)
                self.rover.step(dt)
                self.sim.transmit(self.t)
            self.settle()
            self.drv.poll(self.t)
            self.events += self.drv.drain_events()

    def settle(self, timeout_s: float = 60.0) -> None:
        """Over ``udp_hub``: wait until the hub knows both nodes and has relayed every frame sent
        (loopback delivery is complete when the hub's ``sendto`` returns). Returns as soon as it
        has; the limit only ends a hang (a loaded machine may not run the hub's thread for seconds)."""
        if self.hub is None:
            return
        hub, sent = self.hub, lambda: self.sim_bus.frames_sent + self.fsw_bus.frames_sent
        deadline = time.monotonic() + timeout_s
        while len(hub.nodes) < 2 or hub.frames < sent():
            assert time.monotonic() < deadline, f"hub relayed {hub.frames} of {sent()} frames"
            time.sleep(0.0005)

    def names(self) -> list[str]:
        return [n for n, _ in self.events]

    def close(self) -> None:
        self.sim_bus.shutdown()
        self.fsw_bus.shutdown()
        if self.hub is not None:
            with contextlib.suppress(OSError):
                self.hub.close()


@pytest.fixture(params=["virtual", "udp_hub", "udp_hub_echo"])
def rig(request: pytest.FixtureRequest) -> Iterator[Rig]:
    r = Rig(request.param)
    r.backend = request.param  # type: ignore[attr-defined]
    yield r
    r.close()


class TestBackToBack:
    def test_heartbeats_and_status_bring_every_node_online(self, rig: Rig) -> None:
        """Issue 3 item 5: status at a fixed rate and a heartbeat per controller."""
        rig.step(3)
        assert rig.names().count("CAN_NODE_ONLINE") == len(AXES)
        assert all(s.t_status is not None and s.nmt_state is not None for s in rig.drv.axes.values())
        assert rig.drv.faults & cm.CRITICAL == 0 and rig.drv.rx_bad == 0 and rig.drv.rx_lost == 0
        assert (rig.drv.rx_echo > 0) == (rig.backend == "udp_hub_echo")  # type: ignore[attr-defined]

    def test_drive_and_steer_commands_move_the_axes(self, rig: Rig) -> None:
        for w in ("FL", "FR", "RL", "RR"):
            rig.drv.set_setpoint(f"DRIVE_{w}", 2.0)
            rig.drv.set_setpoint(f"STEER_{w}", 0.5)
        rig.step(15)
        fl = rig.drv.axes["DRIVE_FL"]
        assert fl.velocity_radps == pytest.approx(2.0, abs=0.01) and fl.enabled
        assert fl.position_rad > 1.0 and rig.rover.x > 0.1
        assert rig.drv.axes["STEER_RR"].position_rad == pytest.approx(0.5, abs=0.002)

    def test_limits_enforced_and_reported(self, rig: Rig) -> None:
        rig.drv.set_setpoint("STEER_FL", 2.5)  # beyond the 95 deg set-point limit
        rig.step(25)
        st = rig.drv.axes["STEER_FL"]
        assert st.position_rad == pytest.approx(math.radians(95.0), abs=0.002)
        assert "FaultLimit" in st.faults and rig.drv.has(cm.F_MOTOR) and "MOTOR_FAULT" in rig.names()

    def test_command_timeout_stops_and_latches_until_cleared(self, rig: Rig) -> None:
        rig.drv.set_setpoint("DRIVE_RL", 2.0)
        rig.step(10)
        rig.step(10, fsw_tx=False)  # the flight computer falls silent
        st = rig.drv.axes["DRIVE_RL"]
        assert "FaultTimeout" in st.faults and not st.enabled and abs(st.velocity_radps) < 0.01
        rig.drv.clear_faults()
        rig.step(3)
        assert not rig.drv.axes["DRIVE_RL"].faults and "MOTOR_FAULT_CLEARED" in rig.names()
        assert rig.drv.axes["DRIVE_RL"].velocity_radps > 0.1  # enabled again

    def test_estop_stops_everything_until_released_and_cleared(self, rig: Rig) -> None:
        for w in ("FL", "FR", "RL", "RR"):
            rig.drv.set_setpoint(f"DRIVE_{w}", 2.0)
        rig.step(5)
        rig.drv.estop(True, rig.t)
        rig.step(12)
        assert all("FaultEStop" in rig.drv.axes[a].faults and not rig.drv.axes[a].enabled for a in AXES)
        assert rig.rover.omega.max() < 0.01 and rig.drv.has(cm.F_ESTOP)
        rig.drv.estop(False, rig.t)
        rig.step(5)
        assert not rig.drv.fault_names() or rig.drv.fault_names() == ["bad_frames"]
        assert rig.drv.axes["DRIVE_FL"].velocity_radps > 0.5

    def test_silent_controllers_raise_bus_silent_and_recover(self, rig: Rig) -> None:
        rig.step(3)
        rig.step(8, sim_on=False)
        assert rig.drv.has(cm.F_BUS_SILENT | cm.F_STATUS_TIMEOUT) and "CAN_BUS_SILENT" in rig.names()
        rig.step(3)
        assert not rig.drv.has(cm.F_BUS_SILENT) and "CAN_BUS_RECOVERED" in rig.names()
