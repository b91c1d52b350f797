"""Both agents' cameras on the bench (docs/team.md, "Both agents sense"; docs/algorithm.md §8.1).

* The Cliff-bot's stereo pair (:data:`CLIFFBOT_CAMERA`): smaller and shorter-based than the
  RECON-bot's (320 x 240, 60 deg, 7 cm), on a short head above the body: its pose follows the
  body on the face (:func:`cliffbot_camera_pose`) with a head pan and tilt.
* What the cameras see of the team besides the Cliff-bot's box (the renderer draws that one):
  the tethers as ribbons turned to face the camera, the RECON-bot and the Anchorbots as boxes
  (:func:`team_quads`), all occluded against the terrain like every quad.
* The same shapes for the flight side's mask (``fsw.core.map.body_mask``), at their estimated
  poses (``hil_sim.team.face_scene``); the judge of what the mask keeps out is the renderer's
  own label of the pixels that see them (``StereoRenderer.render_labelled``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from fsw.core.geometry import CameraConfig, CameraPose, rotation_from_yaw_tilt
from fsw.core.map.body_mask import BodyBox, TeamGeometry, TetherLine
from hil_sim.world.cliffbot import Quad

F32 = NDArray[np.float32]
F64 = NDArray[np.float64]

CLIFFBOT_CAMERA = CameraConfig(width_px=320, height_px=240, hfov_deg=60.0, baseline_m=0.07,
                               min_range_m=0.3, max_range_m=4.0)
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
