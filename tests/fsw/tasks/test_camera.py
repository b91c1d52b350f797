"""The camera task (fsw/tasks/camera.py) and the devices task that polls its driver, on a
stepped clock with an in-process frame source (issue 11, item 5)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from task_rig import TaskRig, task_config

from fsw.drivers.camera import CallableSource, CameraDriver
from fsw.drivers.resources import Resources
from fsw.tasks.camera import camera_pose_covariance
from fsw.tasks.messages import CAMERA_FRAME, CAMERA_REQUEST, NAV_POSE, VIEW_FAILED, CaptureRequest, NavPose, ViewFailed

CFG = task_config(("cam_drv", "camera_device"), ("camera", "camera"))
NAV = NavPose(0.0, 1.0, 2.0, 0.3, np.diag([1e-4, 1e-4, 1e-5]), (0.2, -0.6, 0.4))


def _pair() -> tuple[np.ndarray, np.ndarray, float]:
    img = np.zeros((CFG.camera.height_px, CFG.camera.width_px), np.uint8)
    return img, img, 12.5


def test_a_capture_that_times_out_is_published_as_a_failed_view() -> None:
    """The pair never comes: after the driver's timeout the camera task frees itself and
    tells the mission (``ViewFailed``), which retries at once."""
    class Silent:  # a camera that takes requests and never answers
        def request(self, seq: int) -> None: ...
        def receive(self) -> list[Any]: return []
        def close(self) -> None: ...

    rig = TaskRig(CFG, Resources(camera=CameraDriver(Silent(), timeout_s=0.5)))
    frames, failed = rig.tap(CAMERA_FRAME), rig.tap(VIEW_FAILED)
    rig.publish(NAV_POSE, NAV)
    rig.publish(CAMERA_REQUEST, CaptureRequest(3))
    rig.run(int(0.5 / CFG.executive.frame_period_s) + 3)
    assert not frames.drain() and rig.tlm("camera.pending") == 0
    (f,) = failed.drain()
    assert f == ViewFailed(3, "camera: timeout") and rig.tlm("cam_drv.timeouts") == 1


def test_no_pose_is_a_failed_view() -> None:
    rig, frames = _rig()
    failed = rig.tap(VIEW_FAILED)
    rig.publish(CAMERA_REQUEST, CaptureRequest(2))
    rig.run(3)
    assert failed.drain() == [ViewFailed(2, "no pose estimate")]


def _rig(fn: Any = _pair, camera: bool = True) -> tuple[TaskRig, Any]:
    drv = CameraDriver(CallableSource(fn), timeout_s=0.5) if camera else None
    rig = TaskRig(CFG, Resources(camera=drv))
    return rig, rig.tap(CAMERA_FRAME)


def test_a_request_gives_one_frame_with_the_pose_and_its_covariance() -> None:
    rig, frames = _rig()
    rig.publish(NAV_POSE, NAV)
    rig.publish(CAMERA_REQUEST, CaptureRequest(4, expected_new_cells=321.0))
    rig.run(3)
    (fr,) = frames.drain()
    assert fr.view_id == 4 and fr.expected_new_cells == 321.0 and fr.time_s == 12.5
    pose, cov = camera_pose_covariance(NAV, CFG.mast, (math.radians(CFG.capture.joint_sigma_deg),) * 2
                                       + (CFG.capture.lift_sigma_m,))
    assert np.allclose(fr.pose.t, pose.t) and np.allclose(fr.pose.R, pose.R) and np.allclose(fr.pose_cov, cov)
    assert np.allclose(cov, cov.T) and np.linalg.eigvalsh(cov).min() > -1e-15
    assert rig.tlm("camera.captures") == 1 and rig.tlm("camera.pending") == 0
    assert len(rig.events("camera.CAPTURED")) == 1
    rig.run(5)
    assert not frames.drain()  # one request, one frame


def test_pose_covariance_grows_with_the_rover_pose_and_joint_sigmas() -> None:
    _, small = camera_pose_covariance(NAV, CFG.mast, (1e-3, 1e-3, 1e-3))
    _, big = camera_pose_covariance(NAV, CFG.mast, (1e-2, 1e-2, 1e-2))
    assert np.trace(big) > np.trace(small) > 0


def test_no_pose_yet_drops_the_pair_with_an_event() -> None:
    rig, frames = _rig()
    rig.publish(CAMERA_REQUEST, CaptureRequest(1))
    rig.run(3)
    assert not frames.drain() and len(rig.events("camera.NO_POSE")) == 1


def test_no_camera_driver_is_an_event_not_a_crash() -> None:
    rig, frames = _rig(camera=False)
    rig.publish(NAV_POSE, NAV)
    rig.publish(CAMERA_REQUEST, CaptureRequest(1))
    rig.run(2)
    assert not frames.drain() and len(rig.events("camera.CAMERA_MISSING")) == 1
    assert rig.task("camera").exceptions == 0


def test_a_dropout_frees_the_task_for_the_next_request() -> None:
    """The source fails once: the driver's dropout reaches telemetry and events through the
    devices task; the camera task stops waiting, and the next request gets its pair."""
    calls = iter([None, _pair()])
    rig, frames = _rig(lambda: next(calls))
    rig.publish(NAV_POSE, NAV)
    rig.publish(CAMERA_REQUEST, CaptureRequest(1))
    rig.run(3)
    assert not frames.drain() and rig.tlm("camera.pending") == 0
    assert rig.tlm("cam_drv.dropouts") == 1 and len(rig.events("cam_drv.CAMERA_DROPOUT")) == 1
    rig.publish(CAMERA_REQUEST, CaptureRequest(2))
    rig.run(3)
    assert [f.view_id for f in frames.drain()] == [2]
    assert len(rig.events("cam_drv.CAMERA_RECOVERED")) == 1 and rig.tlm("cam_drv.frames") == 1


def test_a_silent_source_times_out() -> None:
    class Silent:
        def request(self, seq: int) -> None:
            pass

        def receive(self) -> list[Any]:
            return []

        def close(self) -> None:
            pass

    rig = TaskRig(CFG, Resources(camera=CameraDriver(Silent(), timeout_s=0.5)))
    rig.publish(NAV_POSE, NAV)
    rig.publish(CAMERA_REQUEST, CaptureRequest(1))
    rig.run(3)
    assert rig.tlm("camera.pending") == 1
    rig.run(5)
    assert rig.tlm("camera.pending") == 0 and rig.tlm("cam_drv.timeouts") == 1
    assert len(rig.events("cam_drv.CAMERA_TIMEOUT")) == 1
