"""The calibration target as a scene element: a printed board held in front of the cameras.

The board is the one ``[calibration]`` of config/fsw.toml describes (ChArUco or chessboard,
``fsw.core.stereo.calibrate.CalibrationConfig``), printed on a flat plate with a white margin of
half a square, drawn by the renderer as a supersampled planar quad (``hil_sim.render``;
texels of ``1/TEXELS_PER_SQUARE`` of a square, nearest-texel, 16 rays per pixel).

:func:`target_poses` places it at ``n`` varied poses in front of the left camera: ranges
of about 0.8-1.5 m, tilted up to ~35 degrees about both board axes and turned up to ~15
degrees, its centre spread over a grid of the image so the corners of the image (where the
lens distorts most) are covered, and the whole board inside both true images. The poses
are a function of the seed only.
"""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from fsw.core.geometry import CameraPose, camera_pose_from_rover
from fsw.core.stereo.calibrate import CalibrationConfig
from fsw.settings import FswConfig
from hil_sim.camera_model import TrueCameras
from hil_sim.world.cliffbot import MARKER_ALBEDO, Quad

F32 = NDArray[np.float32]
F64 = NDArray[np.float64]
U8 = NDArray[np.uint8]

TEXELS_PER_SQUARE = 120
MARGIN_SQUARES = 0.5
IMAGE_MARGIN_PX = 12  # the board's outline stays this far inside both images


def board_texture(cfg: CalibrationConfig) -> F32:
    """Albedo of the printed board with its white margin (rows: board ``y`` down)."""
    n = TEXELS_PER_SQUARE
    m = int(round(MARGIN_SQUARES * n))
    size = (cfg.squares_x * n, cfg.squares_y * n)
    if cfg.target == "charuco":
        img = cfg.charuco_board().generateImage(size, marginSize=0, borderBits=1)
    else:
        yy, xx = np.mgrid[0:size[1], 0:size[0]]
        img = np.where(((xx // n) + (yy // n)) % 2 == 0, 0, 255).astype(np.uint8)
    img = np.pad(img, m, constant_values=255)
    black, white = MARKER_ALBEDO
    return (black + (white - black) * (img.astype(np.float32) / 255.0)).astype(np.float32)


def board_quad(cfg: CalibrationConfig, camera_pose: CameraPose, R_cb: F64, centre_c: F64,
               texture: F32 | None = None) -> Quad:
    """The board as a quad: board axes ``R_cb`` (columns x right, y down, in the camera frame)
    and centre ``centre_c`` in the left camera frame at ``camera_pose``."""
    m = MARGIN_SQUARES * cfg.square_m
    w, h = cfg.squares_x * cfg.square_m, cfg.squares_y * cfg.square_m
    origin_c = centre_c - R_cb[:, 0] * (w / 2 + m) - R_cb[:, 1] * (h / 2 + m)  # top-left of the plate
    Rw = camera_pose.R
    tex = board_texture(cfg) if texture is None else texture
    return Quad(camera_pose.t + Rw @ origin_c, Rw @ R_cb[:, 0] * (w + 2 * m), Rw @ R_cb[:, 1] * (h + 2 * m),
                tex, two_sided=False, fiducial=True)


def target_poses(cfg: CalibrationConfig, cameras: TrueCameras, n: int, seed: int) -> list[tuple[F64, F64]]:
    """``n`` board poses ``(R_cb, centre_c)`` in the left camera frame, inside both images."""
    rng = np.random.default_rng([seed, 1414])
    w, h = cameras.width_px, cameras.height_px
    K = cameras.K[0]
    bw, bh = cfg.squares_x * cfg.square_m, cfg.squares_y * cfg.square_m
    corners_b = np.array([[-bw / 2, -bh / 2, 0], [bw / 2, -bh / 2, 0], [bw / 2, bh / 2, 0], [-bw / 2, bh / 2, 0]])
    grid = [(gx, gy) for gy in (0.2, 0.5, 0.8) for gx in (0.2, 0.5, 0.8)]
    out: list[tuple[F64, F64]] = []
    tries = 0  # for the current view
    while len(out) < n:
        tries += 1
        if tries > 2000:
            raise RuntimeError("cannot place the target inside both images: is it too large?")
        gx, gy = grid[len(out) % len(grid)]
        shrink = max(0.0, 1.0 - tries / 400.0)  # creep toward the centre if it keeps falling out
        u = w * (0.5 + (gx - 0.5) * shrink) + rng.uniform(-0.04, 0.04) * w
        v = h * (0.5 + (gy - 0.5) * shrink) + rng.uniform(-0.04, 0.04) * h
        rng_m = rng.uniform(0.8, 1.5)
        ang = np.radians([rng.uniform(-35, 35), rng.uniform(-35, 35), rng.uniform(-15, 15)])
        R_cb = cv2.Rodrigues(ang.reshape(3, 1))[0]
        centre = rng_m * np.array([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], 1.0])
        pts_l = corners_b @ R_cb.T + centre
        if (pts_l[:, 2] < 0.3).any() or R_cb[2, 2] < 0.3:  # behind, too close or too oblique
            continue
        pts_r = (pts_l - np.array([cameras.baseline_m, 0, 0])) @ cameras.right_rotation
        inside = True
        for which, pts in ((0, pts_l), (1, pts_r)):
            px = cameras.project(which, pts)
            inside &= bool(((px >= IMAGE_MARGIN_PX) & (px <= [w - 1 - IMAGE_MARGIN_PX, h - 1 - IMAGE_MARGIN_PX])).all())
        if inside:
            out.append((R_cb, centre))
            tries = 0
    return out


def render_target_pairs(world: Any, fsw: FswConfig, cameras: TrueCameras, n: int, seed: int,
                        noise_sigma: float) -> list[tuple[str, U8, U8]]:
    """``n`` stereo pairs ``(name, left, right)`` of the target at :func:`target_poses`,
    seen by the cameras on the mast at the rover's start (pan 0, tilt 0, lift 0.5 m)."""
    from hil_sim.render import StereoRenderer

    pose = camera_pose_from_rover(tuple(world.rover_start), (0.0, 0.0, 0.5), fsw.mast,
                                  float(world.plateau_z))
    rend = StereoRenderer(world, fsw.camera, noise_sigma, seed, cameras=cameras)
    tex = board_texture(fsw.calibration)
    out = []
    for i, (R_cb, centre) in enumerate(target_poses(fsw.calibration, cameras, n, seed)):
        left, right = rend.render(pose, (board_quad(fsw.calibration, pose, R_cb, centre, tex),))
        out.append((f"{i:02d}", left, right))
    return out
