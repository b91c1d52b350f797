"""Axis COMMANDs on change and on refresh (issue 15, a lean foreground), against the emulated
controllers on a stepped clock: a changed set-point goes out in the frame it changes, an
unchanged one at least every ``can_command_refresh_s``, so the controllers' command timeout
never trips; each axis keeps its own alive counter, so no controller sees a counter jump."""

from __future__ import annotations

import itertools
from collections import defaultdict

import can
import pytest
from hil_helpers import cfg

from fsw.comm.rover_can import AXES, AxisCommand, RoverCan
from fsw.drivers import can_motors as cm
from hil_sim.hw.motor_controllers import MotorControllerBank, MotorControllerConfig
from hil_sim.rover_truth import FlatTerrain, RoverTruth, RoverTruthConfig

_chan = itertools.count()
CODEC = RoverCan()
FRAME_S = 0.1


class Rig:
    """Flight driver and controller bank on one virtual bus; the bank logs every COMMAND."""

    def __init__(self, refresh_s: float) -> None:
        kw = {"interface": "virtual", "channel": f"refresh-{next(_chan)}"}
        self.sim_bus, self.fsw_bus = can.Bus(**kw), can.Bus(**kw)
        f = cfg()
        self.rover = RoverTruth(FlatTerrain(), f.rover, RoverTruthConfig(slip_noise_sigma=0.0), 0)
        self.hw = MotorControllerConfig()
        self.sim = MotorControllerBank(self.sim_bus, CODEC, self.rover, self.hw)
        self.sim.tap = self._tap
        self.drv = cm.CanMotorDriver(self.fsw_bus, CODEC, command_refresh_s=refresh_s)
        self.t = 0.0
        self.frame = 0
        self.cmds: dict[str, list[tuple[int, AxisCommand]]] = defaultdict(list)  # axis -> (frame, command)

    def _tap(self, msg: can.Message) -> None:
        d = CODEC.decode(msg.arbitration_id, bytes(msg.data))
        if isinstance(d, AxisCommand):
            self.cmds[d.axis].append((self.frame, d))

    def step(self, n: int = 1) -> None:
        for _ in range(n):
            self.drv.transmit(self.t)
            self.t += FRAME_S
            self.sim.receive(self.t)
            self.sim.actuate(self.t)
            self.rover.step(FRAME_S)
            self.sim.transmit(self.t)
            self.drv.poll(self.t)
            self.drv.drain_events()
            self.frame += 1

    def sent_in(self, frame: int) -> dict[str, AxisCommand]:
        return {a: c for a, log in self.cmds.items() for k, c in log if k == frame}

    def close(self) -> None:
        self.sim_bus.shutdown()
        self.fsw_bus.shutdown()


@pytest.fixture
def rig() -> Rig:
    r = Rig(cfg().devices.can_command_refresh_s)
    yield r
    r.close()


def test_configured_refresh_is_at_most_half_the_controllers_timeout() -> None:
    assert 0.0 < cfg().devices.can_command_refresh_s <= MotorControllerConfig().command_timeout_s / 2


def test_held_setpoints_are_refreshed_before_the_command_timeout(rig: Rig) -> None:
    for w in ("FL", "FR", "RL", "RR"):
        rig.drv.set_setpoint(f"DRIVE_{w}", 1.5)
        rig.drv.set_setpoint(f"STEER_{w}", 0.2)
    rig.step(80)  # 8 s of unchanged set-points
    refresh = rig.drv.command_refresh_s
    for axis in AXES:
        frames = [k for k, _ in rig.cmds[axis]]
        gaps = [b - a for a, b in itertools.pairwise(frames)]
        assert max(gaps) * FRAME_S <= refresh + 1e-9 < rig.hw.command_timeout_s
        assert len(frames) < 80  # refreshed, not re-sent every frame
    assert not any("FaultTimeout" in s.faults for s in rig.drv.axes.values())
    assert rig.drv.axes["DRIVE_FL"].enabled and rig.drv.axes["DRIVE_FL"].velocity_radps == pytest.approx(1.5, abs=0.01)
    assert rig.sim.rx_e2e_seq == 0  # per-axis alive counters: +1 a frame of each id, never a jump


def test_a_changed_setpoint_goes_out_in_the_same_frame(rig: Rig) -> None:
    rig.drv.set_setpoint("DRIVE_FL", 1.0)
    rig.step(5)
    for value in (1.25, 1.5, -0.5):
        rig.drv.set_setpoint("DRIVE_FL", value)
        frame = rig.frame
        rig.step(1)
        sent = rig.sent_in(frame)
        assert sent["DRIVE_FL"].setpoint == pytest.approx(value, abs=1e-3) and sent["DRIVE_FL"].enable
    rig.drv.set_setpoint("DRIVE_FL", None)  # disable: a change too
    frame = rig.frame
    rig.step(1)
    assert not rig.sent_in(frame)["DRIVE_FL"].enable
    assert rig.sim.rx_e2e_seq == 0


def test_unchanged_axes_stay_quiet_between_refreshes(rig: Rig) -> None:
    rig.step(3)  # every axis went out in frame 0 and was refreshed in frame 2 (0.2 s)
    assert set(rig.sent_in(2)) == set(AXES) and not rig.sent_in(1)
    rig.drv.set_setpoint("STEER_RR", 0.3)
    rig.step(1)  # frame 3: only the axis that changed
    assert set(rig.sent_in(3)) == {"STEER_RR"}


def test_clear_faults_goes_to_every_axis_at_once(rig: Rig) -> None:
    rig.step(4)
    rig.drv.clear_faults()
    frame = rig.frame
    rig.step(1)
    sent = rig.sent_in(frame)
    assert set(sent) == set(AXES) and all(c.clear_faults for c in sent.values())


def test_estop_change_goes_out_at_once_disabled(rig: Rig) -> None:
    for w in ("FL", "FR", "RL", "RR"):
        rig.drv.set_setpoint(f"DRIVE_{w}", 1.0)
    rig.step(4)
    rig.drv.estop(True, rig.t)
    frame = rig.frame
    rig.step(1)
    sent = rig.sent_in(frame)
    assert all(not sent[f"DRIVE_{w}"].enable for w in ("FL", "FR", "RL", "RR"))


class _FlakyBus:
    """Records sends; fails the sends of one frame."""

    def __init__(self) -> None:
        self.fail = False
        self.sent: list[int] = []

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        if self.fail:
            raise can.CanOperationError("bus full")
        self.sent.append(msg.arbitration_id)

    def recv(self, timeout: float | None = None) -> None:
        return None


def test_a_failed_send_is_retried_next_frame() -> None:
    bus = _FlakyBus()
    drv = cm.CanMotorDriver(bus, CODEC, command_refresh_s=0.2)  # type: ignore[arg-type]
    drv.transmit(0.0)
    bus.sent.clear()
    drv.set_setpoint("DRIVE_FL", 1.0)
    bus.fail = True
    drv.transmit(0.1)
    assert drv.tx_errors > 0
    bus.fail = False
    drv.transmit(0.15)  # before the refresh is due: only the command that failed goes again
    assert bus.sent == [CODEC.frame_id("DRIVE_FL_CMD")]


def test_zero_refresh_sends_every_axis_every_frame() -> None:
    bus = _FlakyBus()
    drv = cm.CanMotorDriver(bus, CODEC, command_refresh_s=0.0)  # type: ignore[arg-type]
    for k in range(3):
        bus.sent.clear()
        drv.transmit(k * FRAME_S)
        assert sum(1 for fid in bus.sent if fid != CODEC.frame_id("FSW_HEARTBEAT")) == len(AXES)
