"""The lips the map already knows, and the points of a new view that land past them
(docs/algorithm.md §4, "Choice: the lip guard"; docs/perception.md "Occluding lips").

A view guards its points against its own lips (``fsw.core.stereo.occlusion.LipGuard``),
but along a stretch of edge where it sees no ground behind the drop it finds no lip there, and a
view merged with a poor heading then lays the plateau's height over the hidden face. The views
merged before it may have found that lip: the map keeps, per cell, the best-placed lip its views
found (their counted lips, placed with their registered pose): the lip's point, the
horizontal way to its drop side and the lip's own horizontal variance (the larger eigenvalue of
the ``xy`` block of its view's pose part at the lip; :meth:`KnownLips.add`).

A point of a new view is **withheld** (:meth:`PastLips.clear`) when it lies within ``k``
sigma of the nearest known lip (the point's horizontal 1-sigma from the view's common, pose,
covariance and the lip's own, added), on the lip's drop side, and no more than ``min_drop_m``
below the lip's height: a point the view's pose error may have carried over the edge from the
plateau, which it cannot be told from. A point past a lip and lower than that is ground below
the lip, whatever its horizontal error, and is kept; a point on the plateau side of a lip is in
a plateau cell and is kept.

A view from below the lip (the Cliff-bot's, on the face) sees the face under it, and the gravity
grid's cell that straddles the lip holds two heights: the lip's and the face's under it. A point
more than ``min_drop_m`` below the nearest known lip is kept out of the gravity grid
(:meth:`PastLips.under`, :meth:`PastLips.gravity_parts`; the face map, where there is one, takes
it) when it lies in the lip's own cell, or on the lip's plateau side within ``k`` sigma of it (the
point's whole horizontal covariance, stereo and pose, and the lip's own): the face below the lip,
carried behind it by its error (seen from below at grazing incidence, a point's depth error runs
into the face). So the lip's cell keeps the lip's height and the plateau behind it the plateau's.
"""

from __future__ import annotations

import base64
import zlib
from collections.abc import Mapping
from typing import TypedDict

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage

from fsw.core.geometry import MapGrid

F64 = NDArray[np.float64]
B = NDArray[np.bool_]
ViewPart = tuple[F64, F64, F64 | None]  # world xyz, total covariance, the view's common (pose) covariance


class KnownLipsState(TypedDict):
    """The lips for a checkpoint: the lip cells' flat indices (int32) and per cell the point,
    the way and the variance (six float64), each zlib-compressed and base64-encoded."""

    cells: str
    lips: str


def horizontal_variance(cov: F64) -> F64:
    """The larger eigenvalue of the ``xy`` block of each covariance (N, 3, 3): the horizontal
    variance along the worst direction."""
    a, b, d = cov[:, 0, 0], cov[:, 0, 1], cov[:, 1, 1]
    return np.asarray(0.5 * (a + d) + np.sqrt(0.25 * (a - d) ** 2 + b * b))


def largest_variance(cov: F64) -> F64:
    """The largest eigenvalue of each covariance (N, 3, 3): the variance along the worst direction."""
    if cov.shape[0] == 0:
        return np.zeros(0)
    return np.asarray(np.linalg.eigvalsh(cov)[:, -1])


def on_sight_line(eye: F64 | None, xyz_w: F64, lip: F64, toward: F64, reach2: F64) -> B:
    """Whether each lip (``lip``, its near point, and ``toward``, the unit horizontal way to its
    drop side; one per point) can hide its point (``xyz_w``, (N, 3)) from the camera ``eye``, or
    be the edge the point was carried over along its sight line, within ``sqrt(reach2)``: the
    lip lies within that of the segment from the camera to the point (the point included), or the
    segment crosses the lip's edge (the vertical plane through the lip across its drop way)
    between the camera and the point lower than that above the lip (the lip stands in the way).
    A sight line that passes the lip higher, or never crosses its edge (a camera over or beyond
    the lip looking down past it), is not hidden by it (docs/algorithm.md §4, "Choice: the lip
    guard"). Without the camera (None): every lip (True)."""
    if eye is None:
        return np.ones(xyz_w.shape[0], bool)
    d = xyz_w - eye
    to_lip = lip - eye
    n2 = np.einsum("ij,ij->i", d, d)
    with np.errstate(invalid="ignore", divide="ignore"):
        t = np.nan_to_num(np.clip(np.einsum("ij,ij->i", to_lip, d) / n2, 0.0, 1.0))
        off = to_lip - t[:, None] * d
        close = np.einsum("ij,ij->i", off, off) <= reach2
        # where the sight line crosses the lip's edge: (eye + s d - lip) . toward = 0, horizontally
        across = np.einsum("ij,ij->i", d[:, :2], toward)
        s = np.einsum("ij,ij->i", to_lip[:, :2], toward) / across
        over = eye[2] + s * d[:, 2] - lip[:, 2]  # the sight line's height over the lip there
        under = (s > 0.0) & (s < 1.0) & (over * np.abs(over) < reach2)
    return np.asarray(close | under)


class PastLips:
    """The known lips nearest each map cell, for one view's guard (:meth:`KnownLips.guard`)."""

    def __init__(self, grid: MapGrid, xyz: F64, toward: F64, var: F64, min_drop_m: float) -> None:
        """``xyz``, ``toward``, ``var``: per cell (grid shape + (3,), + (2,), grid shape), NaN
        where the cell holds no lip."""
        self.grid = grid
        self.min_drop_m = min_drop_m
        self._holds = ~np.isnan(xyz[..., 0])  # the cells that hold a lip of their own
        idx = ndimage.distance_transform_edt(~self._holds, return_distances=False, return_indices=True)
        iy, ix = idx[0], idx[1]
        self._xyz, self._toward, self._var = xyz[iy, ix], toward[iy, ix], var[iy, ix]

    def clear(self, xyz_w: F64, cov_common: F64, k_sigma: float, eye: F64 | None = None) -> B:
        """Points not withheld: those farther than ``k_sigma`` sigma from the nearest known lip
        (the point's common and the lip's horizontal variance), on its plateau side, more than
        ``min_drop_m`` below it, or, with the camera centre ``eye``, that the lip does not hide
        from it within ``k_sigma`` sigma (the largest of the point's common covariance, in any
        direction, and the lip's variance: :func:`on_sight_line`) (points off the grid: True, the
        merge drops them anyway)."""
        out = np.ones(xyz_w.shape[0], bool)
        if k_sigma <= 0.0 or xyz_w.shape[0] == 0:
            return out
        inside, iy, ix, p, lip, off = self._nearest(xyz_w)
        var = horizontal_variance(cov_common[inside]) + self._var[iy, ix]
        past = np.einsum("ij,ij->i", off, self._toward[iy, ix]) > 0.0
        high = p[:, 2] > lip[:, 2] - self.min_drop_m
        near = np.einsum("ij,ij->i", off, off) <= k_sigma * k_sigma * var
        held = past & high & near
        if eye is not None and held.any():  # the point's noise in any direction and the lip's
            reach2 = k_sigma * k_sigma * (largest_variance(cov_common[inside][held]) + self._var[iy, ix][held])
            held[held] = on_sight_line(eye, p[held], lip[held], self._toward[iy, ix][held], reach2)
        out[inside] = ~held
        return out

    def _nearest(self, xyz_w: F64) -> tuple[B, NDArray[np.intp], NDArray[np.intp], F64, F64, F64]:
        """The points on the grid (mask), their cells, the points, the nearest known lip to each
        and the horizontal offset from it (a NaN point falls off the grid)."""
        with np.errstate(invalid="ignore"):
            iy, ix, inside = self.grid.cell_index(xyz_w[:, 0], xyz_w[:, 1])
        iy, ix = iy[inside], ix[inside]
        p = xyz_w[inside]
        lip = self._xyz[iy, ix]
        return inside, iy, ix, p, lip, p[:, :2] - lip[:, :2]

    def under(self, xyz_w: F64, cov_w: F64, k_sigma: float) -> B:
        """Points the gravity grid must not take (module docstring): more than ``min_drop_m``
        below the nearest known lip, and in the lip's own cell or on its plateau side within
        ``k_sigma`` sigma of it (``cov_w``: the point's whole covariance, and the lip's horizontal
        variance). Points off the grid, and every point with ``k_sigma <= 0`` (the guard off): False."""
        out = np.zeros(xyz_w.shape[0], bool)
        if k_sigma <= 0.0 or xyz_w.shape[0] == 0:
            return out
        inside, iy, ix, p, lip, off = self._nearest(xyz_w)
        low = p[:, 2] < lip[:, 2] - self.min_drop_m
        behind = np.einsum("ij,ij->i", off, self._toward[iy, ix]) <= 0.0
        var = horizontal_variance(cov_w[inside]) + self._var[iy, ix]
        near = np.einsum("ij,ij->i", off, off) <= k_sigma * k_sigma * var
        out[inside] = low & (self._holds[iy, ix] | (behind & near))
        return out

    def gravity_parts(self, parts: list[ViewPart], k_sigma: float) -> list[ViewPart]:
        """A view's parts ``(xyz, cov, cov_common)`` without the points :meth:`under` a known lip:
        the gravity grid's share."""
        out: list[ViewPart] = []
        for xyz, cov, common in parts:
            keep = ~self.under(xyz, cov, k_sigma)
            if keep.all():
                out.append((xyz, cov, common))
            elif keep.any():
                out.append((xyz[keep], cov[keep], None if common is None else common[keep]))
        return out


class KnownLips:
    """The lips earlier views found, per map cell (reset with the map)."""

    def __init__(self, grid: MapGrid) -> None:
        self.grid = grid
        self.clear()

    def clear(self) -> None:
        shape = self.grid.shape
        self.xyz = np.full(shape + (3,), np.nan)  # the lip's point (its near, plateau side), m
        self.toward = np.zeros(shape + (2,))  # unit (x, y) way to the drop side
        self.var = np.full(shape, np.inf)  # the lip's horizontal variance from its view's pose, m^2

    @property
    def cells(self) -> int:
        return int(np.count_nonzero(np.isfinite(self.var)))

    def add(self, near: F64, toward: F64, var: F64) -> None:
        """A merged view's counted lips: their points (M, 3), unit ways to the drop side (M, 2)
        and horizontal variances (M,). A cell keeps the lip with the smallest variance (the
        first of equals)."""
        iy, ix, inside = self.grid.cell_index(near[:, 0], near[:, 1])
        ok = inside & np.isfinite(var) & np.isfinite(near).all(axis=1)
        flat = (iy * self.grid.nx + ix)[ok]
        near, toward, var = near[ok], toward[ok], var[ok]
        order = np.lexsort((np.arange(flat.size), var, flat))  # per cell, smallest variance first
        first = np.ones(order.size, bool)
        first[1:] = flat[order][1:] != flat[order][:-1]
        pick = order[first]
        cells = flat[pick]
        better = var[pick] < self.var.reshape(-1)[cells]
        pick, cells = pick[better], cells[better]
        self.xyz.reshape(-1, 3)[cells] = near[pick]
        self.toward.reshape(-1, 2)[cells] = toward[pick]
        self.var.reshape(-1)[cells] = var[pick]

    def relevel(self, omega: F64, centre: F64) -> None:
        """The map's heights turned by the small world rotation ``omega`` (x, y, rad) about
        ``centre`` (levelled, ``fsw.core.registration.mount_bias``): the lips' heights turn alike."""
        x, y = self.xyz[..., 0], self.xyz[..., 1]
        self.xyz[..., 2] += omega[0] * (y - centre[1]) - omega[1] * (x - centre[0])

    def guard(self, min_drop_m: float) -> PastLips | None:
        """The guard of the next view: points past these lips and no more than ``min_drop_m``
        below them (None: no lip known)."""
        if not np.isfinite(self.var).any():
            return None
        return PastLips(self.grid, self.xyz, self.toward, self.var, min_drop_m)

    def state(self) -> KnownLipsState:
        """The lips for a checkpoint: per lip cell its flat index, point, way and variance."""
        flat = np.flatnonzero(np.isfinite(self.var))
        rows = np.column_stack([self.xyz.reshape(-1, 3)[flat], self.toward.reshape(-1, 2)[flat],
                                self.var.reshape(-1)[flat]])
        return {"cells": _pack(flat.astype("<i4")), "lips": _pack(rows.astype("<f8"))}

    def restore(self, state: Mapping[str, object]) -> None:
        """Restore :meth:`state`; anything missing or malformed leaves no lips."""
        self.clear()
        try:
            flat = np.frombuffer(_unpack(state["cells"]), "<i4").astype(np.intp)
            rows = np.frombuffer(_unpack(state["lips"]), "<f8").reshape(flat.size, 6)
        except (KeyError, TypeError, ValueError, zlib.error):  # binascii.Error is a ValueError
            return
        if flat.size and (flat.min() < 0 or flat.max() >= self.var.size or not np.isfinite(rows).all()):
            return
        self.xyz.reshape(-1, 3)[flat] = rows[:, :3]
        self.toward.reshape(-1, 2)[flat] = rows[:, 3:5]
        self.var.reshape(-1)[flat] = rows[:, 5]


def _pack(a: NDArray[np.int32] | NDArray[np.float64]) -> str:
    return base64.b64encode(zlib.compress(a.tobytes())).decode("ascii")


def _unpack(s: object) -> bytes:
    if not isinstance(s, str):
        raise TypeError("not a string")
    return zlib.decompress(base64.b64decode(s, validate=True))
