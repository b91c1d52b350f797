"""Rating views of a steep face on the face's own grid (docs/algorithm.md §8.2, "A model that sees
the face").

On a face of slope ``a`` the gravity grid holds a wall's height in each cell, and its prior for
unknown cells (§3.1: the known neighbours' height) puts the ground below a lip at the lip's
height: from the face, the prior predicts views into the air and none of the face. The face map
(§8.1) does not have that defect: its height is ``w``, the distance along the face normal, and an
unknown cell's prior is the fitted plane (``w = 0``). So views near a face are rated on the face
map's cells:

* :func:`face_cells` lays out the face as the rating sees it: the face map's ``(u, v)`` grid,
  continued ``prior_m`` further down the dip (below what the map has fitted, the plane is still
  the best guess of the face); per cell ``w`` (the face map's, else the gravity grid's height
  turned into ``w`` where the gravity grid knows the ground under the cell, else 0), its
  variance, its count (the face map's, else the gravity cell's: a face cell whose gravity cell
  is mapped is not new), its world point and its gravity cell (the one under its point: for a
  cell the face map knows, off the plane by its measured ``w``). Cells below the band over
  gravity cells already mapped (the floor) are left to the gravity grid.
* :func:`rate_face_station` is ``nbv.rate_station`` on those cells: P_V by the same kernel on the
  face grid (the camera in face coordinates; a camera behind the plane sees none of it), Eq 3's
  bits and the expected new cells (``nbv.cell_values``, interest and ``planned`` read from the
  gravity cell of each face cell), summed over every pointing with the world's yaw and tilt.
* :func:`face_visibility` is the P_V of one chosen view's face cells projected on the gravity
  grid (the largest over the face cells of a gravity cell), for the team's ``planned``.

The protocols keep the planner from importing the map's code (``fsw.core.map.face_map.FaceMap``
satisfies :class:`FaceLike`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage

from fsw.core.geometry import CameraConfig, CameraPose, MapGrid
from fsw.core.planning.nbv import MapLike, StationRating, cell_values, view_sums
from fsw.core.planning.visibility import F64, Terrain, VisibilityConfig, in_view, prior_elevation, terrain_from_map
from fsw.core.planning.visibility_kernel import pv_fast

MIN_W_M = 0.05  # a camera closer to the plane than this (or behind it) rates no face cell


class FrameLike(Protocol):
    """The face plane (``fsw.core.map.face_map.FaceFrame``)."""

    @property
    def origin(self) -> F64: ...

    @property
    def R(self) -> F64: ...  # noqa: N802 - the rotation's conventional name


class FaceLike(Protocol):
    """What face rating reads of a face map: its frame and its map over ``(u, v)``."""

    @property
    def frame(self) -> FrameLike: ...

    @property
    def map(self) -> MapLike: ...


@dataclass(frozen=True)
class FaceCells:
    """The face as the rating sees it (module docstring); arrays over the (padded) face grid."""

    grid: MapGrid  # over (u, v)
    origin: F64
    R: F64
    terrain: Terrain  # w heights with their sigma; unknown: the plane, the prior's sigma
    n: NDArray[np.int32]  # the count of each cell (the gravity cell's where the face map has none)
    world: F64  # (ny, nx, 3) each cell's point in the world
    gy: NDArray[np.intp]  # its gravity cell (row, column); -1 off the gravity grid or left to it
    gx: NDArray[np.intp]
    owned: NDArray[np.bool_]  # the gravity cells the face cells stand for (not rated on the gravity grid)
    below: NDArray[np.bool_]  # unknown gravity cells farther down the dip than the face cells
    floor_z: float  # their prior height: the foot of the face cells (the plane at their lowest v)

    @property
    def rated(self) -> NDArray[np.bool_]:
        return np.asarray(self.gy >= 0, bool)


def face_cells(face: FaceLike, gravity: MapLike, cfg: VisibilityConfig, prior_m: float = 2.0) -> FaceCells:
    """The face map's cells with the gravity grid's knowledge and the plane's prior (module
    docstring), the grid continued ``prior_m`` down the dip."""
    fg = face.map.grid
    pad = max(0, int(np.ceil(prior_m / fg.cell)))
    grid = MapGrid(fg.x0, fg.y0 - pad * fg.cell, fg.cell, fg.nx, fg.ny + pad)
    shape = grid.shape
    w = np.full(shape, np.nan)
    var = np.full(shape, np.inf)
    n = np.zeros(shape, np.int32)
    fz, fv, fn = np.asarray(face.map.z, float), np.asarray(face.map.var, float), np.asarray(face.map.n)
    known_f = np.isfinite(fz) & np.isfinite(fv)
    w[pad:] = np.where(known_f, fz, np.nan)
    var[pad:] = np.where(known_f, fv, np.inf)
    n[pad:] = np.where(known_f, fn, 0)
    R = np.asarray(face.frame.R, float)
    o = np.asarray(face.frame.origin, float)
    U, V = grid.centers()
    plane = np.column_stack([U.ravel(), V.ravel(), np.zeros(U.size)]) @ R.T + o
    g = gravity.grid
    iy, ix, inside = g.cell_index(plane[:, 0], plane[:, 1])
    iy, ix = np.where(inside, iy, 0), np.where(inside, ix, 0)
    gz = np.asarray(gravity.z, float)[iy, ix]
    gvar = np.asarray(gravity.var, float)[iy, ix]
    gn = np.asarray(gravity.n)[iy, ix]
    known_g = inside & np.isfinite(gz) & np.isfinite(gvar) & (gn > 0)
    nz = float(R[2, 2])
    # the gravity grid's height on the vertical through the cell's plane point, as w
    w_g = ((gz - plane[:, 2]) * nz).reshape(shape)
    fill = ~np.isfinite(w) & known_g.reshape(shape)
    w[fill] = w_g[fill]
    var[fill] = (gvar * nz * nz).reshape(shape)[fill]
    n = np.where(n > 0, n, np.where(known_g, gn, 0).reshape(shape)).astype(np.int32)
    known = np.isfinite(w)
    elev = np.where(known, w, 0.0)
    sigma = np.where(known, np.sqrt(np.maximum(np.where(known, var, 0.0), cfg.min_sigma_m**2)), cfg.prior_sigma_m)
    weight = np.where(known, 1.0, min(1.0, grid.cell / cfg.prior_corr_len_m))
    world = (np.column_stack([U.ravel(), V.ravel(), elev.ravel()]) @ R.T + o).reshape(*shape, 3)
    # the gravity cell a face cell stands for: the one under its own point. Where the face map
    # knows the cell that point lies its measured w off the plane, and on a steep face a few
    # centimetres of w are a column several cells away from the plane's foot, whose own ground
    # may lie metres up or down the face: standing for that column, the known cell would take it
    # out of the gravity rating while adding nothing itself (it is measured), and a view of the
    # known cell would record a miss on ground it never had in its field (§3.4)
    own = np.zeros(shape, bool)
    own[pad:] = known_f
    wy, wx, w_in = g.cell_index(world[..., 0].ravel(), world[..., 1].ravel())
    own_flat = own.ravel()
    iy = np.where(own_flat, np.where(w_in, wy, 0), iy)
    ix = np.where(own_flat, np.where(w_in, wx, 0), ix)
    inside = np.where(own_flat, w_in, inside)
    keep = inside.reshape(shape).copy()
    keep[:pad] &= ~known_g.reshape(shape)[:pad]  # below the band: mapped gravity ground stays there
    gy = np.where(keep, iy.reshape(shape), -1).astype(np.intp)
    gx = np.where(keep, ix.reshape(shape), -1).astype(np.intp)
    owned = np.zeros(g.shape, bool)
    owned[gy[keep], gx[keep]] = True
    # unknown gravity cells farther down the dip than the face cells: in front of the face, where
    # the gravity prior puts the ground at a lip's height; their prior is a floor at the foot of
    # the face cells
    X, Y = g.centers()
    below = ((np.column_stack([X.ravel(), Y.ravel(), _plane_z(o, R, X.ravel(), Y.ravel())]) - o) @ R[:, 1]
             ).reshape(g.shape) < grid.y0
    below &= (np.asarray(gravity.n) == 0) & ~owned
    floor_z = float((np.array([0.0, grid.y0, 0.0]) @ R.T + o)[2])
    return FaceCells(grid, o, R, Terrain(grid, elev, sigma, weight), n, world, gy, gx, owned, below, floor_z)


def gravity_with_floor(fc: FaceCells, gravity: MapLike, cfg: VisibilityConfig) -> Terrain:
    """The gravity grid's terrain as a view near the face is rated on (docs/algorithm.md §8.2,
    "The ground beyond the lip"): the cells in front of the face (``fc.below``) at the floor prior
    (:func:`floor_prior`; a prior: the unknown cells' sigma and exponent of §3.1), and every other
    unknown cell past a lip at most at the face's dip continued from its nearest known cell
    (:func:`drop_prior`, within the prior's correlation length of nothing known down the dip),
    with the prior's sigma."""
    z = np.where(fc.below, floor_prior(fc, gravity, cfg), np.asarray(gravity.z, float))
    var = np.where(fc.below, cfg.prior_sigma_m**2, np.asarray(gravity.var, float))
    terrain = terrain_from_map(z, var, gravity.grid, cfg)
    mapped = np.isfinite(np.asarray(gravity.z, float)) & np.isfinite(np.asarray(gravity.var, float))
    unknown = ~(np.isfinite(z) & np.isfinite(var))
    drop = drop_prior(fc, np.asarray(gravity.z, float), mapped, gravity.grid, cfg.prior_corr_len_m)
    elev = np.where(unknown, np.minimum(terrain.elev_m, drop), terrain.elev_m)
    # the floor prior is a prior, not ground: its factors take the unknown cells' exponent (§3.1),
    # else a ray over a metre of it multiplies a dozen factors near one half and reads as hidden
    weight = np.where(fc.below, min(1.0, gravity.grid.cell / cfg.prior_corr_len_m), terrain.weight)
    return Terrain(gravity.grid, elev, terrain.sigma_m, weight)


def floor_prior(fc: FaceCells, gravity: MapLike, cfg: VisibilityConfig) -> F64:
    """The prior height of the unknown ground in front of the face (``fc.below``): where some
    ground in front of the face is known (mapped gravity cells farther down the dip than the face
    cells, lower than the face cells' top by more than the prior's sigma: not a plateau beside
    the face), that ground continued as §3.1 continues known ground
    (:func:`visibility.prior_elevation` of those cells alone: smoothed near them, the nearest
    farther out); with none known, the foot of the face cells ``fc.floor_z``. The foot is the
    plane ``prior_m`` of dip below the face map, a guess the ground of a short face may lie metres
    above: rated at the foot, the ground a view of it maps is out of its depth of field."""
    g = gravity.grid
    z = np.asarray(gravity.z, float)
    known = np.isfinite(z) & np.isfinite(np.asarray(gravity.var, float)) & (np.asarray(gravity.n) > 0)
    X, Y = g.centers()
    front = ((np.column_stack([X.ravel(), Y.ravel(), _plane_z(fc.origin, fc.R, X.ravel(), Y.ravel())]) - fc.origin)
             @ fc.R[:, 1]).reshape(g.shape) < fc.grid.y0
    top_z = float((np.array([0.0, fc.grid.y0 + fc.grid.ny * fc.grid.cell, 0.0]) @ fc.R.T + fc.origin)[2])
    ground = known & front & (np.where(known, z, np.inf) < top_z - cfg.prior_sigma_m)
    if not ground.any():
        return np.full(g.shape, fc.floor_z)
    return prior_elevation(np.where(ground, z, np.nan), g, cfg)


def drop_prior(fc: FaceCells, z: F64, known: NDArray[np.bool_], grid: MapGrid, reach_m: float) -> F64:
    """Where the ground drops past a lip: for each unknown gravity cell with no known cell within
    ``reach_m`` down the face's dip (past the lip, not a gap between known ground), the height the
    ground reaches falling at the face's slope from its nearest known cell,
    ``z_k - tan(slope) max(d, 0)`` with ``d`` the cell's horizontal offset from that cell down the
    dip, never below the floor prior ``fc.floor_z`` nor above ``z_k``; elsewhere ``+inf`` (no
    bound; known cells: their height). The gravity prior (§3.1) puts the ground past a lip at the
    lip's height, where it in fact drops: views over the lip are rated onto ground that is not there."""
    out = np.where(known, z, np.inf)
    normal = fc.R[:, 2]
    horiz = float(np.hypot(normal[0], normal[1]))
    if not known.any() or horiz < 1e-6 or normal[2] <= 1e-6:  # no ground known, or no dip to follow
        return np.asarray(out, float)
    down = np.asarray(normal[:2], float) / horiz  # the outward normal's horizontal part points down the dip
    ahead = np.zeros(grid.shape, bool)  # a known cell within reach_m down the dip
    ny, nx = grid.shape
    for k in range(1, max(1, int(math.ceil(reach_m / grid.cell))) + 1):
        dx, dy = (int(v) for v in np.rint(k * down))
        src = known[max(dy, 0):ny + min(dy, 0), max(dx, 0):nx + min(dx, 0)]
        ahead[max(-dy, 0):ny + min(-dy, 0), max(-dx, 0):nx + min(-dx, 0)] |= src
    _, (ky, kx) = ndimage.distance_transform_edt(~known, return_indices=True)
    zk = np.where(known, z, 0.0)[ky, kx]
    d = ((np.arange(nx)[None, :] - kx) * down[0] + (np.arange(ny)[:, None] - ky) * down[1]) * grid.cell
    drop = np.minimum(zk, np.maximum(fc.floor_z, zk - horiz / float(normal[2]) * np.maximum(d, 0.0)))
    return np.asarray(np.where(~known & ~ahead, drop, out), float)


def _plane_z(o: F64, R: F64, x: F64, y: F64) -> F64:
    """The plane's height over ``(x, y)``."""
    n = R[:, 2]
    return np.asarray(o[2] - (n[0] * (x - o[0]) + n[1] * (y - o[1])) / n[2], float)


def camera_in_face(fc: FaceCells, cam_xyz: tuple[float, float, float]) -> F64:
    """The camera centre in face coordinates ``(u, v, w)``."""
    return np.asarray((np.asarray(cam_xyz, float) - fc.origin) @ fc.R, float)


def rate_face_station(fc: FaceCells, cam_xyz: tuple[float, float, float], yaws: F64, tilts: F64, n_max: int,
                      interest: F64 | None, camera: CameraConfig, cfg: VisibilityConfig,
                      planned: F64 | None = None, weight: F64 | None = None) -> StationRating:
    """Bits and expected new face cells of every pointing (world ``yaws`` x ``tilts``) from one
    camera centre (module docstring); ``interest``, ``planned`` and ``weight`` (the task's weight
    of the bits, ``nbv.cell_values``) are gravity-grid arrays."""
    q = camera_in_face(fc, cam_xyz)
    zero = np.zeros((yaws.size, tilts.size))
    if not q[2] > MIN_W_M:
        return StationRating(zero, zero.copy(), 0)
    rel_all = fc.world - np.asarray(cam_xyz, float)
    near = fc.rated & (np.einsum("ijk,ijk->ij", rel_all, rel_all) <= camera.max_range_m**2)
    pl = None if planned is None else np.where(fc.rated, np.asarray(planned, float)[fc.gy, fc.gx], 0.0)
    worth = near & (fc.n < n_max)
    if pl is not None:
        worth &= pl < 1.0
    it = None if interest is None else np.where(fc.rated, np.asarray(interest, float)[fc.gy, fc.gx], 0.0)
    if it is not None:
        worth &= it > 0
    iy, ix = np.nonzero(worth)
    if iy.size == 0:
        return StationRating(zero, zero.copy(), 0)
    pv = pv_fast(fc.terrain, (float(q[0]), float(q[1]), float(q[2])), iy, ix, cfg)
    wt = None if weight is None else np.asarray(weight, float)[fc.gy, fc.gx][iy, ix]
    bits, new = cell_values(pv, fc.n[iy, ix], n_max, None if it is None else it[iy, ix],
                            None if pl is None else pl[iy, ix], cfg.stereo_return, wt)
    keep = (bits > 1e-6) | (new > 1e-6)
    sums = view_sums(rel_all[iy, ix][keep], np.column_stack([bits[keep], new[keep]]), yaws, tilts, camera)
    return StationRating(sums[..., 0], sums[..., 1], int(iy.size))


def terrain_visibility(terrain: Terrain, pose: CameraPose, camera: CameraConfig, cfg: VisibilityConfig) -> F64:
    """P_V of every cell of ``terrain`` for one camera pose, zero outside the view (as
    ``nbv.predicted_visibility``, on a given terrain: :func:`gravity_with_floor`'s)."""
    g = terrain.grid
    X, Y = g.centers()
    pts = np.column_stack([X.ravel(), Y.ravel(), terrain.elev_m.ravel()])
    vis = in_view(pose, camera, pts).reshape(g.shape)
    out = np.zeros(g.shape)
    iy, ix = np.nonzero(vis)
    if iy.size:
        out[iy, ix] = pv_fast(terrain, (float(pose.t[0]), float(pose.t[1]), float(pose.t[2])), iy, ix, cfg)
    return out


def face_visibility(fc: FaceCells, pose: CameraPose, camera: CameraConfig, cfg: VisibilityConfig,
                    gravity_grid: MapGrid) -> F64:
    """P_V of the face cells one view sees, projected on the gravity grid (per gravity cell the
    largest of its face cells'); zero elsewhere."""
    out = np.zeros(gravity_grid.shape)
    q = camera_in_face(fc, (float(pose.t[0]), float(pose.t[1]), float(pose.t[2])))
    if not q[2] > MIN_W_M:
        return out
    iy, ix = np.nonzero(fc.rated)
    vis = in_view(pose, camera, fc.world[iy, ix])
    if not vis.any():
        return out
    iy, ix = iy[vis], ix[vis]
    pv = pv_fast(fc.terrain, (float(q[0]), float(q[1]), float(q[2])), iy, ix, cfg)
    np.maximum.at(out, (fc.gy[iy, ix], fc.gx[iy, ix]), pv)
    return out
