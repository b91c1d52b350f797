"""One-factor-at-a-time lockstep replays of a mission's views (docs/perception.md, "Cameras").

A lab mission's map error mixes the camera path (lenses, calibration, rectification) with
the trajectory the planner chose and the pose chain (odometry, attitude, registration); two
missions that differ in one factor diverge after a few steps, so their maps cannot say which
factor costs what. :func:`record_mission` runs a mission and keeps, for every view the
perception task merged, the pair, the flight's pose estimate and covariance and the TRUE
camera pose. :func:`replay` feeds those views to a fresh sensing pipeline (the flight's,
``fsw.core.pipeline``) with one factor changed: the calibration file, the cameras the pairs are
rendered with (re-rendered at the true pose), the flight pose replaced by the true one, or
registration off; and scores the map against the truth (``hil_sim.lab.terrain_eval``).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Generator
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from fsw.core.geometry import CameraPose
from fsw.tasks.messages import CameraFrame

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class RecordedView:
    """One merged view: the pair as the perception task got it, its pose estimate and
    covariance, and the true left-camera pose it was rendered at."""

    view_id: int
    left: NDArray[np.uint8]
    right: NDArray[np.uint8]
    pose: CameraPose
    pose_cov: F64
    true_pose: CameraPose
    ground_z_m: float = 0.0  # the frame's ground under the rover (``CameraFrame.ground_z_m``)
    nav_fix_id: int = 0  # the navigation fix its pose held (``CameraFrame.nav_fix_id``)
    body_yaw_rad: float = float("nan")  # the rover's yaw at capture (``CameraFrame.body_yaw_rad``)


def record_mission(spec: Any) -> tuple[dict[str, Any], list[RecordedView]]:
    """Run the mission ``spec`` (:class:`hil_sim.mission.run_spec.RunSpec`) and record its views."""
    from hil_sim.mission.mission_run import run_mission

    truth: dict[bytes, CameraPose] = {}
    frames: list[CameraFrame] = []

    def observe(bench: Any) -> None:
        render, rig = bench.camera.render, bench.rig
        task = bench.exe.tasks["perception"]
        merge = task.merge_view

        def recording_render() -> tuple[Any, Any, float]:
            with rig.lock:
                pose = rig.camera_pose()
            left, right, t = render()
            truth[left.tobytes()] = CameraPose(pose.R.copy(), pose.t.copy())
            return left, right, t

        def recording_merge(fr: CameraFrame) -> Generator[None, None, Any]:
            frames.append(fr)
            return (yield from merge(fr))

        bench.camera.render = recording_render
        task.merge_view = recording_merge

    summary = run_mission(spec, mode="fresh", on_bench=observe)
    views = [RecordedView(fr.view_id, fr.left, fr.right, fr.pose, np.asarray(fr.pose_cov, np.float64),
                          truth[fr.left.tobytes()], fr.ground_z_m, fr.nav_fix_id, fr.body_yaw_rad)
             for fr in frames if fr.left.tobytes() in truth]
    return summary, views


@dataclass(frozen=True)
class Factor:
    """What a replay changes: ``calibration_file`` (None: the configuration's; "": no
    rectification), ``cameras`` to re-render the pairs with at the true pose ("ideal" or
    "real"; None: the recorded pairs), ``true_pose`` (the flight gets the true pose, with
    the recorded covariance), ``registration``, ``carry`` (None: the configuration's)."""

    calibration_file: str | None = None
    cameras: str | None = None
    true_pose: bool = False
    registration: bool = True
    carry: bool | None = None


def replay(views: list[RecordedView], scenario: str, seed: int, factor: Factor,
           config: str | None = None, datum_m: float = 0.0,
           on_register: Callable[[RecordedView, Any, CameraPose], None] | None = None) -> dict[str, Any]:
    """The map quality (``hil_sim.lab.terrain_eval.map_quality``) of ``views`` merged by a fresh
    sensing pipeline (``fsw.core.pipeline``) with ``factor`` applied; ``datum_m``: the recorded
    mission's true body height at the start (its summary's ``map_quality.datum_m``), the flight
    poses' height origin. True poses put the map in the world's own heights (datum 0).
    ``on_register`` is called with each view, its ``fsw.core.registration.registration.Registration``
    and the pose merged."""
    from fsw.core.pipeline import SensingPipeline
    from fsw.settings import load_stereo_calibration
    from hil_sim.camera_model import TrueCameras
    from hil_sim.lab.terrain_eval import map_quality
    from hil_sim.mission.mission_run import RunSpec, mission_config
    from hil_sim.render import StereoRenderer
    from hil_sim.rig import load_hardware
    from hil_sim.world import load_scenario

    world = load_scenario(scenario, seed)
    spec = RunSpec(scenario=scenario, seed=seed) if config is None else RunSpec(scenario=scenario, seed=seed,
                                                                                 config=config)
    cfg = mission_config(spec, world)
    cam, reg = cfg.camera, cfg.registration
    if factor.calibration_file is not None:
        cam = dataclasses.replace(cam, calibration_file=factor.calibration_file)
    reg = dataclasses.replace(reg, enabled=factor.registration,
                              carry=reg.carry if factor.carry is None else factor.carry)
    cfg = dataclasses.replace(cfg, camera=cam, registration=reg)
    pipeline = SensingPipeline(cfg, load_stereo_calibration(cfg))
    rend = None
    if factor.cameras is not None:
        hw = load_hardware(spec.hardware)
        cams = TrueCameras.from_config(cfg.camera, dataclasses.replace(hw.camera, model=factor.cameras))
        rend = StereoRenderer(world, cfg.camera, float(world.noise_sigma), seed, cameras=cams)
    merged = []
    for v in views:
        left, right = (v.left, v.right) if rend is None else rend.render(v.true_pose)
        pose = v.true_pose if factor.true_pose else v.pose
        sv = pipeline.view(CameraFrame(v.view_id, 0.0, left, right, pose, v.pose_cov,
                                       ground_z_m=v.ground_z_m, nav_fix_id=v.nav_fix_id,
                                       body_yaw_rad=v.body_yaw_rad))
        if on_register is not None:
            on_register(v, sv.placed.registration, sv.placed.pose)
        t = sv.placed.pose.t
        merged.append(((float(t[0]), float(t[1]), float(t[2])), *sv.view_cells))
    datum = 0.0 if factor.true_pose else datum_m
    return map_quality(pipeline.map, world.truth_on_grid(pipeline.map.grid), merged, datum)


def registration_errors(views: list[RecordedView], scenario: str, seed: int,
                        config: str | None = None) -> tuple[list[dict[str, float]], dict[str, Any]]:
    """Consistency of the registration (docs/perception.md, "Attitude and registration"):
    the views merged again from their TRUE poses, so the map is the truth's frame and every
    registered pose's error is the registration's own. Per registered view: the error
    ``e = (rotation vector of R R_true^T, t - t_true)`` normalised by the registration's
    covariance without the reference's part (NEES: ``e^T C^-1 e``, chi-square with 2 dof for
    roll/pitch and 6 for all if the covariance is right), the tilt error and its sigma; and
    the replay's map quality."""
    import cv2

    rows: list[dict[str, float]] = []

    def record(v: RecordedView, reg: Any, pose: CameraPose) -> None:
        if reg.status != "registered":
            return
        rvec = cv2.Rodrigues(np.ascontiguousarray(pose.R @ v.true_pose.R.T))[0].ravel()
        e = np.concatenate([rvec, pose.t - v.true_pose.t])
        C = np.asarray(reg.cov - reg.ref_cov, np.float64)
        rp = C[:2, :2]
        # pinv: a degenerate covariance gives a figure, not a traceback
        rows.append({"nees_rp": float(e[:2] @ np.linalg.pinv(rp) @ e[:2]),
                     "nees6": float(e @ np.linalg.pinv(C) @ e),
                     "tilt_err_deg": float(np.degrees(np.hypot(e[0], e[1]))),
                     "tilt_sd_deg": float(np.degrees(np.sqrt(rp[0, 0] + rp[1, 1])))})

    q = replay(views, scenario, seed, Factor(true_pose=True), config, 0.0, on_register=record)
    return rows, q
