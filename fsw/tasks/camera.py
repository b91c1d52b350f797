"""The camera task: takes a stereo pair on request and tags it with the camera pose estimate.

On a ``CaptureRequest`` it triggers the camera driver; when the pair arrives it publishes a
``CameraFrame`` carrying the left-camera pose from the latest rover pose estimate and mast
joints (``nav.pose``), and that pose's 6x6 covariance (rotation vector, translation in the
world), propagated from the rover pose covariance and the joint uncertainty through the
mast kinematics (docs/algorithm.md §1.2: the pose term of each point's covariance).
"""

from __future__ import annotations

import math
from typing import ClassVar

import numpy as np
from numpy.typing import NDArray

from fsw.core.geometry import CameraPose, MastConfig, camera_pose_from_rover
from fsw.core.localization.localization import so3_log
from fsw.drivers.camera import CameraReply
from fsw.framework.telemetry import Channel, EventDef, Severity
from fsw.tasks.base import FlightTask
from fsw.tasks.messages import (
    CAMERA_FRAME,
    CAMERA_REQUEST,
    NAV_POSE,
    VIEW_FAILED,
    CameraFrame,
    CaptureRequest,
    NavPose,
    ViewFailed,
)


def camera_pose_covariance(
    nav: NavPose, mast: MastConfig, joint_sigma: tuple[float, float, float]
) -> tuple[CameraPose, NDArray[np.float64]]:
    """Camera pose and its 6x6 covariance from the rover pose, attitude, joints and their
    sigmas (§1.2, §5.1: the chain world <- body <- mast base <- pan <- tilt <- lift <- camera).

    The Jacobian of (rotation vector, centre) with respect to (x, y, yaw, pan, tilt, lift,
    roll, pitch, z) is taken by central differences of the mast kinematics.
    """
    q0 = np.array([nav.x, nav.y, nav.yaw, *nav.joints, nav.roll, nav.pitch, nav.z_m], dtype=np.float64)

    def chain(q: NDArray[np.float64]) -> CameraPose:
        return camera_pose_from_rover((q[0], q[1], q[2]), (q[3], q[4], q[5]), mast, q[8], (q[6], q[7]))

    pose = chain(q0)
    J = np.zeros((6, 9))
    for i, h in enumerate((1e-4, 1e-4, 1e-5, 1e-5, 1e-5, 1e-4, 1e-5, 1e-5, 1e-4)):
        cols = []
        for s in (h, -h):
            q = q0.copy()
            q[i] += s
            p = chain(q)
            cols.append(np.concatenate([so3_log(p.R @ pose.R.T), p.t]))
        J[:, i] = (cols[0] - cols[1]) / (2 * h)
    sigma = np.zeros((9, 9))
    sigma[:3, :3] = np.asarray(nav.cov, dtype=np.float64)[:3, :3]
    sigma[3:6, 3:6] = np.diag(np.square(joint_sigma))
    if nav.att_cov is not None:
        sigma[6:, 6:] = np.asarray(nav.att_cov, dtype=np.float64).reshape(3, 3)
    return pose, J @ sigma @ J.T


class CameraTask(FlightTask):
    KIND: ClassVar[str] = "camera"
    RATE_HZ: ClassVar[tuple[float, float]] = (5.0, 50.0)  # its timeouts and moves assume ~10 Hz
    REQUIRES: ClassVar[tuple[str, ...]] = ("camera_device",)
    DOC: ClassVar[str] = "Captures stereo pairs on request and tags them with the camera pose."
    CHANNELS = (
        Channel("captures", "count"),
        Channel("capture_latency_ms", "ms", doc="trigger to pair"),
        Channel("pose_sigma_m", "m", doc="camera position sigma of the last pair"),
        Channel("pending", "count"),
    )
    EVENTS = (
        EventDef("CAPTURED", Severity.ACTIVITY_LO, "pair {seq} for view {view} ({ms:.0f} ms)"),
        EventDef("NO_POSE", Severity.WARNING_HI, "no pose estimate yet; capture for view {view} dropped", throttle=3),
        EventDef("EMPTY_PAIR", Severity.WARNING_HI, "a reply without images for view {view}; dropped", throttle=3),
        EventDef(
            "CAMERA_MISSING", Severity.WARNING_HI, "no camera driver; capture for view {view} dropped", throttle=3
        ),
    )

    def setup(self) -> None:
        self.requests = self.subscribe(CAMERA_REQUEST, depth=2, policy="drop_oldest")
        self.nav_box = self.subscribe(NAV_POSE, depth=1, policy="drop_oldest")
        self.nav: NavPose | None = None
        self.waiting: tuple[int, CaptureRequest, float] | None = None
        self.captures = 0

    def run(self, frame: int) -> None:
        self.nav = self.nav_box.latest() or self.nav
        cam = self.ctx.res.camera
        now = self.ctx.clock.now()
        if self.waiting is None:
            req: CaptureRequest | None = self.requests.get()
            if req is not None:
                if cam is None:
                    self.event("CAMERA_MISSING", view=req.view_id)
                else:
                    seq = cam.trigger(now)
                    if seq is not None:
                        self.waiting = (seq, req, now)
        if self.waiting is not None and cam is not None:
            seq, req, t0 = self.waiting
            reply = cam.take()
            if reply is not None and reply.seq == seq:
                self.waiting = None
                self._publish(reply, req, now - t0)
            elif not cam.busy and reply is None:  # timed out, dropped or the link broke (evented)
                self.waiting = None
                why = ", ".join(cam.fault_names()) or "no pair"
                self.publish(VIEW_FAILED, ViewFailed(req.view_id, f"camera: {why}"))
        self.tlm("pending", 0 if self.waiting is None else 1)

    def _publish(self, reply: CameraReply, req: CaptureRequest, latency_s: float) -> None:
        if self.nav is None or reply.left is None or reply.right is None:
            self.event("NO_POSE" if self.nav is None else "EMPTY_PAIR", view=req.view_id)
            self.publish(VIEW_FAILED, ViewFailed(req.view_id, "no pose estimate" if self.nav is None else "empty pair"))
            return
        cfg = self.ctx.cfg
        js = math.radians(cfg.capture.joint_sigma_deg)
        pose, cov = camera_pose_covariance(self.nav, cfg.mast, (js, js, cfg.capture.lift_sigma_m))
        self.captures += 1
        self.publish(
            CAMERA_FRAME,
            CameraFrame(
                view_id=req.view_id,
                time_s=reply.t_capture_s,
                left=reply.left,
                right=reply.right,
                pose=pose,
                pose_cov=cov,
                expected_new_cells=req.expected_new_cells,
                ground_z_m=self.nav.z_m,
                nav_fix_id=self.nav.fix_id,
                body_yaw_rad=self.nav.yaw,
            ),
        )
        self.tlm("captures", self.captures)
        self.tlm("capture_latency_ms", latency_s * 1e3)
        self.tlm("pose_sigma_m", float(np.sqrt(np.trace(cov[3:, 3:]))))
        self.event("CAPTURED", seq=reply.seq, view=req.view_id, ms=latency_s * 1e3)
