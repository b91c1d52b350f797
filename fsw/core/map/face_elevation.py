"""The face map's grid: the elevation map of §1.1 with the face's changes (docs/algorithm.md §8.1).

:class:`FaceElevation` is the :class:`~fsw.core.map.elevation_map.ElevationMap` the face map
(:class:`fsw.core.map.face_map.FaceMap`) holds over its ``(u, v)`` grid; it changes how one
view's measurement of a cell is weighted and gated. The variance of a view's sample of a cell
against the cell's centre (the relief the view cannot resolve, the steps beside the cell, the
steps the view did not see) is worked out per view by :func:`relief_variance` and the
functions below it.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage

from fsw.core.geometry import MapGrid
from fsw.core.map.elevation_map import ElevationMap, FusionConfig, nan_gradient

F64 = NDArray[np.float64]
B = NDArray[np.bool_]


class FaceElevation(ElevationMap):
    """The face map's grid: §1.1 with five changes (docs/algorithm.md §8.1).

    *The relief the view cannot resolve.* A view's gradient ``g`` (of its own cell means, the
    slope term of §1.2) is the face's relief blurred by the points' error along the face: at
    grazing incidence it is about half the local slope. The slope term takes the slope as
    uncertain, ``g + dg`` with ``dg`` zero-mean and, per axis, the variance of the resolved
    gradient (``E[g_i^2] = 2 g_i^2``): each point's variance gains
    ``g_u^2 P_uu + g_v^2 P_vv`` (:meth:`_vertical_variance`). And a view's points sample a cell
    where that view sees it (at grazing incidence, the parts facing the camera), not at its
    centre, once per view: the view's cell measurement gains ``E|g|^2 c^2 / 12 =
    2 |g|^2 c^2 / 12`` (the variance of a plane of that slope over a cell of side ``c``),
    independent between views (:meth:`_fuse`).

    *The steps beside a cell.* At grazing incidence a view's matching windows and its sight
    lines mix a cell with the relief beside it: next to a step out of the face the view sees the
    step's side and its top, not the cell's own ground behind it, and a cell on a step's top
    gets the lower ground beyond its edge. The view's cell measurement gains
    ``(r_up^2 + r_down^2) / 3``, with ``r_up`` (``r_down``) how far the view's own cell means
    within ``step_cells`` cells rise above (fall below) the cell's tangent plane (its min-mod
    gradient: a plane gives none): the sample lies anywhere between the cell's ground and the
    step's, the second moment of a uniform error over the step (:func:`relief_variance`). It is
    a grazing view's: each step counts by the share of the cell it reaches (:func:`step_variance`),
    ``h tan t`` over one cell, at most 1, with ``h`` the step and ``t`` the incidence of the view's
    sight line to the cell (the face a step hides or mixes in; a view head-on mixes none), and a
    step that does not rise between the camera and the cell (no shadow on it) only as far as
    two of the view's matching windows reach (``window_rad``).

    *The steps a view did not see* (``[fusion] hidden_relief``). Beside a cell the view did not
    measure (the relief hid it) the steps' term finds no step; the cell gains the variance of a
    step as large as the steps the view saw elsewhere, or, in a view that resolved no relief of
    its own, as the cell's height out of the plane (:func:`hidden_relief`).

    *The weights.* Of a cell's height and a view's, each is weighted by its whole variance, not
    by its independent part alone as in §1.1: the common part (the camera pose's, a share of the
    view's) is one error within one agent's frame, but two agents' poses err apart, and the face
    map is where their views meet. The variance is §1.1's (its common part does not average down).

    *The gate.* A measurement the gate refuses (farther than ``gate_sigma`` from the cell)
    replaces the cell when its variance is smaller than the cell's: of two inconsistent surfaces
    (two agents' views of one cell, one of them wrong) the cell holds the better-supported one,
    whichever came first, so fusing a second agent never leaves a cell worse than the better
    agent's own."""

    def __init__(self, grid: MapGrid, cfg: FusionConfig | None = None, step_cells: int = 2) -> None:
        super().__init__(grid, cfg)
        self.step_cells = step_cells
        # the camera centre (face frame) of the view being merged, or None (unknown: the steps'
        # term in full); FaceMap.merge_parts sets it for one merge
        self.eye: F64 | None = None
        # the cells the view being merged looked at (:func:`fsw.core.map.face_map.in_view`), or None (all of them);
        # FaceMap.merge_parts sets it for one merge
        self.in_view: B | None = None
        # the stereo matching window's angle of the view being merged (rad), or None (unknown:
        # no bound on how far a step mixes in); FaceMap.merge_parts sets it for one merge
        self.window_rad: float | None = None

    def _vertical_variance(self, grad: tuple[F64, F64], c6: tuple[F64, ...], footprint: bool) -> F64:
        """§1.2's slope term plus the unresolved slope's share, ``g_u^2 P_uu + g_v^2 P_vv``, in a
        point's whole variance (``footprint``; the view's common part is left as it is)."""
        out = super()._vertical_variance(grad, c6, footprint)
        if footprint and self.cfg.slope_term:
            gx, gy = grad
            out = out + gx * gx * c6[0] + gy * gy * c6[3]
        return np.asarray(out)

    def _fuse(self, cells: NDArray[np.intp], zm: F64, vm: F64, vm_pose: F64 | None = None) -> tuple[int, int, int]:
        if self.cfg.slope_term and cells.size:
            vm = vm + relief_variance(self.grid, cells, zm, self.step_cells, self.eye, self.cfg.hidden_relief,
                                      self.in_view, self.window_rad)
        z, var, n = self.z.reshape(-1), self.var.reshape(-1), self.n.reshape(-1)
        z0, v0, n0 = z[cells], var[cells], n[cells]
        with np.errstate(invalid="ignore"):
            near = np.abs(zm - z0) <= self.cfg.gate_sigma * np.sqrt(v0 + vm)
        swap = (n0 > 0) & ~near & (vm < v0)
        inlier = (n0 > 0) & near
        out = super()._fuse(cells, zm, vm, vm_pose)
        c = cells[inlier]  # the heights by the whole variances (the agents' common parts are not one error)
        z[c] = (vm[inlier] * z0[inlier] + v0[inlier] * zm[inlier]) / (v0[inlier] + vm[inlier])
        c = cells[swap]
        z[c], var[c] = zm[swap], vm[swap]
        vp = np.zeros(int(swap.sum())) if vm_pose is None else np.clip(vm_pose[swap], 0.0, vm[swap])
        self.var_common.reshape(-1)[c] = self.cfg.view_correlation * (vm[swap] - vp) + vp
        return out


def relief_variance(grid: MapGrid, cells: NDArray[np.intp], zm: F64, step_cells: int = 0,
                    eye: F64 | None = None, hidden: bool = False, looked: B | None = None,
                    window_rad: float | None = None) -> F64:
    """Per measured cell (flat ``cells``, the view's cell means ``zm``), the variance of a view's
    sample of the cell against its centre: ``E|g|^2 c^2 / 12`` with ``E|g|^2 = 2 |g|^2`` (``g``
    the gradient of the view's cell means, its unresolved part as wide again), plus, with
    ``step_cells > 0``, ``(r_up^2 + r_down^2) / 3`` for the steps beside the cell: ``r_up``
    (``r_down``) how far the view's cell means within ``step_cells`` cells rise above (fall
    below) the cell's tangent plane, each step scaled by the share of the cell it reaches seen
    from ``eye`` (face frame; None: in full, :func:`step_variance`): ``h tan t`` (the length of
    face a step ``h`` high hides or mixes in at the incidence ``t`` of the sight line to the
    cell) over one cell, at most 1; a step that does not rise between the camera and the cell
    casts no shadow on it and reaches it only through the stereo matching windows (of angle
    ``window_rad``; None: unknown, no such bound), within two window spans of the step.
    With ``hidden`` (and ``step_cells > 0``), a cell next to a cell the view did not measure
    though it looked at it (of its eight neighbours inside the grid and in ``looked``,
    :func:`fsw.core.map.face_map.in_view`; None: all of them) also gains ``h^2 / 3``, scaled by ``h tan t`` over one
    cell, at most 1, for the step the view could not see beside it: as large as the steps it saw
    (``h^2 = 3 rho^2``, ``rho^2`` the view's mean steps' variance over the cells whose whole
    reach it measured, :func:`hidden_relief`), or, when it measured no such cell and so shows no
    relief of its own, as the cell's own height out of the fitted plane (``h = zm``: the face
    beside a rock's top the view saw alone lies on the plane)."""
    dense = np.full(grid.nx * grid.ny, np.nan)
    dense[cells] = zm
    z = dense.reshape(grid.shape)
    gy, gx = nan_gradient(z, grid.cell)
    g2 = (gx * gx + gy * gy).reshape(-1)[cells]
    out = 2.0 * g2 * grid.cell**2 / 12.0
    if step_cells > 0:
        sight = None if eye is None else _sight_lines(grid, z, eye, window_rad)
        out = out + step_variance(z, step_cells, grid.cell, sight).reshape(-1)[cells]
        if hidden:
            tan_t = None if sight is None else sight[2].reshape(-1)[cells]
            beside, rho2 = hidden_relief(z, step_cells, looked)
            h2 = np.full(len(cells), 3.0 * rho2) if rho2 is not None else zm * zm
            out = out + beside.reshape(-1)[cells] * _step_share(np.sqrt(h2), tan_t, grid.cell) * h2 / 3.0
    return np.asarray(out, float)


Sight = tuple[F64, F64, F64, F64]  # per cell: the unit direction to the camera in (u, v), tan t, window span


def _sight_lines(grid: MapGrid, z: F64, eye: F64, window_rad: float | None) -> Sight:
    """Per cell of a view's heightfield ``z`` (face frame, NaN unknown: taken on the plane), seen
    from the camera centre ``eye``: the unit direction ``(du, dv)`` from the cell towards the
    camera along the face, ``tan t`` (``t`` the incidence of the sight line on the face) and the
    length of face one matching window of angle ``window_rad`` covers there along the sight
    line's trace, ``window_rad r / cos t`` (:func:`fsw.core.map.face_map.window_span`; inf when ``window_rad`` is
    None)."""
    X, Y = grid.centers()
    e = np.reshape(eye, 3)
    d = np.stack([X - e[0], Y - e[1], np.nan_to_num(z) - e[2]])
    across = np.hypot(d[0], d[1])
    along_n = np.abs(d[2])
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        du, dv = np.nan_to_num(-d[0] / across), np.nan_to_num(-d[1] / across)
        tan_t = across / along_n
        span = (np.full(z.shape, np.inf) if window_rad is None
                else window_rad * (across * across + along_n * along_n) / along_n)
    return (np.asarray(du, float), np.asarray(dv, float), np.asarray(tan_t, float),
            np.asarray(np.nan_to_num(span, nan=np.inf), float))


def _step_share(h: F64, tan_t: F64 | None, cell_m: float) -> F64:
    """The share of a step ``h`` high a view mixes into a cell at the incidence ``t`` of its
    sight line: ``h tan t`` over one cell, at most 1 (None: the incidence is unknown, 1)."""
    if tan_t is None:
        return np.ones(len(h))
    with np.errstate(invalid="ignore"):
        share = np.nan_to_num(h * tan_t / cell_m, nan=1.0, posinf=1.0)
    return np.asarray(np.clip(share, 0.0, 1.0), float)


def hidden_relief(z: F64, reach: int, looked: B | None = None) -> tuple[B, float | None]:
    """``(beside, rho^2)`` for one view's heightfield of cell means ``z`` (NaN: the view put no
    point there): the cells it measured with a neighbour it did not though it looked at it (of
    their eight inside the grid, beyond which the ground is the gravity grid's, and in
    ``looked``, None: all; a cell outside the view's image or range was not hidden), and the view's mean steps'
    variance ``(r_up^2 + r_down^2) / 3`` (:func:`step_heights` within ``reach``) over the cells
    whose whole reach it measured (None when it measured no such cell).

    At grazing incidence a view misses the ground the relief hides from it (behind a rise, in
    front of a step turned away) and puts a cell's points on what it sees of the cell: the top of
    the rise. Beside a neighbour it did not see, its own cell means show no step and the steps'
    term adds nothing, yet the cell's ground may lie as far below its sample as the relief
    reaches; the relief the view could not see is taken as large as the relief it saw."""
    known = np.isfinite(z)
    if not known.any():
        return np.zeros(z.shape, bool), None
    missed = ~known if looked is None else ~known & looked
    ring = ndimage.convolve(missed.astype(np.float64), np.ones((3, 3)), mode="constant", cval=0.0)
    beside = known & (ring > 0.5)
    size = 2 * reach + 1
    full = known & (ndimage.convolve(known.astype(np.float64), np.ones((size, size)), mode="constant",
                                     cval=1.0) > size * size - 0.5)
    up, down = step_heights(z, reach)
    steps = (up * up + down * down) / 3.0
    rho2 = float(np.mean(steps[full])) if full.any() else None
    return np.asarray(beside, bool), rho2


def _deviations(z: F64, reach: int) -> Iterator[tuple[int, int, F64]]:
    """``(dy, dx, d)`` for every offset within ``reach`` cells (the square around each cell, the
    cell itself included): how far the known cell there lies above the cell's tangent plane (NaN
    where either is unknown). The plane's gradient is, per axis, the min-mod of the two one-sided
    differences to the next cells (the smaller, 0 where they differ in sign; the one known where
    the other is not): a plane gives 0, a step beside the cell its height."""
    ny, nx = z.shape
    p = np.pad(z, reach, constant_values=np.nan)

    def at(dy: int, dx: int) -> F64:
        return np.asarray(p[reach + dy: reach + dy + ny, reach + dx: reach + dx + nx], float)

    def slope(a: F64, b: F64) -> F64:
        with np.errstate(invalid="ignore"):
            m = np.where(a * b > 0, np.sign(a) * np.minimum(np.abs(a), np.abs(b)), 0.0)
            m = np.where(np.isnan(a), b, np.where(np.isnan(b), a, m))
        return np.asarray(np.nan_to_num(m), float)

    gx = slope(at(0, 1) - z, z - at(0, -1))
    gy = slope(at(1, 0) - z, z - at(-1, 0))
    for dy in range(-reach, reach + 1):
        for dx in range(-reach, reach + 1):
            yield dy, dx, at(dy, dx) - z - gx * dx - gy * dy


def step_heights(z: F64, reach: int) -> tuple[F64, F64]:
    """Per cell of a heightfield ``z`` (NaN unknown), how far the known cells within ``reach``
    cells (the square around it) rise above and fall below the cell's tangent plane (``(up,
    down)``, both >= 0; 0 for unknown cells; the plane of :func:`_deviations`)."""
    up, down = np.zeros(z.shape), np.zeros(z.shape)
    for _, _, d in _deviations(z, reach):
        up = np.fmax(up, d)
        down = np.fmax(down, -d)
    return np.asarray(np.nan_to_num(up), float), np.asarray(np.nan_to_num(down), float)


def step_variance(z: F64, reach: int, cell_m: float, sight: Sight | None = None) -> F64:
    """Per cell of a view's heightfield ``z`` (NaN unknown), the steps' variance ``(r_up^2 +
    r_down^2) / 3`` (docs/algorithm.md §8.1): ``r_up^2`` (``r_down^2``) the largest ``s d^2``
    over the cells within ``reach`` that rise above (fall below) the cell's tangent plane by
    ``d`` (:func:`_deviations`), ``s`` the share of the cell that step reaches, seen along
    ``sight`` (:func:`_sight_lines`; None: 1). A step ``h = |d|`` high hides or mixes in ``h tan
    t`` of face at the incidence ``t``; a rise between the camera and the cell (its offset
    towards the camera along the face, less than a cell across the sight line's trace) shadows
    the cell by that much, ``s = h tan t / c``; any other step (a rise beyond the cell, turned to
    the camera; a fall; a rise off to the side) casts no shadow on the cell and reaches it only
    through the stereo matching windows that straddle it and the depth they mix, taken as two
    window spans ``w`` (:func:`fsw.core.map.face_map.window_span`; a bound set on the face-map experiment's tuning
    scenes): ``s = min(h tan t, 2 w - gap) / c`` with ``gap`` the face between the two cells;
    both at most 1. A view far off at grazing incidence (the RECON-bot's, windows several cells
    long on the face) keeps every step within reach; a view close to the face (the Cliff-bot's)
    keeps the steps that shadow the cell and the ones next to it."""
    up, down = np.zeros(z.shape), np.zeros(z.shape)
    for dy, dx, d in _deviations(z, reach):
        if sight is None:
            share: F64 | float = 1.0
        else:
            du, dv, tan_t, span = sight
            with np.errstate(invalid="ignore", over="ignore"):
                mixed = np.abs(d) * tan_t
                across = np.abs(dx * dv - dy * du)  # the step's offset across the sight line, in cells
                shadow = (d > 0) & (dx * du + dy * dv > 0) & (across < 1.0)
                gap = cell_m * (max(abs(dx), abs(dy)) - 1)
                reach_m = np.where(shadow, mixed, np.minimum(mixed, 2.0 * span - gap))
            share = np.clip(np.nan_to_num(reach_m / cell_m, nan=1.0, posinf=1.0), 0.0, 1.0)
        with np.errstate(invalid="ignore"):
            up = np.fmax(up, np.where(d > 0, share * d * d, 0.0))
            down = np.fmax(down, np.where(d < 0, share * d * d, 0.0))
    return np.asarray((np.nan_to_num(up) + np.nan_to_num(down)) / 3.0, float)
