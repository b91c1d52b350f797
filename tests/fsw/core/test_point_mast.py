"""Pointing the mast at a point (``fsw.core.geometry.point_mast``): the one function the Cliff-bot
fixer, the bench's ``aim_at``, the team run's RECON-bot fixer, the face scene and the fiducials
experiment call."""

from __future__ import annotations

import math

import numpy as np

from fsw.core.geometry import MastConfig, camera_pose_from_rover, point_mast
from hil_sim.world import load_scenario
from hil_sim.world.world import aim_at


def _formula(rover: tuple[float, float, float], target: np.ndarray, mast: MastConfig, lift: float,
             ground: float) -> tuple[tuple[float, float, float], bool]:
    """The inline arithmetic the callers had (the flight fixer's: pan wrapped before the clamp)."""
    base = camera_pose_from_rover(rover, (0.0, 0.0, lift), mast, ground_z_m=ground).t
    d = target - base
    pan = math.atan2(float(d[1]), float(d[0])) - rover[2]
    pan = math.atan2(math.sin(pan), math.cos(pan))
    tilt = math.atan2(float(d[2]), math.hypot(float(d[0]), float(d[1])))
    joints = mast.clamp(pan, tilt, lift)
    return joints, not (abs(joints[0] - pan) > 1e-6 or abs(joints[1] - tilt) > 1e-6)


def test_the_optical_axis_goes_through_a_reachable_target_and_the_joints_are_the_callers() -> None:
    mast = MastConfig()
    rng = np.random.default_rng(7)
    reachable = 0
    for _ in range(400):
        rover = (float(rng.uniform(-5, 5)), float(rng.uniform(-5, 5)), float(rng.uniform(-7, 7)))
        ground = float(rng.uniform(-1, 1))
        target = np.array([rover[0] + rng.uniform(-6, 6), rover[1] + rng.uniform(-6, 6), ground + rng.uniform(-3, 1)])
        joints, ok = point_mast(rover, target, mast, 0.3, ground_z_m=ground)
        assert (joints, ok) == _formula(rover, target, mast, 0.3, ground)  # bit for bit
        assert mast.within_limits(*joints)
        if not ok:
            continue
        reachable += 1
        cam = camera_pose_from_rover(rover, joints, mast, ground_z_m=ground)
        ray = (target - cam.t) / np.linalg.norm(target - cam.t)
        assert np.linalg.norm(np.cross(cam.R[:, 2], ray)) < 1e-9 and cam.R[:, 2] @ ray > 0
    assert 100 < reachable < 400  # both kinds were drawn


def test_a_target_behind_the_pan_limit_or_below_the_tilt_limit_is_out_of_reach() -> None:
    mast = MastConfig()  # pan +-170 deg, tilt -75 .. 30 deg
    joints, ok = point_mast((0.0, 0.0, 0.0), (-3.0, 0.01, 0.5), mast, 0.3)  # straight behind: pan ~ 180 deg
    assert not ok and joints[0] == math.radians(170.0)
    joints, ok = point_mast((0.0, 0.0, 0.0), (0.0, 0.0, -5.0), mast, 0.3)  # straight down
    assert not ok and joints[1] == math.radians(-75.0)
    # the pan is wrapped before the clamp: heading 3pi/2 (toward -y), a point toward -y is pan ~0, not -2pi
    joints, ok = point_mast((0.0, 0.0, 3 * math.pi / 2), (0.0, -2.0, 0.5), mast, 0.3)
    assert ok and abs(joints[0]) < 0.2
    _, ok = point_mast((0.0, 0.0, 0.0), (math.nan, 1.0, 0.0), mast, 0.3)
    assert not ok


def test_the_bench_aims_at_the_cliffbots_centre() -> None:
    world = load_scenario("lab", 0)
    mast = MastConfig()
    cb = world.cliffbot
    joints = aim_at(world, world.rover_start, mast)
    assert joints == point_mast(world.rover_start, (cb.x, cb.y, cb.z + 0.5 * cb.height_m), mast, 0.3,
                                world.plateau_z)[0]
    cam = camera_pose_from_rover(world.rover_start, joints, mast, world.plateau_z)
    ray = np.array([cb.x, cb.y, cb.z + 0.5 * cb.height_m]) - cam.t
    assert np.linalg.norm(np.cross(cam.R[:, 2], ray / np.linalg.norm(ray))) < 1e-9
