"""The RECON-bot's fixer task (fsw/tasks/cliffbot_fixer.py): a Cliff-bot behind the mast's pan
range is answered NO_FIX "out of the mast's reach" and the RECON-bot turns its body toward it in
place (a small turn through the motion task); one below the tilt's range is not turned to."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from task_rig import TaskRig, task_config

from fsw.comm.team import fix_packets
from fsw.framework.telemetry import Channel
from fsw.tasks.messages import (
    MOTION_REQUEST,
    MOTION_STATUS,
    NAV_POSE,
    RADIO_FIX_OUT,
    RADIO_FIX_REQUEST,
    MotionStatus,
    MoveOutcome,
    NavPose,
)


def _rig() -> TaskRig:
    cfg = task_config(("cliffbot_fixer", "cliffbot_fixer"))
    cfg = dataclasses.replace(cfg, localization=dataclasses.replace(cfg.localization, anchor_marker_ids=()))
    rig = TaskRig(cfg)
    rig.exe.telemetry.register("mission.state", Channel("state"))
    rig.exe.telemetry.write("mission.state", "DONE", 0.0)
    # the rover at the origin facing -x: a Cliff-bot at +x is 180 deg off its body
    rig.publish(NAV_POSE, NavPose(0.0, 0.0, 0.0, math.pi, np.zeros((3, 3)), (0.0, 0.0, 0.3)))
    return rig


def _ask(rig: TaskRig, seq: int, x: float, y: float) -> fix_packets.NoFix:
    out = rig.tap(RADIO_FIX_OUT)
    rig.publish(RADIO_FIX_REQUEST, fix_packets.FixRequest(seq, 0, x, y))
    rig.run(2)
    got = [fix_packets.decode(b) for b in out.drain()]
    assert len(got) == 1 and isinstance(got[0], fix_packets.NoFix)
    return got[0]


def test_out_of_the_pan_range_it_answers_and_turns_toward_the_cliffbot() -> None:
    rig = _rig()
    moves = rig.tap(MOTION_REQUEST)
    ans = _ask(rig, 1, 3.0, 0.3)  # 174 deg off the body: past the pan's 170 deg
    assert fix_packets.NO_FIX_REASONS[ans.reason] == "out of the mast's reach"
    (turn,) = [m for m in moves.drain() if m.kind == "turn"]
    pan = math.atan2(0.3, 3.0) - math.pi  # -174.3 deg
    # the least turn that leaves the pan 10 deg inside the range: small, toward the Cliff-bot
    assert math.degrees(turn.angle_rad) < 0 and 10.0 < abs(math.degrees(turn.angle_rad)) < 20.0
    assert abs(math.degrees(pan - turn.angle_rad)) <= 160.0 + 1e-6
    assert rig.events("cliffbot_fixer.TURN_TO_CLIFFBOT")
    # a request during the turn is told busy; after it the fixer is idle again
    assert fix_packets.NO_FIX_REASONS[_ask(rig, 2, 3.0, 0.3).reason] == "busy"
    rig.publish(MOTION_STATUS, MotionStatus(turn.request_id, "turn", MoveOutcome.DONE))
    rig.run(2)
    assert rig.events("cliffbot_fixer.TURNED") and rig.task("cliffbot_fixer").turn_id is None


def test_a_cliffbot_below_the_tilt_range_is_not_turned_to() -> None:
    rig = _rig()
    moves = rig.tap(MOTION_REQUEST)
    rig.task("cliffbot_fixer")._height = lambda x, y: -20.0  # its map: the ground there 20 m down
    ans = _ask(rig, 1, 1.0, 0.0)  # 20 m below, 1 m away, behind: steeper than the tilt's -75 deg
    assert fix_packets.NO_FIX_REASONS[ans.reason] == "out of the mast's reach"
    assert not [m for m in moves.drain() if m.kind == "turn"]
