"""Fault backdoor: every injected fault is detected (fault flag and event) and the executive
keeps running (issue 3, item 8 and done-when 1)."""

from __future__ import annotations

import math

import can
import numpy as np
import pytest
from hil_helpers import bench

from fsw.drivers import camera as cam
from fsw.drivers import can_motors as cm
from fsw.drivers import mast_serial as ms
from hil_sim.faults import FaultSpec, load_faults


def _render() -> tuple[np.ndarray, np.ndarray, float]:
    img = np.full((24, 32), 100, np.uint8)
    return img, img, 0.0


# kind, fault args, expected event, fault bit, telemetry word, what the flight side is doing
CASES = [
    (
        "can_drop",
        {"rate": 1.0, "direction": "to_fsw", "target": "DRIVE_FL"},
        "CAN_STATUS_TIMEOUT",
        cm.F_STATUS_TIMEOUT,
        "can",
        "drive",
    ),
    ("can_drop", {"rate": 0.3, "direction": "to_fsw"}, "CAN_FRAMES_LOST", cm.F_LOST_FRAMES, "can", "idle"),
    ("can_delay", {"delay_s": 1.0, "direction": "to_fsw"}, "CAN_BUS_SILENT", cm.F_BUS_SILENT, "can", "drive"),
    ("can_corrupt", {"rate": 0.2, "direction": "to_fsw"}, "CAN_BAD_FRAME", cm.F_BAD_FRAMES, "can", "idle"),
    ("bus_off", {}, "CAN_BUS_SILENT", cm.F_BUS_SILENT, "can", "drive"),
    ("motor_fault", {"target": "DRIVE_RR", "mode": "driver"}, "MOTOR_FAULT", cm.F_MOTOR, "can", "drive"),
    ("motor_fault", {"target": "DRIVE_FL", "mode": "stall"}, "MOTOR_FAULT", cm.F_MOTOR, "can", "drive"),
    ("serial_noise", {"rate": 0.05}, "MAST_BAD_FRAME", ms.F_BAD_FRAMES, "mast", "mast"),
    ("serial_disconnect", {}, "MAST_SILENT", ms.F_SILENT, "mast", "mast"),
    ("mast_stall", {}, "MAST_CONTROLLER_FAULT", ms.F_CONTROLLER, "mast", "mast"),
    ("camera_dropout", {}, "CAMERA_TIMEOUT", cam.F_TIMEOUT, "cam", "camera"),
    ("camera_dropout", {"mode": "status"}, "CAMERA_DROPOUT", cam.F_DROPOUT, "cam", "camera"),
]


@pytest.mark.parametrize("kind,args,event,bit,word,activity", CASES, ids=[f"{c[0]}-{c[2]}" for c in CASES])
def test_fault_is_detected_without_crashing(
    kind: str, args: dict, event: str, bit: int, word: str, activity: str
) -> None:
    """Issue 3 done-when 1: a fault-injection test for each fault (flag + event, no crash)."""
    with bench(render=_render) as b:
        b.run(12)
        if activity == "drive":
            assert b.command("motion.DRIVE", distance_m=1.0, speed_mps=0.0).status.name == "OK"
            b.run(15)  # steered and rolling
        elif activity == "mast":
            assert b.command("motion.POINT_MAST", pan_deg=40.0, tilt_deg=-20.0, lift_m=0.1).status.name == "OK"
        b.faults.inject(kind, start_s=b.clock.now(), duration_s=2.0, **args)
        seen = 0
        camera = b.exe.ctx.res.camera
        for _ in range(30):
            if activity == "camera" and not camera.busy:
                camera.trigger(b.clock.now())
            b.run(1)
            seen |= int(b.tlm(f"{word}_drv.faults"))
        assert seen & bit, f"fault bit 0x{bit:X} never set in {word}_drv.faults"
        assert b.events(f".{event}"), f"no {event} event"
        assert not b.events(".EXCEPTION") and b.exe.frame == b.exe.frame  # executive alive
        if activity == "drive" and bit & cm.CRITICAL:
            assert b.events(".MOVE_ABORTED"), "a critical motor fault must abort the move"
        # after the fault: clear and move again
        b.run(10)
        b.command("motion.CLEAR_FAULTS")
        b.run(5)
        if word == "can":
            assert b.command("motion.DRIVE", distance_m=0.1, speed_mps=0.0).status.name == "OK"
            b.run_until(lambda: b.tlm("motion.state") == "IDLE", 80)
            assert not int(b.tlm("can_drv.faults")) & cm.CRITICAL


def test_bad_frames_on_the_bus_are_counted_never_raised() -> None:
    """Unknown ids, extended ids, wrong lengths, error frames: counted and evented."""
    with bench() as b:
        b.run(3)
        junk = [
            can.Message(arbitration_id=0x555, data=b"\x01"),
            can.Message(arbitration_id=0x190, data=b"\x00" * 3),
            can.Message(arbitration_id=0x1ABCDEF, data=b"", is_extended_id=True),
            can.Message(arbitration_id=0x190, is_error_frame=True),
        ]
        for m in junk:
            b.sim_bus.send(m)
        b.run(2)
        assert int(b.tlm("can_drv.bad")) == len(junk) and b.events(".CAN_BAD_FRAME")
        assert not b.events(".EXCEPTION")


def test_fault_schedule_from_config(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """Faults from scenario/bench config: [[faults]] tables, validated like any config."""
    p = tmp_path / "faults.toml"
    p.write_text('[[faults]]\nkind = "bus_off"\nstart_s = 1.0\nduration_s = 1.5\n')
    faults = load_faults(p)
    assert faults == (FaultSpec("bus_off", 1.0, 1.5),)
    with bench(faults=faults) as b:
        b.run(35)
        assert b.events(".CAN_BUS_SILENT") and b.events(".CAN_BUS_RECOVERED")
    p.write_text('[[faults]]\nkind = "bus_of"\n')
    with pytest.raises(ValueError, match="faults.*kind"):
        load_faults(p)


def test_estop_command_stops_the_rover() -> None:
    with bench() as b:
        b.run(10)
        b.command("motion.DRIVE", distance_m=1.0, speed_mps=0.0)
        b.run(20)
        assert b.command("motion.ESTOP", engage=True).status.name == "OK"
        b.run(10)
        assert max(abs(b.rig.rover.omega)) < 0.05 and b.tlm("motion.state") == "ESTOP"
        assert b.command("motion.DRIVE", distance_m=0.5, speed_mps=0.0).status.name == "EXECUTION_ERROR"
        b.command("motion.ESTOP", engage=False)
        b.run(3)
        assert b.command("motion.DRIVE", distance_m=0.2, speed_mps=0.0).status.name == "OK"
        x0 = b.rig.rover.x
        b.run_until(lambda: b.tlm("motion.state") == "IDLE", 60)
        assert b.rig.rover.x > x0 + 0.15 and not math.isnan(b.rig.rover.x)
