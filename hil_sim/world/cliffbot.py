"""The Cliff-bot as the RECON-bot's cameras see it: a box body carrying ArUco markers.

The paper's relative localization (docs/algorithm.md §5) has the RECON-bot map fiducials on the
Cliff-bot and solve a PnP problem. Here the Cliff-bot is a box (``length`` along its heading,
``width``, ``height``) standing on the terrain, with four ArUco markers (OpenCV
``DICT_4X4_50``): on the front face, the left and right faces (all vertical) and on a plate
inclined 45 degrees on its top, facing forward and up. Each marker is a black square of
``marker_size_m`` inside a white quiet zone one marker cell wide.

Body frame: origin at the centre of the footprint on the ground, ``x`` forward (``yaw``),
``y`` left, ``z`` up. Marker corners are listed in OpenCV ArUco order (top-left, top-right,
bottom-right, bottom-left as seen facing the marker), in the body frame and in the world, so
``solvePnP`` truth needs no further convention. The renderer draws the body and markers as
planar quads (:class:`Quad`) with exact occlusion against the terrain.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from fsw.core.geometry import normal_from_attitude

F32 = NDArray[np.float32]
F64 = NDArray[np.float64]

ARUCO_DICT = "DICT_4X4_50"
MARKER_BITS = 4  # data bits per side; the marker is MARKER_BITS + 2 cells wide with its border
MARKER_ALBEDO = (0.06, 0.88)  # black, white
PANEL_OFFSET_M = 0.004  # marker plates stand this far proud of the body faces


@dataclass(frozen=True, eq=False)
class Quad:
    """A textured planar rectangle: ``p0 + a * eu + b * ev`` for ``a, b`` in ``[0, 1]``.

    ``texture[row, col]`` maps ``b`` to rows and ``a`` to columns (nearest texel). Seen from
    its front, ``eu`` points right and ``ev`` down; the front normal is ``ev x eu``. A
    ``fiducial`` quad is drawn supersampled (anti-aliased edges for sub-pixel corners).
    """

    p0: F64
    eu: F64
    ev: F64
    texture: F32
    two_sided: bool = False
    fiducial: bool = False

    @property
    def normal(self) -> F64:
        n = np.cross(self.ev, self.eu)
        return np.asarray(n / np.linalg.norm(n), float)

    @property
    def corners(self) -> F64:
        return np.array([self.p0, self.p0 + self.eu, self.p0 + self.eu + self.ev, self.p0 + self.ev])


@dataclass(frozen=True, eq=False)
class ArucoMarker:
    """One fiducial: its id, black-square side and corners (TL, TR, BR, BL), metres."""

    id: int
    size_m: float
    corners_body: F64   # (4, 3)
    corners_world: F64  # (4, 3)

    @property
    def center_world(self) -> F64:
        return np.asarray(self.corners_world.mean(axis=0), float)

    @property
    def normal_world(self) -> F64:
        """Unit normal pointing out of the marker's face (toward a viewer that can read it)."""
        c = self.corners_world
        n = np.cross(c[3] - c[0], c[1] - c[0])
        return np.asarray(n / np.linalg.norm(n), float)


@dataclass(frozen=True, eq=False)
class CliffbotTruth:
    """The Cliff-bot's true pose and fiducials (``(x, y, z)`` = footprint centre on its base)."""

    x: float
    y: float
    z: float
    yaw: float
    length_m: float
    width_m: float
    height_m: float
    markers: tuple[ArucoMarker, ...]
    quads: tuple[Quad, ...]
    dictionary: str = ARUCO_DICT
    roll: float = 0.0  # rad, the attitude sensor's convention (fsw.core.geometry.normal_from_attitude)
    pitch: float = 0.0  # rad, nose up +

    @property
    def R(self) -> F64:
        """Body-to-world rotation: heading ``yaw``; on tilted ground its up axis is the ground's
        normal that ``roll`` and ``pitch`` give, its forward axis the one across that normal in
        the vertical plane of the heading (so the heading read from the rotation is ``yaw``)."""
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        if self.roll == 0.0 and self.pitch == 0.0:
            return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        n = normal_from_attitude(self.yaw, self.roll, self.pitch)
        fwd = max(float(n[2]), 1e-6) * np.array([c, s, 0.0]) - (c * n[0] + s * n[1]) * np.array([0.0, 0.0, 1.0])
        fwd /= float(np.linalg.norm(fwd))
        return np.column_stack([fwd, np.cross(n, fwd), n])

    @property
    def t(self) -> F64:
        return np.array([self.x, self.y, self.z])

    def body_to_world(self, pts: F64) -> F64:
        return np.asarray(np.asarray(pts, float) @ self.R.T + self.t, float)

    def marker(self, marker_id: int) -> ArucoMarker:
        for m in self.markers:
            if m.id == marker_id:
                return m
        raise KeyError(f"the Cliff-bot carries no marker {marker_id}")

    def marker_corners_world(self) -> dict[int, F64]:
        """``{id: (4, 3) world corners}`` in ArUco corner order."""
        return {m.id: m.corners_world for m in self.markers}

    def stamp_height(self, height: F32, x0: float, y0: float, cell_m: float) -> None:
        """Raise ``height`` (in place) to the Cliff-bot's top surface (2.5D truth)."""
        ny, nx = height.shape
        half = 0.5 * math.hypot(self.length_m, self.width_m) + 0.3
        ix0 = max(0, int((self.x - half - x0) / cell_m))
        ix1 = min(nx, int((self.x + half - x0) / cell_m) + 1)
        iy0 = max(0, int((self.y - half - y0) / cell_m))
        iy1 = min(ny, int((self.y + half - y0) / cell_m) + 1)
        if ix0 >= ix1 or iy0 >= iy1:
            return
        gx, gy = np.meshgrid(x0 + (np.arange(ix0, ix1) + 0.5) * cell_m,
                             y0 + (np.arange(iy0, iy1) + 0.5) * cell_m)
        top = np.full(gx.shape, -np.inf)
        for q in self.quads:
            n = q.normal
            if abs(n[2]) < 1e-6:
                continue  # vertical faces have no footprint of their own
            # Height of the quad's plane over each cell, kept where the cell is inside it.
            z = q.p0[2] - (n[0] * (gx - q.p0[0]) + n[1] * (gy - q.p0[1])) / n[2]
            rel = np.stack([gx - q.p0[0], gy - q.p0[1], z - q.p0[2]], axis=-1)
            a = rel @ q.eu / (q.eu @ q.eu)
            b = rel @ q.ev / (q.ev @ q.ev)
            inside = (a >= 0) & (a <= 1) & (b >= 0) & (b <= 1)
            top = np.where(inside, np.maximum(top, z), top)
        block = height[iy0:iy1, ix0:ix1]
        np.maximum(block, top.astype(np.float32), out=block)


def build_cliffbot(
    x: float,
    y: float,
    z: float,
    yaw: float,
    *,
    size_m: tuple[float, float, float] = (0.6, 0.45, 0.35),
    marker_size_m: float = 0.18,
    marker_ids: tuple[int, int, int, int] = (1, 2, 3, 4),
    seed: int = 0,
    roll: float = 0.0,
    pitch: float = 0.0,
) -> CliffbotTruth:
    """A Cliff-bot whose footprint centre stands at ``(x, y, z)`` heading ``yaw`` (rad), tilted
    by ``roll`` and ``pitch`` (rad) with the ground it stands on (:attr:`CliffbotTruth.R`).

    Markers: ``marker_ids`` = (front, left, right, top plate). The body needs faces at least
    a panel (``marker_size_m * 8 / 6``) wide and high.
    """
    length, width, height = size_m
    panel = marker_size_m * (MARKER_BITS + 4) / (MARKER_BITS + 2)
    if min(width, height) < panel or length < panel:
        raise ValueError(f"Cliff-bot faces {size_m} m are too small for {marker_size_m} m markers")
    rng = np.random.default_rng(seed + 7919)
    rot = CliffbotTruth(x, y, z, yaw, length, width, height, (), (), roll=roll, pitch=pitch).R
    origin = np.array([x, y, z])

    def to_world(p: F64) -> F64:
        return np.asarray(np.asarray(p, float) @ rot.T + origin, float)

    L2, W2, H = length / 2, width / 2, height
    body: list[tuple[F64, F64, F64]] = [  # (p0, eu, ev) in body frame, front normal outward
        (np.array([L2, -W2, H]), np.array([0, width, 0.0]), np.array([0, 0, -H])),    # front
        (np.array([L2, W2, H]), np.array([-length, 0, 0.0]), np.array([0, 0, -H])),   # left
        (np.array([-L2, -W2, H]), np.array([length, 0, 0.0]), np.array([0, 0, -H])),  # right
        (np.array([-L2, W2, H]), np.array([0, -width, 0.0]), np.array([0, 0, -H])),   # back
        (np.array([-L2, W2, H]), np.array([length, 0, 0.0]), np.array([0, -width, 0.0])),  # top
    ]
    quads: list[Quad] = []
    for p0, eu, ev in body:
        raw = np.clip(0.42 + 0.08 * rng.standard_normal((48, 48)), 0.2, 0.7).astype(np.float32)
        tex = np.asarray(cv2.GaussianBlur(raw, (3, 3), 0.8), np.float32)
        quads.append(Quad(to_world(p0), eu @ rot.T, ev @ rot.T, tex))
    s45 = math.sqrt(0.5)
    centers = [  # (panel centre, right, down) in body frame; front normal = down x right
        (np.array([L2 + PANEL_OFFSET_M, 0, H / 2]), np.array([0, 1.0, 0]), np.array([0, 0, -1.0])),
        (np.array([0, W2 + PANEL_OFFSET_M, H / 2]), np.array([-1.0, 0, 0]), np.array([0, 0, -1.0])),
        (np.array([0, -W2 - PANEL_OFFSET_M, H / 2]), np.array([1.0, 0, 0]), np.array([0, 0, -1.0])),
        (np.array([-0.05, 0, H + PANEL_OFFSET_M + panel / 2 * s45]), np.array([0, 1.0, 0]),
         np.array([s45, 0, -s45])),
    ]
    markers: list[ArucoMarker] = []
    for mid, (c, right, down) in zip(marker_ids, centers, strict=True):
        tex = marker_texture(mid)
        p0 = c - right * panel / 2 - down * panel / 2
        quads.append(Quad(to_world(p0), (right * panel) @ rot.T, (down * panel) @ rot.T, tex,
                          fiducial=True))
        h = marker_size_m / 2
        corners = np.array([c - right * h - down * h, c + right * h - down * h,
                            c + right * h + down * h, c - right * h + down * h])
        markers.append(ArucoMarker(int(mid), marker_size_m, corners, to_world(corners)))
    # The plate's back and a post under it, so the plate does not float.
    plate = quads[-1]
    quads.append(Quad(plate.p0 + plate.eu, -plate.eu, plate.ev,
                      np.full((4, 4), 0.35, np.float32)))
    return CliffbotTruth(x, y, z, yaw, length, width, height, tuple(markers), tuple(quads), roll=roll, pitch=pitch)


def marker_plates(frames: list[tuple[int, F64, F64, F64]], marker_size_m: float) -> tuple[Quad, ...]:
    """Free-standing marker plates (the Anchorbots', docs/algorithm.md §5.2): each ``(id, centre,
    right, down)`` in the world, a ``marker_size_m`` black square in its white quiet zone, and the
    plate's grey back."""
    panel = marker_size_m * (MARKER_BITS + 4) / (MARKER_BITS + 2)
    quads: list[Quad] = []
    for mid, c, right, down in frames:
        r, d = np.asarray(right, float) * panel, np.asarray(down, float) * panel
        p0 = np.asarray(c, float) - r / 2 - d / 2
        quads.append(Quad(p0, r, d, marker_texture(int(mid)), fiducial=True))
        quads.append(Quad(p0 + r, -r, d, np.full((4, 4), 0.35, np.float32)))
    return tuple(quads)


def marker_texture(marker_id: int) -> F32:
    """The marker with its one-cell white quiet zone, one texel per cell, albedo in [0, 1]."""
    if not 0 <= marker_id < 50:
        raise ValueError(f"marker id {marker_id} is not in {ARUCO_DICT} (0..49)")
    dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, ARUCO_DICT))
    img = cv2.aruco.generateImageMarker(dictionary, int(marker_id), MARKER_BITS + 2)
    img = np.pad(img, 1, constant_values=255)
    black, white = MARKER_ALBEDO
    return np.where(img > 127, white, black).astype(np.float32)
