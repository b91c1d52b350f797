"""Both agents' cameras on the bench (docs/team.md, "Both agents sense"; docs/algorithm.md §8.1).

* The Cliff-bot's stereo pair (its flight program's ``[cliffbot_sensing]`` camera): smaller and
  shorter-based than the RECON-bot's (320 x 240, 60 deg, 7 cm), on a short head above the body:
  its pose follows the body on the face (:func:`cliffbot_camera_pose`) with a head pan and tilt.
* What the cameras see of the team besides the Cliff-bot's box (the renderer draws that one):
  the tethers as ribbons turned to face the camera, the RECON-bot and the Anchorbots as boxes
  (:func:`team_quads`), all occluded against the terrain like every quad.
* Its pairs in the lockstep team mission (:class:`CliffbotHeadCamera`): the flight camera
  driver's frame source, rendered at the Cliff-bot's TRUE pose along the head's scan.
* The same shapes for the flight side's mask (``fsw.core.map.body_mask``), at their estimated
  poses (``hil_sim.team.face_scene``); the judge of what the mask keeps out is the renderer's
  own label of the pixels that see them (``StereoRenderer.render_labelled``).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from fsw.comm import camera_frames
from fsw.comm.camera_frames import CameraReply
from fsw.core.geometry import CameraConfig, CameraPose, rotation_from_yaw_tilt
from fsw.core.map.body_mask import BodyBox, TeamGeometry, TetherLine
from fsw.core.team.cliffbot_head import head_camera_pose, head_end
from fsw.core.team.standing_plane import surface_normal
from fsw.sections import CliffbotSensingConfig
from hil_sim.team.cliffbot_rig import CliffbotRig
from hil_sim.world.cliffbot import Quad

F32 = NDArray[np.float32]
F64 = NDArray[np.float64]

HEAD_M = 0.45  # the Cliff-bot's camera above its ground, along the ground's normal
TETHER_RADIUS_M = 0.006
RECON_HALF_M = (0.45, 0.35, 0.3)  # the RECON-bot's body box (half sizes, m), centre 0.3 m up
ANCHOR_HALF_M = (0.3, 0.25, 0.2)


@dataclass(frozen=True)
class TeamPose:
    """The team's true state for one view: robots and tether polylines."""

    cliffbot: BodyBox
    recon: BodyBox
    anchors: tuple[BodyBox, BodyBox]
    tethers: tuple[F64, F64]  # (K, 3) polylines, anchor exit first

    def geometry(self, radius_m: float = TETHER_RADIUS_M) -> TeamGeometry:
        return TeamGeometry((self.cliffbot, self.recon, *self.anchors),
                            tuple(TetherLine(t, radius_m) for t in self.tethers))


def yaw_box(center: F64, yaw: float, half: tuple[float, float, float], sigma_m: float = 0.0) -> BodyBox:
    c, s = math.cos(yaw), math.sin(yaw)
    R = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return BodyBox(np.asarray(center, float), R, np.asarray(half, float), sigma_m)


def cliffbot_camera_pose(body: F64, normal: F64, yaw: float, pan: float, tilt: float,
                         up_dip_m: float = 0.0) -> CameraPose:
    """The Cliff-bot's left camera: ``HEAD_M`` along the ground normal above the body point
    ``body`` and ``up_dip_m`` up the slope (a head at the body's upper or lower end), looking
    along ``yaw`` turned by ``pan`` and tilted by ``tilt`` (radians)."""
    n = np.asarray(normal, float)
    up = np.array([0.0, 0.0, 1.0]) - n[2] * n
    up = up / max(float(np.linalg.norm(up)), 1e-9)
    t = np.asarray(body, float) + HEAD_M * n + up_dip_m * up
    return CameraPose(rotation_from_yaw_tilt(yaw + pan, tilt), t)


def _ribbon(a: F64, b: F64, radius: float, eye: F64, value: float) -> Quad | None:
    ab = b - a
    side = np.cross(ab, 0.5 * (a + b) - eye)
    ns = float(np.linalg.norm(side))
    if ns < 1e-9 or float(np.linalg.norm(ab)) < 1e-6:
        return None
    side = side / ns * radius
    tex = np.full((1, 8), value, np.float32)
    tex[0, ::2] *= 0.5  # a braid pattern along the rope
    return Quad(a - side, ab, 2 * side, np.ascontiguousarray(np.repeat(tex, 4, 0)), two_sided=True)


def _box(box: BodyBox, value: float) -> list[Quad]:
    quads = []
    h, R, c = box.half, box.R, box.center
    rng = np.random.default_rng(7)
    tex = (value * (0.7 + 0.3 * rng.random((16, 16)))).astype(np.float32)
    for axis in range(3):
        for sgn in (-1.0, 1.0):
            u, v = [k for k in range(3) if k != axis]
            n = np.zeros(3)
            n[axis] = sgn * h[axis]
            eu = np.zeros(3)
            eu[u] = 2 * h[u]
            ev = np.zeros(3)
            ev[v] = 2 * h[v]
            p0 = c + R @ (n - 0.5 * eu - 0.5 * ev)
            quads.append(Quad(p0, R @ eu, R @ ev, tex, two_sided=True))
    return quads


def team_quads(team: TeamPose, eye: F64, radius_m: float = TETHER_RADIUS_M) -> tuple[Quad, ...]:
    """Quads of the tethers (ribbons facing ``eye``), the RECON-bot and the Anchorbots (the
    Cliff-bot's box is the world's own)."""
    out: list[Quad] = []
    for line in team.tethers:
        for a, b in zip(line[:-1], line[1:], strict=True):
            q = _ribbon(a, b, radius_m, eye, 0.8)
            if q is not None:
                out.append(q)
    for box in (team.recon, *team.anchors):
        out += _box(box, 0.6)
    return tuple(out)


class CliffbotHeadCamera:
    """The Cliff-bot's stereo pair on the lockstep bench: a frame source of the flight camera
    driver (``fsw.drivers.camera``, ``sim``). Capture ``seq`` renders the world at the Cliff-bot's
    TRUE pose (``rig``: its place on the true ground, the ground's normal, its heading) from the
    head looking along the scan's ``(seq - 1) mod n``-th pan and tilt (``[cliffbot_sensing] pan_deg``,
    ``tilts_deg``: the
    head steps through its scan once per capture), with the team in the picture: the Cliff-bot's
    box (the world's), the tethers as ribbons over their true contacts, the Anchorbots, and the
    RECON-bot where ``recon`` (x, y, yaw, world) puts it."""

    def __init__(self, rig: CliffbotRig, sc: CliffbotSensingConfig, seed: int,
                 recon: Callable[[], tuple[float, float, float]] | None = None, now: Callable[[], float] | None = None
                 ) -> None:
        self.rig, self.sc, self.recon, self.now = rig, sc, recon, now
        self.camera = CameraConfig(width_px=sc.width_px, height_px=sc.height_px, hfov_deg=sc.hfov_deg,
                                   baseline_m=sc.baseline_m, min_range_m=sc.min_range_m, max_range_m=sc.max_range_m)
        self.rng = np.random.default_rng([seed, 2804])
        self._out: list[CameraReply] = []
        self.poses: list[CameraPose] = []  # every true camera pose rendered (the judge's)

    def true_pose(self, seq: int) -> CameraPose:
        rig, sc = self.rig, self.sc
        x, y = float(rig.xy[0]), float(rig.xy[1])
        n = surface_normal(rig.z, rig.grid, rig.xy, rig.ccfg.footprint_m)
        n = np.array([0.0, 0.0, 1.0]) if n is None else n
        pan = math.radians(sc.pan_deg[(seq - 1) % len(sc.pan_deg)])
        body = np.array([x, y, float(rig.world.ground_at(x, y))])
        return head_camera_pose(body, n, rig.yaw, pan, math.radians(sc.tilt_of(seq - 1)), sc.head_m,
                                head_end(pan, sc.head_end_m, sc.place_of(seq - 1)))

    def team_now(self) -> TeamPose:
        rig = self.rig
        team = rig.world.team
        assert team is not None
        attach = np.array([float(rig.xy[0]), float(rig.xy[1]),
                           float(rig.world.ground_at(float(rig.xy[0]), float(rig.xy[1]))) + rig.tcfg.attach_m])
        lines = tuple(np.vstack([rig.anchors[k], np.asarray(rig.state.paths[k].contacts, float).reshape(-1, 3), attach])
                      for k in range(2))
        rx, ry, ryaw = self.recon() if self.recon is not None else (1e3, 1e3, 0.0)
        recon = yaw_box(np.array([rx, ry, float(rig.world.ground_at(rx, ry)) + 0.3]) if self.recon is not None
                        else np.array([rx, ry, -1e3]), ryaw, RECON_HALF_M)
        ground = [float(rig.world.ground_at(float(a[0]), float(a[1]))) for a in team.anchors_xy]
        anchors = tuple(yaw_box(np.array([a[0], a[1], g + ANCHOR_HALF_M[2]]), -math.pi / 2, ANCHOR_HALF_M)
                        for a, g in zip(team.anchors_xy, ground, strict=True))
        me = yaw_box(attach, rig.yaw, (0.3, 0.25, 0.25))  # (the renderer draws the world's own box)
        return TeamPose(me, recon, (anchors[0], anchors[1]), (lines[0], lines[1]))

    def request(self, seq: int) -> None:
        from hil_sim.render import StereoRenderer

        pose = self.true_pose(seq)
        self.poses.append(pose)
        rend = StereoRenderer(self.rig.world_now(), self.camera, self.rig.world.noise_sigma,
                              seed=int(self.rng.integers(1 << 30)))
        left, right = rend.render(pose, team_quads(self.team_now(), pose.t))
        t = self.now() if self.now is not None else float("nan")
        self._out.append(CameraReply(seq, camera_frames.OK, t, np.asarray(left, np.uint8), np.asarray(right, np.uint8)))

    def receive(self) -> list[CameraReply]:
        out, self._out = self._out, []
        return out

    def close(self) -> None:
        pass
