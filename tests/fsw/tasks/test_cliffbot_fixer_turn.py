"""The RECON-bot's fixer task (fsw/tasks/fixer/task.py): a Cliff-bot behind the mast's pan
range is answered NO_FIX "out of the mast's reach" and the RECON-bot turns its body toward it in
place (a small turn through the motion task) when the geofence allows it, on the mission's ground:
near a hidden lip (the map's frontier) or a mapped drop the turn is refused with an event and not
made; one below the tilt's range is not turned to."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from fence_ground import mission_ground
from task_rig import TaskRig, task_config

from fsw.comm.team import fix_packets
from fsw.framework.telemetry import Channel
from fsw.tasks.messages import (
    MISSION_GROUND,
    MOTION_REQUEST,
    MOTION_STATUS,
    NAV_POSE,
    RADIO_FIX_OUT,
    RADIO_FIX_REQUEST,
    MotionStatus,
    MoveOutcome,
    NavPose,
)
from fsw.tasks.mission_ground import check_move

X0, Y0 = 2.0, -2.0  # the rover, facing -x: a Cliff-bot at +x is 180 deg off its body
FRONT_M = 0.45  # its footprint's front from its centre (half the wheelbase and a wheel's radius)
MARGIN_M = 0.15  # [geofence] margin_m


def _rig(ground: bool = True) -> TaskRig:
    cfg = task_config(("cliffbot_fixer", "cliffbot_fixer"))
    cfg = dataclasses.replace(cfg, localization=dataclasses.replace(cfg.localization, anchor_marker_ids=()))
    assert math.isclose((cfg.rover.wheelbase_m + cfg.rover.wheel_diameter_m) / 2, FRONT_M)
    assert cfg.geofence.margin_m == MARGIN_M
    rig = TaskRig(cfg)
    rig.exe.telemetry.register("mission.state", Channel("state"))
    rig.exe.telemetry.write("mission.state", "DONE", 0.0)
    rig.publish(NAV_POSE, NavPose(0.0, X0, Y0, math.pi, np.zeros((3, 3)), (0.0, 0.0, 0.3)))
    if ground:  # the mission's ground: mapped all round
        rig.publish(MISSION_GROUND, mission_ground(cfg))
    return rig


def _ask(rig: TaskRig, seq: int, x: float, y: float) -> fix_packets.NoFix:
    out = rig.tap(RADIO_FIX_OUT)
    rig.publish(RADIO_FIX_REQUEST, fix_packets.FixRequest(seq, 0, x, y))
    rig.run(3)
    got = [fix_packets.decode(b) for b in out.drain()]
    assert len(got) == 1 and isinstance(got[0], fix_packets.NoFix)
    return got[0]


def test_out_of_the_pan_range_it_answers_and_turns_toward_the_cliffbot() -> None:
    rig = _rig()
    moves = rig.tap(MOTION_REQUEST)
    ans = _ask(rig, 1, X0 + 3.0, Y0 + 0.3)  # 174 deg off the body: past the pan's 170 deg
    assert fix_packets.NO_FIX_REASONS[ans.reason] == "out of the mast's reach"
    (turn,) = [m for m in moves.drain() if m.kind == "turn"]  # the geofence allowed it
    assert not rig.events("cliffbot_fixer.TURN_REFUSED")
    pan = math.atan2(0.3, 3.0) - math.pi  # -174.3 deg
    # the least turn that leaves the pan 10 deg inside the range: small, toward the Cliff-bot
    assert math.degrees(turn.angle_rad) < 0 and 10.0 < abs(math.degrees(turn.angle_rad)) < 20.0
    assert abs(math.degrees(pan - turn.angle_rad)) <= 160.0 + 1e-6
    assert rig.events("cliffbot_fixer.TURN_TO_CLIFFBOT")
    # a request during the turn is told busy; after it the fixer is idle again
    assert fix_packets.NO_FIX_REASONS[_ask(rig, 2, X0 + 3.0, Y0 + 0.3).reason] == "busy"
    rig.publish(MOTION_STATUS, MotionStatus(turn.request_id, "turn", MoveOutcome.DONE))
    rig.run(2)
    assert rig.events("cliffbot_fixer.TURNED") and rig.task("cliffbot_fixer").turn_id is None


def test_a_cliffbot_below_the_tilt_range_is_not_turned_to() -> None:
    rig = _rig()
    moves = rig.tap(MOTION_REQUEST)
    rig.task("cliffbot_fixer")._height = lambda x, y: -20.0  # its map: the ground there 20 m down
    ans = _ask(rig, 1, X0 + 1.0, Y0)  # 20 m below, 1 m away, behind: steeper than the tilt's -75 deg
    assert fix_packets.NO_FIX_REASONS[ans.reason] == "out of the mast's reach"
    assert not [m for m in moves.drain() if m.kind == "turn"]


def _lip_ahead(x, y):  # noqa: ANN001, ANN202 - the map's frontier (a hidden lip) 16 cm ahead of the footprint
    return x < X0 - FRONT_M - MARGIN_M - 0.01


def _drop_ahead(cfg, ground):  # noqa: ANN001, ANN202 - mapped drop cells 16 cm ahead of the footprint
    grid = ground.latest.snapshot.grid
    ix = np.arange(grid.nx)
    drop = np.zeros(grid.shape, bool)
    drop[:, grid.x0 + (ix + 0.5) * grid.cell < X0 - FRONT_M - MARGIN_M - 0.01] = True
    return dataclasses.replace(ground, latest=dataclasses.replace(ground.latest, drop=drop))


def _verdict(job):  # noqa: ANN001, ANN202 - a slack job run to its end
    try:
        while True:
            next(job)
    except StopIteration as stop:
        return stop.value


@pytest.mark.parametrize("lip", ["unmapped", "drop"])
def test_a_turn_toward_the_cliffbot_near_a_lip_is_refused_with_the_event_and_not_made(lip: str) -> None:
    rig = _rig(ground=False)
    cfg = rig.exe.cfg
    ground = mission_ground(cfg, _lip_ahead) if lip == "unmapped" else _drop_ahead(cfg, mission_ground(cfg))
    rig.publish(MISSION_GROUND, ground)
    moves = rig.tap(MOTION_REQUEST)
    # standing still there is allowed (the start keeps the margin); the turn swings the front corners closer
    nav = NavPose(0.0, X0, Y0, math.pi, np.zeros((3, 3)), (0.0, 0.0, 0.3))
    assert _verdict(check_move(cfg, ground, nav, (X0, Y0, math.pi))).allowed
    ans = _ask(rig, 1, X0 + 3.0, Y0 + 0.3)
    assert fix_packets.NO_FIX_REASONS[ans.reason] == "out of the mast's reach"
    assert rig.events("cliffbot_fixer.TURN_TO_CLIFFBOT")
    rig.run(3)
    (ev,) = rig.events("cliffbot_fixer.TURN_REFUSED")
    assert ("unknown ground" if lip == "unmapped" else "drop") in ev.text
    assert not [m for m in moves.drain() if m.kind == "turn"]  # never a move
    fixer = rig.task("cliffbot_fixer")
    assert fixer.turn_id is None and fixer.phase == "idle"
    # the next request is answered (out of reach again), not left busy
    assert fix_packets.NO_FIX_REASONS[_ask(rig, 2, X0 + 3.0, Y0 + 0.3).reason] == "out of the mast's reach"


def test_without_the_mission_ground_a_turn_is_refused() -> None:
    rig = _rig(ground=False)
    moves = rig.tap(MOTION_REQUEST)
    _ask(rig, 1, X0 + 3.0, Y0 + 0.3)
    rig.run(3)
    (ev,) = rig.events("cliffbot_fixer.TURN_REFUSED")
    assert "not known" in ev.text and not [m for m in moves.drain() if m.kind == "turn"]
