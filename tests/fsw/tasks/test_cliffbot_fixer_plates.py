"""The RECON-bot's fixer task (fsw/tasks/fixer/task.py) views the Anchorbots' plates from
where it stands: a rover standing tilted (a wheel over the lip) aims the mast with its body
attitude, so the camera looks at each plate; a survey that resects no plate says so and which
(event NO_LANDMARKS), and the fix then rests on the rover's estimate. A turn toward a plate past
the mast's pan is made when the geofence allows it; refused, the fix is made without it."""

from __future__ import annotations

import math

import numpy as np
import pytest
from fence_ground import mission_ground
from numpy.typing import NDArray
from task_rig import TaskRig, task_config

from fsw.comm.team import fix_packets
from fsw.core.geometry import camera_pose_from_rover, point_mast
from fsw.core.localization.landmarks import anchor_marker_corners
from fsw.framework.telemetry import Channel
from fsw.settings import FswConfig
from fsw.tasks.fixer.task import LIFT_M
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

ROLL, PITCH, Z = math.radians(25.0), math.radians(-30.0), -0.1


def _axis_miss_deg(cfg, pose: tuple[float, float, float], joints, target) -> float:  # noqa: ANN001
    cam = camera_pose_from_rover(pose, joints, cfg.mast, Z, (ROLL, PITCH))
    d = np.asarray(target, float) - cam.t
    return math.degrees(math.acos(min(1.0, float(d @ cam.R[:, 2]) / float(np.linalg.norm(d)))))


def test_a_tilted_rover_aims_at_each_plate_and_reports_none_resected() -> None:
    rig = TaskRig(task_config(("cliffbot_fixer", "cliffbot_fixer")))
    cfg = rig.exe.cfg
    rig.exe.telemetry.register("mission.state", Channel("state"))
    rig.exe.telemetry.write("mission.state", "DONE", 0.0)
    pose = (2.3, -0.8, math.radians(80.0))
    rig.publish(NAV_POSE, NavPose(0.0, *pose, np.zeros((3, 3)), (0.0, 0.0, LIFT_M), roll=ROLL, pitch=PITCH, z_m=Z,
                                  att_cov=np.diag([1e-4, 1e-4, 1e-4]), attitude_valid=True))
    site = cfg.cliffbot_site
    plates = anchor_marker_corners(site.anchor_a_xyz, site.anchor_b_xyz, cfg.localization)
    moves, out = rig.tap(MOTION_REQUEST), rig.tap(RADIO_FIX_OUT)
    rig.publish(RADIO_FIX_REQUEST, fix_packets.FixRequest(1, 0, 2.6, 2.5))
    aimed = []
    for _ in range(len(plates)):
        rig.run(2)
        (req,) = [m for m in moves.drain() if m.kind == "mast"]
        aimed.append(req.joints)
        rig.publish(MOTION_STATUS, MotionStatus(req.request_id, "mast", MoveOutcome.REFUSED, "test"))
    for joints, corners in zip(aimed, plates.values(), strict=True):
        centre = corners.mean(axis=0)
        assert _axis_miss_deg(cfg, pose, joints, centre) < 0.01
        level, _ = point_mast(pose, centre, cfg.mast, LIFT_M, Z)  # as if the body stood level: tens of deg off
        assert _axis_miss_deg(cfg, pose, level, centre) > 10.0
    rig.run(2)
    (ev,) = rig.events("cliffbot_fixer.NO_LANDMARKS")
    assert "11 mast not pointed" in ev.text and "12 mast not pointed" in ev.text
    # the fix's own view is aimed next, also with the attitude; refused: NO_FIX, never a traceback
    (req,) = [m for m in moves.drain() if m.kind == "mast"]
    assert _axis_miss_deg(cfg, pose, req.joints, (2.6, 2.5, Z + 0.25)) < 0.01
    rig.publish(MOTION_STATUS, MotionStatus(req.request_id, "mast", MoveOutcome.REFUSED, "test"))
    rig.run(2)
    got = [fix_packets.decode(b) for b in out.drain()]
    assert len(got) == 1 and isinstance(got[0], fix_packets.NoFix)


def _past_a_plate() -> tuple[TaskRig, FswConfig, NDArray[np.float64], tuple[float, float, float]]:
    """A fixer after the mission, the rover standing with plate 11 about 176 deg off its heading
    (past the mast's pan): the rig, its config, the plate's centre, the pose."""
    rig = TaskRig(task_config(("cliffbot_fixer", "cliffbot_fixer")))
    cfg = rig.exe.cfg
    rig.exe.telemetry.register("mission.state", Channel("state"))
    rig.exe.telemetry.write("mission.state", "DONE", 0.0)
    site = cfg.cliffbot_site
    plates = anchor_marker_corners(site.anchor_a_xyz, site.anchor_b_xyz, cfg.localization)
    a = plates[11].mean(axis=0)
    yaw = math.atan2(a[1] + 0.8, a[0] - 2.3) - math.radians(176.0)
    return rig, cfg, a, (2.3, -0.8, yaw)


def test_with_no_plate_resected_it_turns_toward_one_beyond_the_pan_and_views_again() -> None:
    rig, cfg, a, pose = _past_a_plate()
    rig.publish(MISSION_GROUND, mission_ground(cfg))  # mapped all round: the geofence allows the turn
    assert not point_mast(pose, a, cfg.mast, LIFT_M)[1]
    rig.publish(NAV_POSE, NavPose(0.0, *pose, np.zeros((3, 3)), (0.0, 0.0, LIFT_M)))
    moves, out = rig.tap(MOTION_REQUEST), rig.tap(RADIO_FIX_OUT)
    rig.publish(RADIO_FIX_REQUEST, fix_packets.FixRequest(1, 0, 2.5, -2.0))
    rig.run(2)
    (req,) = [m for m in moves.drain() if m.kind == "mast"]  # plate 12 only
    rig.publish(MOTION_STATUS, MotionStatus(req.request_id, "mast", MoveOutcome.REFUSED, "test"))
    rig.run(2)
    assert rig.events("cliffbot_fixer.NO_LANDMARKS") and rig.events("cliffbot_fixer.TURN_TO_PLATE")
    rig.run(2)  # the geofence's check of the turn
    (turn,) = [m for m in moves.drain() if m.kind == "turn"]
    turned = (pose[0], pose[1], pose[2] + turn.angle_rad)
    assert point_mast(turned, a, cfg.mast, LIFT_M)[1] and abs(math.degrees(turn.angle_rad)) < 20.0
    rig.publish(RADIO_FIX_REQUEST, fix_packets.FixRequest(1, 0, 2.5, -2.0))  # asked again meanwhile: it waits
    rig.run(2)
    assert not out.drain()  # the request waits for the turn and the plates, no answer yet
    rig.publish(MOTION_STATUS, MotionStatus(turn.request_id, "turn", MoveOutcome.DONE))
    rig.run(2)  # the turn's last pose not in yet: the plates are viewed from the old estimate
    (req,) = [m for m in moves.drain() if m.kind == "mast"]
    rig.publish(NAV_POSE, NavPose(1.0, *turned, np.zeros((3, 3)), (0.0, 0.0, LIFT_M)))
    rig.publish(MOTION_STATUS, MotionStatus(req.request_id, "mast", MoveOutcome.REFUSED, "test"))
    rig.run(2)  # the estimate moved during that survey: viewed again, from the new standing, plate 11 first
    (req,) = [m for m in moves.drain() if m.kind == "mast"]
    assert _axis_miss_deg_level(cfg, turned, req.joints, a) < 0.01
    assert not out.drain()


def _axis_miss_deg_level(cfg, pose: tuple[float, float, float], joints, target) -> float:  # noqa: ANN001
    cam = camera_pose_from_rover(pose, joints, cfg.mast)
    d = np.asarray(target, float) - cam.t
    return math.degrees(math.acos(min(1.0, float(d @ cam.R[:, 2]) / float(np.linalg.norm(d)))))


@pytest.mark.parametrize("near_lip", [False, True])
def test_a_turn_toward_a_plate_near_a_lip_is_not_made_and_the_fix_goes_on_without_it(near_lip: bool) -> None:
    rig, cfg, a, pose = _past_a_plate()
    yaw = pose[2]
    # the map's frontier (a hidden lip) 0.16 m ahead of the footprint's front: a turn swings its corners closer
    front = (cfg.rover.wheelbase_m + cfg.rover.wheel_diameter_m) / 2
    lip = front + 0.16 if near_lip else 3.0
    c, s = math.cos(yaw), math.sin(yaw)
    rig.publish(MISSION_GROUND, mission_ground(cfg, lambda x, y: (x - pose[0]) * c + (y - pose[1]) * s > lip))
    rig.publish(NAV_POSE, NavPose(0.0, *pose, np.zeros((3, 3)), (0.0, 0.0, LIFT_M)))
    moves, out = rig.tap(MOTION_REQUEST), rig.tap(RADIO_FIX_OUT)
    rig.publish(RADIO_FIX_REQUEST, fix_packets.FixRequest(1, 0, 2.5, -2.0))
    rig.run(2)
    (req,) = [m for m in moves.drain() if m.kind == "mast"]  # plate 12 only
    rig.publish(MOTION_STATUS, MotionStatus(req.request_id, "mast", MoveOutcome.REFUSED, "test"))
    rig.run(4)
    assert rig.events("cliffbot_fixer.TURN_TO_PLATE")
    got = moves.drain()
    turns = [m for m in got if m.kind == "turn"]
    if not near_lip:
        assert len(turns) == 1 and not rig.events("cliffbot_fixer.TURN_REFUSED")
        return
    (ev,) = rig.events("cliffbot_fixer.TURN_REFUSED")
    assert "unknown ground" in ev.text and not turns  # never a move
    # the fix is made without the turn: the mast aimed at the Cliff-bot from where the rover stands
    (req,) = [m for m in got if m.kind == "mast"]
    assert _axis_miss_deg_level(cfg, pose, req.joints, (2.5, -2.0, 0.25)) < 0.01
    assert not out.drain()  # no answer yet: the fix's view is under way
