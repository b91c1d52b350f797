"""Frames, the stereo camera model, mast kinematics and the map grid.

Conventions used everywhere in ``fsw`` and ``hil_sim`` (see docs/architecture.md, "Frames"):

* World / map frame: right-handed, metres, ``z`` up. The RECON-bot's start pose is the
  origin with its heading along ``+x`` (docs/algorithm.md §5: one robot is the origin).
* Rover pose: ``(x, y, yaw)``; yaw is counter-clockwise from ``+x``, radians. Its attitude
  (docs/algorithm.md §5.1) is ``(roll, pitch)``: pitch nose up positive, roll left side up
  positive; the body-to-world rotation is ``Rz(yaw) Ry(-pitch) Rx(roll)``
  (:func:`body_rotation`), and the body origin is the ground under the body centre at
  height ``z``.
* Camera frame: OpenCV's: ``x`` right, ``y`` down, ``z`` forward (optical axis). The left
  camera is the reference; the right camera sits ``baseline_m`` along the camera ``+x``.
* Camera pointing: ``pan`` (yaw of the optical axis relative to the rover heading, CCW
  positive) and ``tilt`` (elevation of the optical axis, negative looks down), radians.
* Mast: three joints, ``pan``, ``tilt`` and ``lift`` (prismatic height of the camera head
  above the mast base), each with limits and rates (``MastConfig``).
* Map grid: ``ny`` rows by ``nx`` columns of square cells; array index ``[iy, ix]``; cell
  ``(iy, ix)`` covers ``x0 + ix*cell .. x0 + (ix+1)*cell`` and likewise in ``y``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import overload

import numpy as np
from numpy.typing import NDArray

from fsw.framework.params import param

F64 = NDArray[np.float64]


@overload
def wrap_angle(a: float) -> float: ...
@overload
def wrap_angle(a: F64) -> F64: ...
def wrap_angle(a: float | F64) -> float | F64:
    """An angle (rad; or an array of them) folded into [-pi, pi]: ``atan2(sin a, cos a)``,
    within an ulp of an angle already in range (``(a + pi) % 2pi - pi`` is not: ``a + pi``
    rounds a small angle to the ulp of pi). Plain floats stay on ``math`` (~20x faster)."""
    if isinstance(a, np.ndarray):
        return np.arctan2(np.sin(a), np.cos(a))
    return math.atan2(math.sin(a), math.cos(a))


@dataclass(frozen=True)
class CameraConfig:
    """The stereo pair (defaults: SRR-like 640x480, 50 deg field of view, 15 cm baseline)."""

    width_px: int = param(640, lo=32, hi=4096, units="px")
    height_px: int = param(480, lo=32, hi=4096, units="px")
    hfov_deg: float = param(50.0, lo=10.0, hi=120.0, units="deg")
    baseline_m: float = param(0.15, lo=0.02, hi=1.0, units="m")
    min_range_m: float = param(0.8, lo=0.05, hi=50.0, units="m", doc="near end of the usable depth")
    max_range_m: float = param(5.0, lo=0.5, hi=100.0, units="m", doc="far end of the usable depth")
    calibration_file: str = param(
        "", doc="stereo calibration (OpenCV YAML, relative paths: to the repository root); "
                "'' = the pair is already the ideal pinhole pair above, no rectification")

    def __post_init__(self) -> None:
        if self.min_range_m >= self.max_range_m:
            raise ValueError("min_range_m must be below max_range_m")

    @property
    def focal_px(self) -> float:
        return (self.width_px / 2.0) / math.tan(math.radians(self.hfov_deg) / 2.0)

    @property
    def vfov_rad(self) -> float:
        return 2.0 * math.atan((self.height_px / 2.0) / self.focal_px)

    @property
    def K(self) -> F64:
        f = self.focal_px
        return np.array([[f, 0.0, (self.width_px - 1) / 2.0], [0.0, f, (self.height_px - 1) / 2.0], [0, 0, 1.0]])


@dataclass(frozen=True)
class MastConfig:
    """The 3-DOF mast: pan and tilt of the camera head and its lift above the mast base."""

    pan_min_deg: float = param(-170.0, lo=-180.0, hi=0.0, units="deg")
    pan_max_deg: float = param(170.0, lo=0.0, hi=180.0, units="deg")
    tilt_min_deg: float = param(-75.0, lo=-90.0, hi=0.0, units="deg")
    tilt_max_deg: float = param(30.0, lo=0.0, hi=90.0, units="deg")
    lift_min_m: float = param(0.0, lo=0.0, hi=2.0, units="m")
    lift_max_m: float = param(0.5, lo=0.0, hi=2.0, units="m")
    pan_rate_dps: float = param(30.0, lo=0.1, hi=360.0, units="deg/s")
    tilt_rate_dps: float = param(30.0, lo=0.1, hi=360.0, units="deg/s")
    lift_rate_mps: float = param(0.05, lo=0.001, hi=1.0, units="m/s")
    # Mast base in the rover body frame (x forward, y left, z up from the ground under the
    # body centre), metres.
    base_x_m: float = param(0.30, lo=-2.0, hi=2.0, units="m")
    base_y_m: float = param(0.0, lo=-2.0, hi=2.0, units="m")
    base_z_m: float = param(1.0, lo=0.1, hi=3.0, units="m")

    def clamp(self, pan: float, tilt: float, lift: float) -> tuple[float, float, float]:
        """Joint values (rad, rad, m) clamped to the limits."""
        return (
            float(np.clip(pan, math.radians(self.pan_min_deg), math.radians(self.pan_max_deg))),
            float(np.clip(tilt, math.radians(self.tilt_min_deg), math.radians(self.tilt_max_deg))),
            float(np.clip(lift, self.lift_min_m, self.lift_max_m)),
        )

    def within_limits(self, pan: float, tilt: float, lift: float, tol: float = 1e-9) -> bool:
        return self.clamp(pan, tilt, lift) == (pan, tilt, lift) or all(
            abs(a - b) <= tol for a, b in zip(self.clamp(pan, tilt, lift), (pan, tilt, lift), strict=True)
        )


@dataclass(frozen=True)
class RoverConfig:
    """SRR-like rover body: footprint, wheels and speed limits."""

    length_m: float = param(0.9, lo=0.1, hi=5.0, units="m")
    width_m: float = param(0.7, lo=0.1, hi=5.0, units="m")
    wheel_diameter_m: float = param(0.2, lo=0.02, hi=2.0, units="m")
    wheelbase_m: float = param(0.7, lo=0.1, hi=5.0, units="m", doc="front to rear axle")
    track_m: float = param(0.6, lo=0.1, hi=5.0, units="m", doc="left to right wheel centres")
    max_speed_mps: float = param(0.2, lo=0.01, hi=5.0, units="m/s")
    max_yaw_rate_dps: float = param(20.0, lo=0.1, hi=360.0, units="deg/s")


@dataclass(frozen=True)
class MapGridConfig:
    """The map plane (docs/algorithm.md §1): origin, cell size and extent; horizontal by default."""

    origin_x_m: float = param(-0.5, units="m")
    origin_y_m: float = param(-6.5, units="m")
    cell_m: float = param(0.03, lo=0.001, hi=10.0, units="m")
    nx: int = param(256, lo=2, hi=8192, units="cells")
    ny: int = param(256, lo=2, hi=8192, units="cells")


@dataclass(frozen=True)
class CameraPose:
    """Left-camera pose in the world: centre ``t`` and rotation ``R`` (camera to world)."""

    R: F64
    t: F64

    @staticmethod
    def from_pan_tilt(x: float, y: float, z: float, yaw: float, tilt: float) -> CameraPose:
        """Pose of a camera at ``(x, y, z)`` whose optical axis has world yaw and elevation."""
        return CameraPose(rotation_from_yaw_tilt(yaw, tilt), np.array([x, y, z], dtype=float))

    def world_to_camera(self, pts_w: F64) -> F64:
        """``(N, 3)`` world points to camera coordinates."""
        return (pts_w - self.t) @ self.R

    def camera_to_world(self, pts_c: F64) -> F64:
        return pts_c @ self.R.T + self.t

    def right(self, baseline_m: float) -> CameraPose:
        """The right camera of the stereo pair."""
        return CameraPose(self.R, self.t + baseline_m * self.R[:, 0])


def rotation_from_yaw_tilt(yaw: float, tilt: float) -> F64:
    """Camera-to-world rotation for an optical axis with world ``yaw`` and elevation ``tilt``.

    Columns are the camera axes in the world: right, down, forward. No roll.
    """
    cy, sy, ct, st = math.cos(yaw), math.sin(yaw), math.cos(tilt), math.sin(tilt)
    fwd = np.array([ct * cy, ct * sy, st])
    right = np.array([sy, -cy, 0.0])
    down = np.cross(fwd, right)
    return np.column_stack([right, down, fwd])


def body_rotation(yaw: float, pitch: float, roll: float) -> F64:
    """Body-to-world rotation of the rover (docs/algorithm.md §5.1): ``Rz(yaw) Ry(-pitch) Rx(roll)``.

    Yaw about world ``z`` (CCW +), then pitch about the body's left axis with the nose up
    positive, then roll about the body's forward axis with the left side up positive. Full
    rotation matrices, no small-angle approximation.
    """
    cy, sy = math.cos(yaw), math.sin(yaw)
    cp, sp = math.cos(-pitch), math.sin(-pitch)
    cr, sr = math.cos(roll), math.sin(roll)
    rz = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
    ry = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
    rx = np.array([[1.0, 0.0, 0.0], [0.0, cr, -sr], [0.0, sr, cr]])
    return rz @ ry @ rx


def camera_pose_from_rover(
    rover_xy_yaw: tuple[float, float, float],
    joints: tuple[float, float, float],
    mast: MastConfig,
    ground_z_m: float = 0.0,
    attitude: tuple[float, float] = (0.0, 0.0),
) -> CameraPose:
    """Left-camera pose from the rover pose ``(x, y, yaw)``, the mast joints ``(pan, tilt,
    lift)`` and the body attitude ``(roll, pitch)`` (docs/algorithm.md §5.1).

    The chain is world <- body (x, y, ``ground_z_m``, yaw, pitch, roll) <- mast base (its
    offset in the body frame) <- pan <- tilt <- lift <- camera. With no attitude the rover is
    level at ``ground_z_m`` (the plateau it drives on).
    """
    x, y, yaw = rover_xy_yaw
    pan, tilt, lift = joints
    roll, pitch = attitude
    if roll != 0.0 or pitch != 0.0:
        Rb = body_rotation(yaw, pitch, roll)
        t = np.array([x, y, ground_z_m]) + Rb @ np.array([mast.base_x_m, mast.base_y_m, mast.base_z_m + lift])
        return CameraPose(Rb @ rotation_from_yaw_tilt(pan, tilt), t)
    c, s = math.cos(yaw), math.sin(yaw)
    bx = x + c * mast.base_x_m - s * mast.base_y_m
    by = y + s * mast.base_x_m + c * mast.base_y_m
    return CameraPose.from_pan_tilt(bx, by, ground_z_m + mast.base_z_m + lift, yaw + pan, tilt)


def point_mast(
    rover_xy_yaw: tuple[float, float, float],
    target_xyz: tuple[float, float, float] | F64,
    mast: MastConfig,
    lift_m: float,
    ground_z_m: float = 0.0,
    attitude: tuple[float, float] = (0.0, 0.0),
) -> tuple[tuple[float, float, float], bool]:
    """Mast joints ``(pan, tilt, lift)`` that put the camera's optical axis through ``target_xyz``
    (world), for a rover at ``rover_xy_yaw`` on ground ``ground_z_m`` with the body attitude
    ``(roll, pitch)`` (level by default) and the head at ``lift_m``; and whether the mast reaches
    them. The joints are clamped to the mast's limits (pan wrapped to [-pi, pi] first);
    ``reachable`` is false when the clamp moved pan or tilt by more than 1e-6 rad (the camera
    would not look at the target)."""
    pan, tilt = mast_angles(rover_xy_yaw, target_xyz, mast, lift_m, ground_z_m, attitude)
    joints = mast.clamp(pan, tilt, lift_m)
    return joints, abs(joints[0] - pan) <= 1e-6 and abs(joints[1] - tilt) <= 1e-6


def mast_angles(
    rover_xy_yaw: tuple[float, float, float],
    target_xyz: tuple[float, float, float] | F64,
    mast: MastConfig,
    lift_m: float,
    ground_z_m: float = 0.0,
    attitude: tuple[float, float] = (0.0, 0.0),
) -> tuple[float, float]:
    """Pan (wrapped to [-pi, pi]) and tilt that put the camera's optical axis through
    ``target_xyz``, before the mast's limits (:func:`point_mast` clamps them). With a body
    attitude ``(roll, pitch)`` the direction is taken in the body's frame (the joints turn the
    head relative to the body, :func:`camera_pose_from_rover`)."""
    cam = camera_pose_from_rover(rover_xy_yaw, (0.0, 0.0, lift_m), mast, ground_z_m, attitude).t
    d = np.asarray(target_xyz, dtype=float)[:3] - cam
    roll, pitch = attitude
    if roll != 0.0 or pitch != 0.0:
        db = body_rotation(rover_xy_yaw[2], pitch, roll).T @ d
        return wrap_angle(math.atan2(db[1], db[0])), math.atan2(db[2], math.hypot(db[0], db[1]))
    dx, dy, dz = (float(v) for v in d)
    return wrap_angle(math.atan2(dy, dx) - rover_xy_yaw[2]), math.atan2(dz, math.hypot(dx, dy))


@dataclass(frozen=True)
class MapGrid:
    """Index arithmetic of the map grid (docs/algorithm.md §1)."""

    x0: float
    y0: float
    cell: float
    nx: int
    ny: int

    @staticmethod
    def from_config(cfg: MapGridConfig) -> MapGrid:
        return MapGrid(cfg.origin_x_m, cfg.origin_y_m, cfg.cell_m, cfg.nx, cfg.ny)

    @property
    def shape(self) -> tuple[int, int]:
        return (self.ny, self.nx)

    @property
    def extent(self) -> tuple[float, float, float, float]:
        """``(xmin, xmax, ymin, ymax)`` in metres (matplotlib ``imshow`` order with origin='lower')."""
        return (self.x0, self.x0 + self.nx * self.cell, self.y0, self.y0 + self.ny * self.cell)

    def cell_index(self, x: F64, y: F64) -> tuple[NDArray[np.intp], NDArray[np.intp], NDArray[np.bool_]]:
        """Row and column of each point and a mask of the points inside the grid."""
        ix = np.floor((np.asarray(x) - self.x0) / self.cell).astype(np.intp)
        iy = np.floor((np.asarray(y) - self.y0) / self.cell).astype(np.intp)
        inside = (ix >= 0) & (ix < self.nx) & (iy >= 0) & (iy < self.ny)
        return iy, ix, inside

    def cell_means(self, xyz: F64) -> tuple[NDArray[np.int32], NDArray[np.float32]]:
        """The cells that the finite points ``xyz`` (N, 3) fall in (flat index) and their mean
        height there: what one view measured, for the seam checks (§5.1)."""
        iy, ix, inside = self.cell_index(xyz[:, 0], xyz[:, 1])
        inside &= np.isfinite(xyz[:, 2])
        flat = (iy * self.nx + ix)[inside]
        cnt = np.bincount(flat, minlength=self.nx * self.ny)
        tot = np.bincount(flat, weights=xyz[inside, 2], minlength=self.nx * self.ny)
        idx = np.flatnonzero(cnt)
        return idx.astype(np.int32), (tot[idx] / cnt[idx]).astype(np.float32)

    def centers(self) -> tuple[F64, F64]:
        """``(X, Y)`` arrays of cell-centre coordinates, each of the grid's shape."""
        xs = self.x0 + (np.arange(self.nx) + 0.5) * self.cell
        ys = self.y0 + (np.arange(self.ny) + 0.5) * self.cell
        return np.meshgrid(xs, ys)


def normal_from_attitude(yaw: float, roll: float, pitch: float) -> F64:
    """The ground's upward unit normal under a body with heading ``yaw``, ``roll`` (left side
    up +) and ``pitch`` (nose up +), radians: the attitude sensor's convention
    (``hil_sim.team.cliffbot_rig``: ``sin pitch = -n . forward``, ``sin roll = n . left``)."""
    fwd = np.array([math.cos(yaw), math.sin(yaw), 0.0])
    left = np.array([-math.sin(yaw), math.cos(yaw), 0.0])
    a, b = -math.sin(pitch), math.sin(roll)
    up = math.sqrt(max(1.0 - a * a - b * b, 1e-6))
    n = a * fwd + b * left + np.array([0.0, 0.0, up])
    return n / float(np.linalg.norm(n))
