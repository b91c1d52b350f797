"""The 2.5D elevation map and its fusion of measured points (docs/algorithm.md §1, §1.1, §3.4, §4).

Cell state (arrays ``(ny, nx)``, index ``[iy, ix]`` as ``fsw.core.geometry.MapGrid``):
``z`` fused elevation (m), ``var`` its variance (m^2), ``n`` merged measurements (capped by
``n_max``), ``interest`` the interest function IF (starts at 1), ``misses`` unsuccessful
measurements, ``outliers`` measurements refused by the gate.

Unknown cell: ``z = NaN``, ``var = inf``, ``n = 0``; *mapped* once ``n >= 1`` (nothing else).

One ``merge`` call is one view. Its points are first reduced per cell (a vectorized
``np.bincount``): the inverse-variance mean of the points in the cell is the view's
measurement ``zm`` of that cell. Points of one view in one cell share the camera pose error
and overlapping matching windows, so their errors are correlated; with equicorrelation
``rho`` (``point_correlation``) the measurement variance is ``vm = (1 + (k-1) rho) / sum(1/v)``
for ``k`` points (``rho = 1``: the view counts as one measurement, ``rho = 0``: independent
points). ``n`` counts views, not points.

A point's vertical variance ``v`` is ``P_zz`` of its world covariance (§1.2) or, when the
full covariance is given, the larger of that and the slope term: a horizontal error ``dxy``
moves the point to terrain of another height, so the error in the cell's height is
``dz - g.dxy`` with ``g`` the local gradient (from this view's own cell means, so a view's
measurement does not depend on the map it is fused into), ``P_zz - 2 g.P_xyz + g^T P_xy g``.
(On a slope facing the camera that is below ``P_zz``; a noisy gradient may not lower it.)
That is the error of a point that stays on the surface of its own cell. A point's error across
its line of sight may carry it off that surface: a face point seen along the face's foot lands in
a flat cell beside it at the face's height, and the flat cell's gradient says nothing of that.
Given the camera's centre (``eye``), the lateral part of the covariance (``P`` without its
component along the ray) reaches ``source_reach_sigma`` of its horizontal sigma round the point,
and the point may have come from the steepest surface within that reach (the view's own cell
means, square windows of 1, 2, 4, ... cells): its variance is at least ``P_zz + |g_s|^2
lambda_max(P_lat,xy)`` with ``g_s`` that steepest gradient (no credit for the cross term: which
way the other surface leans against the error is not known).
Optionally the footprint term ``|g|^2 cell^2 / 12`` (one point samples one spot of a sloping
cell); off by default because the sub-cell term measures it from the points: the spread of a
view's points in a cell beyond their noise is added to the cell's measurement variance (a
step or a rock edge inside the cell). Calibrated against the bench truth in docs/perception.md.
A view's points near its own occluding lips never get here (``fsw.core.stereo.occlusion``).

The view's measurement is fused into the map by the 1-D Kalman update of §1.1; a
measurement whose Mahalanobis distance ``|zm - z| / sqrt(var + vm)`` exceeds ``gate_sigma``
is not averaged in: the cell's ``outliers`` count goes up and its ``var`` is multiplied by
``outlier_var_factor`` so that a real change is accepted after a few views. Where several
agents' views meet in one grid (:class:`TeamElevation`) a refused measurement above the cell's
height with a smaller variance than the cell's replaces its content instead (docs/algorithm.md §8).

Misses (§4, §3.4): given the visibility probability ``P_V`` of each cell for this view (or a
boolean mask, ``P_V = 1``), every cell with ``P_V > 0`` that got no point has its interest
multiplied by ``exp(-beta P_V)``; those with ``P_V >= miss_pv_threshold`` count a miss.
"""

from __future__ import annotations

from collections.abc import Generator, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage

from fsw.core.geometry import MapGrid
from fsw.core.steps import run_to_end
from fsw.framework.params import param

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class FusionConfig:
    """Map fusion parameters (config ``[fusion]``)."""

    n_max: int = param(10, lo=1, hi=100000, doc="cap of the merged-measurement count n")
    gate_sigma: float = param(
        3.0, lo=0.5, hi=100.0, units="sigma", doc="Mahalanobis gate of a cell measurement"
    )
    outlier_var_factor: float = param(
        4.0, lo=1.0, hi=1e6, doc="a cell's variance is multiplied by this on an outlier"
    )
    point_correlation: float = param(
        0.3, lo=0.0, hi=1.0, doc="error correlation of points of one view in one cell"
    )
    view_correlation: float = param(
        0.4, lo=0.0, hi=0.9, doc="part of a view's variance common to all views of a cell"
    )
    pose_common: bool = param(
        True, doc="a view's camera-pose part of the variance is common to all views of a cell (the map's frame error)"
    )
    slope_term: bool = param(True, doc="add the slope term (horizontal error times gradient)")
    footprint_term: bool = param(False, doc="add |gradient|^2 cell^2 / 12 per point")
    source_reach_sigma: float = param(
        0.0, lo=0.0, hi=10.0, units="sigma",
        doc="a point's lateral error (across its line of sight) may carry it this many sigma from the surface it "
            "came from: its variance takes the steepest slope of the view's cells within that reach (0: off)"
    )
    subcell_term: bool = param(
        True, doc="add the points' spread in the cell beyond their noise (sub-cell relief)"
    )
    min_var_m2: float = param(1e-8, lo=0.0, hi=1.0, units="m^2", doc="variance floor per point")
    max_var_m2: float = param(
        0.25, lo=1e-8, hi=1e6, units="m^2", doc="points with a larger variance are dropped"
    )
    miss_pv_threshold: float = param(
        0.5, lo=0.0, hi=1.0, doc="P_V at or above which a cell without a point counts a miss"
    )
    interest_beta: float = param(1.0, lo=0.0, hi=100.0, doc="interest decay rate beta (§3.4)")
    hidden_relief: bool = param(
        True, doc="face map (docs/algorithm.md §8.1): a view's cell beside one it looked at and did not measure "
                  "gains the variance of a step as large as the view's mean step (none measured: the cell's height out "
                  "of the plane)"
    )
    lip_guard_sigma: float = param(2.0, lo=0.0, hi=10.0, units="sigma", doc="withhold points closer to a lip (0: off)")
    lip_min_drop_m: float = param(0.30, lo=0.0, hi=100.0, units="m", doc="a lip counts when it drops by more")
    lip_sight_line: bool = param(
        False, doc="a lip withholds only the points it can hide from the view's camera (docs/algorithm.md §4; "
                   "on for the Cliff-bot's own views)"
    )


@dataclass(frozen=True)
class MergeStats:
    """What one ``merge`` did."""

    points_in: int
    points_used: int
    cells_measured: int
    cells_new: int
    cells_fused: int
    outliers: int
    misses: int


class ElevationMap:
    """Elevation grid with variance, count, interest function and misses (§1)."""

    def __init__(self, grid: MapGrid, cfg: FusionConfig | None = None) -> None:
        self.grid = grid
        self.cfg = cfg or FusionConfig()
        self.n_max = self.cfg.n_max
        shape = grid.shape
        self.z = np.full(shape, np.nan)
        self.var = np.full(shape, np.inf)
        self.n = np.zeros(shape, np.int32)
        self.interest = np.ones(shape)
        self.misses = np.zeros(shape, np.int32)
        self.outliers = np.zeros(shape, np.int32)
        self.var_common = np.zeros(shape)  # part of var common to all views (see _fuse)

    @property
    def mapped(self) -> NDArray[np.bool_]:
        return self.n >= 1

    @property
    def sigma(self) -> F64:
        return np.sqrt(self.var)

    def copy(self) -> ElevationMap:
        out = ElevationMap(self.grid, self.cfg)
        for name in ("z", "var", "n", "interest", "misses", "outliers", "var_common"):
            setattr(out, name, getattr(self, name).copy())
        return out

    def merge(
        self,
        xyz: F64,
        var_z: F64 | None = None,
        cov: F64 | None = None,
        p_visible: NDArray[np.float32] | NDArray[np.float64] | NDArray[np.bool_] | None = None,
        cov_common: F64 | None = None,
        eye: F64 | None = None,
    ) -> MergeStats:
        """Fuse one view's world points (§1.1) and record its misses (§4).

        ``xyz`` (N, 3) world points; either ``var_z`` (N,) vertical variances or ``cov``
        (N, 3, 3) world covariances (enables the slope term). ``cov_common`` (N, 3, 3) is
        the part of ``cov`` shared by every point of the view (the camera pose term of
        §1.2); it is averaged, not reduced, within a cell. ``p_visible`` (ny, nx): the
        probability that each cell was visible in this view, or a boolean mask. ``eye`` (3,):
        the camera's centre (with ``cov``: the slope of the surface a point may have come
        from, module docstring; None: its own cell's only).
        """
        return run_to_end(self.merge_steps(xyz, var_z, cov, p_visible, cov_common, eye=eye))

    def merge_steps(
        self,
        xyz: F64,
        var_z: F64 | None = None,
        cov: F64 | None = None,
        p_visible: NDArray[np.float32] | NDArray[np.float64] | NDArray[np.bool_] | None = None,
        cov_common: F64 | None = None,
        chunk: int | None = None,
        eye: F64 | None = None,
    ) -> Generator[None, None, MergeStats]:
        """:meth:`merge` for a slack job: the points go through in chunks of ``chunk``
        (None: all at once), yielding after each, in two passes (the per-cell means, then
        the per-point variances that need the gradient of those means). The per-cell sums
        are the same; only their floating-point summation order depends on ``chunk``. The
        map is only written in the last step."""
        xyz = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
        n_in = xyz.shape[0]
        # the six distinct entries xx xy xz yy yz zz of each covariance, as strided views
        c6: tuple[F64, ...] | None = None
        cc6: tuple[F64, ...] | None = None
        if cov is not None:
            c6 = _sym6(_rows(cov, n_in, "cov"))
            v_all = c6[5]
        elif var_z is not None:
            v_all = _rows(var_z, n_in, "var_z").reshape(-1)
        else:
            raise ValueError("merge needs var_z or cov")
        if cov_common is not None:
            if cov is None:
                raise ValueError("cov_common needs cov")
            cc6 = _sym6(_rows(cov_common, n_in, "cov_common"))
        step = max(1, n_in if chunk is None else int(chunk))
        chunks = []
        for a in range(0, max(n_in, 1), step):
            sl = slice(a, a + step)
            chunks.append((xyz[sl], v_all[sl], None if c6 is None else tuple(c[sl] for c in c6),
                           None if cc6 is None else tuple(c[sl] for c in cc6)))
        return (yield from self._merge_chunks(chunks, n_in, p_visible, chunk, eye))

    def merge_parts_steps(
        self,
        parts: list[tuple[F64, F64, F64 | None]],
        p_visible: NDArray[np.float32] | NDArray[np.float64] | NDArray[np.bool_] | None = None,
        step_points: int = 50000,
        eye: F64 | None = None,
    ) -> Generator[None, None, MergeStats]:
        """:meth:`merge` of one view in parts ``(xyz, cov, cov_common)`` (as a slack job propagates
        them), not joined first; yields once ``step_points`` points went through a pass since the
        last yield. ``cov_common``: in every part or none. ``parts`` is emptied as its covariances
        go to 6 components (one form at a time: both were the flight peak, +25 MB; issue 15).
        ``eye``: the camera's centre, as in :meth:`merge`."""
        chunks, n_in = [], 0
        if len({pc is None for _, _, pc in parts}) > 1:
            raise ValueError("cov_common must be given for every part or for none")
        parts.reverse()
        while parts:
            xyz, cov, cov_common = parts.pop()
            xyz = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
            n = xyz.shape[0]
            c6 = _sym6(_rows(cov, n, "cov"))
            cc6 = None if cov_common is None else _sym6(_rows(cov_common, n, "cov_common"))
            chunks.append((xyz, c6[5], c6, cc6))
            n_in += n
        if not chunks:
            chunks.append((np.zeros((0, 3)), np.zeros(0), tuple(np.zeros(0) for _ in range(6)), None))
        return (yield from self._merge_chunks(chunks, n_in, p_visible, step_points, eye))

    def _merge_chunks(
        self,
        chunks: Sequence[tuple[F64, F64, tuple[F64, ...] | None, tuple[F64, ...] | None]],
        n_in: int,
        p_visible: NDArray[np.float32] | NDArray[np.float64] | NDArray[np.bool_] | None,
        step_points: int | None,
        eye: F64 | None = None,
    ) -> Generator[None, None, MergeStats]:
        """The merge proper over chunks ``(xyz, P_zz or var_z, cov6 or None, common6 or None)``;
        yields once ``step_points`` points went through since the last yield (None: never)."""
        if eye is not None and not np.all(np.isfinite(np.asarray(eye, float))):
            raise ValueError("eye must be three finite numbers")
        budget = [0]

        def due(n: int) -> bool:
            budget[0] += n
            if step_points is None or budget[0] < step_points:
                return False
            budget[0] = 0
            return True

        has_cov = chunks[0][2] is not None
        has_common = chunks[0][3] is not None
        g = self.grid
        size = g.nx * g.ny
        # pass 1: per cell, the inverse-variance mean of the points (weights from P_zz)
        k = np.zeros(size, np.int64)
        sw = np.zeros(size)
        swz = np.zeros(size)
        parts: list[tuple[NDArray[np.intp], F64, F64, F64, F64, tuple[F64, ...] | None,
                          tuple[F64, ...] | None]] = []
        for p, v, pc6, pcc6 in chunks:
            fx, fy, ok = self._usable(p, v)
            if not ok.all():
                fx, fy, p, v = fx[ok], fy[ok], p[ok], v[ok]
                pc6 = None if pc6 is None else tuple(c[ok] for c in pc6)
                pcc6 = None if pcc6 is None else tuple(c[ok] for c in pcc6)
            flat = fy.astype(np.intp) * g.nx + fx.astype(np.intp)
            z = p[:, 2]
            v = np.maximum(v, self.cfg.min_var_m2)
            w = 1.0 / v
            k += np.bincount(flat, minlength=size)
            sw += np.bincount(flat, w, size)
            swz += np.bincount(flat, w * z, size)
            parts.append((flat, p, z, v, w, pc6, pcc6))
            if due(p.shape[0]):
                yield None
        with np.errstate(invalid="ignore", divide="ignore"):
            zm_dense = swz / sw
        grad_cells: tuple[F64, F64] | None = None
        steepest: SteepestWithin | None = None
        if has_cov and any(pt[0].size for pt in parts):
            gy, gx = nan_gradient(zm_dense.reshape(g.shape), g.cell)
            grad_cells = (gx.reshape(-1), gy.reshape(-1))
            if eye is not None and self.cfg.source_reach_sigma > 0.0:
                steepest = SteepestWithin(gx * gx + gy * gy)
        # pass 2: per point, the variance of the cell height (slope term) and its sums
        swi = np.zeros(size)
        swvc = np.zeros(size)
        swdev = np.zeros(size)
        n_used = 0
        for flat, p, z, v, w, pc6, pcc6 in parts:
            n_used += flat.size
            vc: F64 | float = 0.0
            if pc6 is not None and grad_cells is not None:
                grad = (grad_cells[0][flat], grad_cells[1][flat])
                src = None if steepest is None or eye is None else (_unit_rays(p, eye), steepest)
                v = self._vertical_variance(grad, pc6, footprint=True)
                if src is not None:
                    v = np.maximum(v, self._source_variance(flat, src[0], pc6, src[1]))
                if pcc6 is not None:
                    v_common = self._vertical_variance(grad, pcc6, footprint=False)
                    if src is not None:
                        v_common = np.maximum(v_common, self._source_variance(flat, src[0], pcc6, src[1]))
                    vc = np.minimum(v_common, v - self.cfg.min_var_m2)
            swi += np.bincount(flat, 1.0 / (v - vc), size)  # the independent (stereo) part
            if has_common:
                swvc += np.bincount(flat, w * vc, size)
            if self.cfg.subcell_term:
                swdev += np.bincount(flat, w * (z - zm_dense[flat]) ** 2, size)
            if due(flat.size):
                yield None
        cells = np.flatnonzero(k)
        kc, swc, zm = k[cells], sw[cells], zm_dense[cells]
        swi_c = swi[cells]
        vm = (1.0 + (kc - 1) * self.cfg.point_correlation) / swi_c
        vm_pose: F64 | None = None
        if has_common:
            vm_pose = swvc[cells] / swc  # common part: averaged
            vm += vm_pose
        if self.cfg.subcell_term:
            spread = swdev[cells] / swc  # weighted point spread
            excess = np.maximum(spread - kc / swi_c, 0.0) * kc / np.maximum(kc - 1, 1)
            vm += np.where(kc >= 2, excess, 0.0)
        new, fused, outl = self._fuse(cells, zm, vm, vm_pose if self.cfg.pose_common else None)
        n_miss = 0
        if p_visible is not None:
            n_miss = self.record_misses(p_visible, hit=k.reshape(g.shape) > 0)
        return MergeStats(n_in, n_used, int(cells.size), new, fused, outl, n_miss)

    def _usable(self, p: F64, v: F64) -> tuple[F64, F64, NDArray[np.bool_]]:
        """Fractional cell coordinates of points ``p`` (N, 3) and which the merge uses: on the
        grid, finite height, vertical variance ``v`` within ``[0, max_var_m2]``."""
        g = self.grid
        inv = 1.0 / g.cell
        with np.errstate(invalid="ignore"):
            fx = (p[:, 0] - g.x0) * inv  # >= 0 where inside, so truncation is floor
            fy = (p[:, 1] - g.y0) * inv
            ok = (fx >= 0) & (fx < g.nx) & (fy >= 0) & (fy < g.ny) & np.isfinite(p[:, 2])
            ok &= (v >= 0) & (v <= self.cfg.max_var_m2)  # False for NaN too
        return fx, fy, ok

    def hit_cells(self, parts: Sequence[tuple[F64, F64, F64 | None]]) -> NDArray[np.bool_]:
        """The cells a view's parts ``(xyz, cov, cov_common)`` put a point into when merged
        (:meth:`merge_parts_steps`): its misses can only be the other cells."""
        g = self.grid
        hit = np.zeros(g.nx * g.ny, bool)
        for xyz, cov, _ in parts:
            p = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
            fx, fy, ok = self._usable(p, _sym6(_rows(cov, p.shape[0], "cov"))[5])
            hit[fy[ok].astype(np.intp) * g.nx + fx[ok].astype(np.intp)] = True
        return hit.reshape(g.shape)

    def _vertical_variance(self, grad: tuple[F64, F64], c6: tuple[F64, ...],
                           footprint: bool) -> F64:
        """Per-point variance of the cell height: ``P_zz`` with the slope term and, if asked,
        the footprint term (module docstring). ``c6``: xx xy xz yy yz zz per point."""
        gx, gy = grad
        xx, xy, xz, yy, yz, zz = c6
        out = zz
        if self.cfg.slope_term:
            slope = zz - 2.0 * (gx * xz + gy * yz) + gx * (gx * xx + 2.0 * gy * xy) + gy * gy * yy
            out = np.maximum(zz, slope)  # a noisy gradient must not talk the variance down
        out = np.maximum(out, self.cfg.min_var_m2)
        if footprint and self.cfg.footprint_term:
            out += (gx * gx + gy * gy) * (self.grid.cell**2 / 12.0)
        return np.asarray(out)

    def _source_variance(self, flat: NDArray[np.intp], ray: F64, c6: tuple[F64, ...],
                         steepest: SteepestWithin) -> F64:
        """Per-point variance of the cell height when the point's lateral error (``c6`` without
        its part along the unit ``ray``) may have carried it off the steepest surface of the
        view within ``source_reach_sigma`` of that error: ``P_zz + |g_s|^2 lambda_max(P_lat,xy)``
        (module docstring)."""
        lam = _lateral_horizontal_variance(ray, c6)
        reach = self.cfg.source_reach_sigma * np.sqrt(lam) / self.grid.cell
        return np.asarray(c6[5] + steepest.at(flat, reach) * lam)

    def _fuse(self, cells: NDArray[np.intp], zm: F64, vm: F64, vm_pose: F64 | None = None) -> tuple[int, int, int]:
        """Inverse-variance update of the given flat cells with a Mahalanobis gate (§1.1).

        The part ``c = view_correlation`` of every view's variance is common to all views
        of the cell and does not average out: the map keeps it apart (``var_common``, the
        smallest seen) and fuses only the independent rest, ``var = var_indep + var_common``.
        ``vm_pose`` (the camera pose's part of ``vm``, with ``pose_common``) is common as a
        whole: the views of a map share its frame error (the first view's attitude, every later
        view registered to it), so it does not average down either (§1.2).
        With ``c = 0`` and no ``vm_pose`` this is exactly the 1-D Kalman update of §1.1.
        """
        c = self.cfg.view_correlation
        vm_pose = np.zeros_like(vm) if vm_pose is None else np.clip(vm_pose, 0.0, vm)
        cm = c * (vm - vm_pose) + vm_pose  # the view's part common to all views of the cell
        z, var, n = self.z.reshape(-1), self.var.reshape(-1), self.n.reshape(-1)
        vcom = self.var_common.reshape(-1)
        z0, v0, n0, vc0 = z[cells], var[cells], n[cells], vcom[cells]
        empty = n0 == 0
        with np.errstate(invalid="ignore"):
            d = np.abs(zm - z0) / np.sqrt(v0 + vm)
        outlier = ~empty & (d > self.cfg.gate_sigma)
        inlier = ~empty & ~outlier
        z_new = np.where(empty, zm, z0)
        v_new = np.where(empty, vm, v0)
        vc_new = np.where(empty, cm, vc0)
        zi, vi, mi, vmi, vci, cmi = z0[inlier], v0[inlier], zm[inlier], vm[inlier], vc0[inlier], cm[inlier]
        ind0, ind_m = vi - vci, vmi - cmi
        tot = ind0 + ind_m  # the independent parts weigh the heights (a common error shifts both alike)
        with np.errstate(invalid="ignore", divide="ignore"):
            z_new[inlier] = np.where(tot > 0, (ind_m * zi + ind0 * mi) / tot, 0.5 * (zi + mi))
            ind = np.where(tot > 0, ind0 * ind_m / tot, 0.0)
        vc_new[inlier] = np.minimum(vci, cmi)
        v_new[inlier] = ind + vc_new[inlier]
        v_new[outlier] = v0[outlier] * self.cfg.outlier_var_factor
        vc_new[outlier] = vc0[outlier] * self.cfg.outlier_var_factor
        z[cells], var[cells], vcom[cells] = z_new, v_new, vc_new
        n[cells] = np.where(outlier, n0, np.minimum(n0 + 1, self.n_max))
        self.outliers.reshape(-1)[cells[outlier]] += 1
        return int(empty.sum()), int(inlier.sum()), int(outlier.sum())

    def record_misses(
        self,
        p_visible: NDArray[np.float32] | NDArray[np.float64] | NDArray[np.bool_],
        hit: NDArray[np.bool_],
    ) -> int:
        """Interest decay and miss count for cells expected visible that got no point (§3.4)."""
        pv = np.asarray(p_visible, dtype=np.float64)
        if pv.shape != self.grid.shape:
            raise ValueError(f"p_visible must have shape {self.grid.shape}, got {pv.shape}")
        if not np.isfinite(pv).all() or pv.min() < 0.0 or pv.max() > 1.0:
            raise ValueError("p_visible must lie in [0, 1]")
        empty = ~hit & (pv > 0.0)
        self.interest[empty] *= np.exp(-self.cfg.interest_beta * pv[empty])
        missed = empty & (pv >= self.cfg.miss_pv_threshold)
        self.misses[missed] += 1
        return int(missed.sum())


class TeamElevation(ElevationMap):
    """A gravity grid that several agents' views enter (docs/algorithm.md §8, "Fusion from
    several agents"): §1.1, except that a measurement the gate refuses replaces the cell's content
    when it lies above it and its variance is smaller than the cell's. A gravity cell holds its
    upper surface (the face map keeps the outer one, §8.1): a cell that straddles a lip, seen
    first from below (the Cliff-bot's view of the face under it), is given the lip's height when
    a tighter view from above comes, whichever agent saw it first, where §1.1 keeps the first
    until a change has outvoted it over a few views; a lower height never displaces a cell's.
    Within one agent's views §1.1 holds (a refused measurement is more often the odd one)."""

    def _fuse(self, cells: NDArray[np.intp], zm: F64, vm: F64, vm_pose: F64 | None = None) -> tuple[int, int, int]:
        z0, v0, n0 = self.z.reshape(-1)[cells], self.var.reshape(-1)[cells], self.n.reshape(-1)[cells]
        with np.errstate(invalid="ignore"):
            refused = np.abs(zm - z0) > self.cfg.gate_sigma * np.sqrt(v0 + vm)
        better = (n0 > 0) & refused & (vm < v0) & (zm > z0)
        out = super()._fuse(cells, zm, vm, vm_pose)
        c = cells[better]
        self.z.reshape(-1)[c], self.var.reshape(-1)[c] = zm[better], vm[better]
        vp = np.zeros(c.size) if vm_pose is None else np.clip(vm_pose[better], 0.0, vm[better])
        self.var_common.reshape(-1)[c] = self.cfg.view_correlation * (vm[better] - vp) + vp  # as a first view's
        return out


class SteepestWithin:
    """The steepest squared gradient of a view's cells within a square window round each cell,
    for windows of half-size 0, 1, 2, 4, ... cells (each built when first asked for; a reach is
    rounded up to the next, so a point is never given a flatter neighbourhood than its reach)."""

    def __init__(self, slope2: F64) -> None:
        self.shape = slope2.shape
        self.levels: dict[int, F64] = {0: np.asarray(slope2, float).reshape(-1)}

    def at(self, flat: NDArray[np.intp], reach_cells: F64) -> F64:
        """The steepest squared gradient within ``reach_cells`` (per point) of each point's cell ``flat``."""
        r = np.ceil(np.nan_to_num(np.asarray(reach_cells, float), nan=0.0, posinf=0.0))
        cap = max(self.shape)
        r = np.minimum(np.maximum(r, 0.0), cap)
        half = np.where(r > 0, 2.0 ** np.ceil(np.log2(np.maximum(r, 1.0))), 0.0).astype(np.int64)
        out = np.empty(flat.shape[0])
        for h in np.unique(half):
            sel = half == h
            out[sel] = self._level(int(h))[flat[sel]]
        return out

    def _level(self, half: int) -> F64:
        if half not in self.levels:
            base = self.levels[0].reshape(self.shape)
            self.levels[half] = ndimage.maximum_filter(base, size=2 * half + 1, mode="constant", cval=0.0).reshape(-1)
        return self.levels[half]


def _unit_rays(p: F64, eye: F64) -> F64:
    """Unit lines of sight from the camera's centre ``eye`` to the points ``p`` (N, 3)."""
    d = p - np.asarray(eye, float).reshape(1, 3)
    n = np.linalg.norm(d, axis=1, keepdims=True)
    return np.asarray(d / np.maximum(n, 1e-9))


def _lateral_horizontal_variance(u: F64, c6: tuple[F64, ...]) -> F64:
    """The largest horizontal variance of the error across the line of sight: ``lambda_max`` of the
    xy block of ``(I - u u^T) P (I - u u^T)`` per point (``u`` unit rays, ``P`` as xx xy xz yy yz zz)."""
    xx, xy, xz, yy, yz, zz = c6
    ux, uy, uz = u[:, 0], u[:, 1], u[:, 2]
    pux = xx * ux + xy * uy + xz * uz
    puy = xy * ux + yy * uy + yz * uz
    puz = xz * ux + yz * uy + zz * uz
    upu = ux * pux + uy * puy + uz * puz
    lxx = xx - 2.0 * ux * pux + upu * ux * ux
    lyy = yy - 2.0 * uy * puy + upu * uy * uy
    lxy = xy - ux * puy - pux * uy + upu * ux * uy
    mid = 0.5 * (lxx + lyy)
    return np.asarray(np.maximum(mid + np.sqrt(0.25 * (lxx - lyy) ** 2 + lxy * lxy), 0.0))


def _sym6(cov: F64) -> tuple[F64, ...]:
    """xx xy xz yy yz zz of (N, 3, 3) covariances, as views (no copy)."""
    c = cov.reshape(-1, 9)
    return tuple(c[:, i] for i in (0, 1, 2, 4, 5, 8))


def _rows(a: F64, n: int, name: str) -> F64:
    arr = np.asarray(a, dtype=np.float64)
    if arr.shape[:1] != (n,):
        raise ValueError(f"{name} has {arr.shape[:1]} rows for {n} points")
    return arr


def nan_gradient(zc: F64, cell_m: float) -> tuple[F64, F64]:
    """Central-difference gradient (d/dy, d/dx) that falls back to one-sided next to NaNs."""
    pad = np.pad(zc, 1, constant_values=np.nan)
    c = pad[1:-1, 1:-1]
    out = []
    xp, xm = pad[1:-1, 2:], pad[1:-1, :-2]
    yp, ym = pad[2:, 1:-1], pad[:-2, 1:-1]
    for p, m in ((yp, ym), (xp, xm)):
        central = (p - m) / (2.0 * cell_m)
        fwd = (p - c) / cell_m
        bwd = (c - m) / cell_m
        gr = np.where(np.isnan(central), np.where(np.isnan(fwd), bwd, fwd), central)
        out.append(np.nan_to_num(gr, nan=0.0))
    return out[0], out[1]
