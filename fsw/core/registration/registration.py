"""Registration of a view against the map before it is merged (docs/algorithm.md §5.1, §5).

The "known spatial points" of §5 are the map itself: the points of a new view that fall on
well-measured map cells are aligned to the map's elevation surface by weighted least squares,

    minimise  sum_i w_i (z_i(pose) - Ob(x_i(pose), y_i(pose)))^2 + d^T Sigma_pose^-1 d,
    w_i = 1 / (a_i P_i a_i^T + s(x_i)^2),   a_i = (-dOb/dx, -dOb/dy, 1),

over the correction ``d = (dtheta, dt)`` of the camera pose in the convention of
``fsw.core.localization.localization`` (a rotation about the world axes through the camera centre, then a
translation): a point moves as ``p' = exp(dtheta) (p - c) + c + dt``. ``Ob`` and ``s^2`` are
the map's elevation and variance, bilinear between cell centres; ``P_i`` the point's stereo
covariance. The prior term (the view's pose covariance from the attitude sensor, odometry
and mast, §1.2) keeps what the terrain does not constrain at its prior: on level ground
only height, roll and pitch move; x, y and yaw move where the slopes constrain them (the
normal matrix says which). Gauss-Newton, a few iterations, residuals gated around their
median against their sigma and a robust (MAD) scale.

Points of one view are not independent (shared matching windows, the same surface patch),
so the data information is scaled down to ``n_eff`` points (choice), and the weights are
scaled by the robust a posteriori variance factor ``s^2`` of the residuals (the map's
variance includes the pose error common to all its cells, which does not blur the surface
being fitted). Relative to the map the correction's covariance is the posterior
``C = (J^T W J n_eff/n / s^2 + Sigma^-1)^-1``; the map itself is only as well placed as the
views that mapped it, so with ``reference_error`` their pose error joins it
(``fsw.core.registration.registration_stats.reference_covariance``,
``fsw.core.map.reference_frames``): ``cov = C + ref_cov``.

A false minimum (issue 13: terrain seed 6, a weakly constrained view settled 11 deg and
23 cm off, inside the chi-square gate, with a 5 cm sigma) is caught by consistency: two
spatially disjoint halves of the overlap are fitted apart and must agree within their
covariances (:func:`_split_check`, a chi-square test at ``split_alpha``). If they disagree
in all six directions, height, roll and pitch alone are fitted (yaw, x and y held at the
prior with its covariance: :func:`fsw.core.registration.registration_stats.posterior`), and
checked the same way; the record's ``reason`` says so.

A flat minimum (issue 27: cliff-team seed 1, a view on near-level ground 4.8 deg off in yaw
registered to a 1.1 deg sigma, 3.7 deg left) is caught by the cost itself: the normal matrix
takes the map's millimetre relief as information in yaw, x and y, the cost does not rise
there (:func:`_curvature_check`); that information is dropped from the covariance (yaw, x and
y keep about the prior's sigma) and the record's ``reason`` says so.

Refused (the view is merged with its pose covariance inflated instead): fewer than
``min_points`` points on reference cells (too little overlap), data that do not fix height,
roll and pitch (ill-conditioned: the normal matrix of height and tilt times the lever arm
has a condition number above ``max_condition``), a fit whose residual stays large, a
correction implausible against the prior (chi-square gate), or halves that disagree even in
height and tilt.
"""

from __future__ import annotations

import math
from collections.abc import Generator
from dataclasses import dataclass, field
from typing import TypedDict

import numpy as np
from numpy.typing import NDArray
from scipy.special import chdtri

from fsw.core.geometry import CameraPose, MapGrid
from fsw.core.localization.localization import so3_exp
from fsw.core.map.reference_frames import ReferenceFrames
from fsw.core.registration.registration_stats import (
    ALL,
    HEIGHT_TILT,
    halves,
    posterior,
    reference_covariance,
)
from fsw.core.steps import run_to_end
from fsw.framework.params import param

F64 = NDArray[np.float64]
CURVATURE_PASSES = 3  # the curvature check repeated at the sigmas it scaled (choice: converged in 2-3 on the benches)
CURVATURE_OK = 0.8  # a rise this close to the predicted one: the direction's information kept as it is


class RegistrationSummary(TypedDict):
    """One view's registration: status, correction (deg, m), its sigmas and what was constrained."""

    view: int
    status: str
    reason: str
    points: int
    droll_deg: float
    dpitch_deg: float
    dyaw_deg: float
    dx_m: float
    dy_m: float
    dz_m: float
    sigma: list[float]  # roll, pitch, yaw (deg), x, y, z (m)
    constrained: str  # letters of R, P, Y, x, y, z the terrain constrained
    residual_sigma: float
    split_chi2: float  # the two halves' disagreement, chi-square (dof: directions fitted; nan: not checked)
    ref_sigma: list[float]  # the part of sigma from the reference's own placement


@dataclass(frozen=True)
class RegistrationConfig:
    """Map registration of each view (config ``[registration]``)."""

    enabled: bool = param(True, doc="register views against the map before merging")
    ref_max_sigma_m: float = param(
        0.03, lo=0.001, hi=1.0, units="m", doc="map cells this good (or the better half) are the reference"
    )
    min_points: int = param(300, lo=10, hi=10**7, doc="fewer points on reference cells: not registered")
    max_points: int = param(4000, lo=100, hi=10**7, doc="points used (an even subsample)")
    n_eff: int = param(50, lo=1, hi=10**7, doc="independent points the data are worth at most")
    iterations: int = param(6, lo=1, hi=50, doc="Gauss-Newton iterations")
    gate_sigma: float = param(3.0, lo=1.0, hi=100.0, units="sigma", doc="residual gate")
    max_condition: float = param(
        1e4, lo=10.0, hi=1e12, doc="height/tilt normal matrix (tilt times the lever) worse conditioned: refused"
    )
    max_residual_sigma: float = param(3.0, lo=0.5, hi=100.0, units="sigma",
                                      doc="RMS normalised residual of the fit above this: refused")
    gate_chi2: float = param(50.0, lo=1.0, hi=1e9, doc="correction against the prior (6 dof) above this: refused")
    curvature_sigma: float = param(2.0, lo=0.0, hi=10.0, units="sigma", doc="the fit's cost is evaluated this "
                                   "many posterior sigmas along each of its principal directions (0: no check)")
    curvature_ratio: float = param(0.25, lo=0.0, hi=1.0, doc="the data's cost there rising by less than this "
                                   "fraction of what the linearised fit predicts: a flat minimum, the data's "
                                   "information along it dropped (under 0.8: scaled by the ratio)")
    split_alpha: float = param(0.001, lo=0.0, hi=0.5, doc="two disjoint halves of the overlap fitted apart disagree "
                               "beyond this chi-square tail (dof: the directions fitted; 0: no check): refit "
                               "in height and tilt only, or refused")
    reference_error: bool = param(True, doc="the pose error of the views that mapped the reference cells joins "
                                            "the correction's covariance (fsw.core.map.reference_frames)")
    inflate_rot_deg: float = param(0.3, lo=0.0, hi=30.0, units="deg", doc="unregistered view: added rotation sigma")
    inflate_pos_m: float = param(0.02, lo=0.0, hi=10.0, units="m", doc="unregistered view: added position sigma")
    carry: bool = param(True, doc="a new station starts from the last registered station's dead-reckoning "
                                  "correction (yaw, x, y, z) with the odometry covariance grown since")
    feed_back: bool = param(True, doc="a registered view's yaw, x, y, z correction also corrects the rover's "
                                      "own pose estimate (odometry and body height; fsw.core.localization.nav_fix)")
    bias_estimate: bool = param(True, doc="estimate the mast tilt offset and the attitude sensor's roll/pitch "
                                          "biases from the registered views and level the map's frame with them "
                                          "(fsw.core.registration.mount_bias)")
    bias_tilt_sigma_deg: float = param(0.2, lo=0.001, hi=10.0, units="deg", doc="prior sigma of the mast tilt offset")
    bias_attitude_sigma_deg: float = param(0.1, lo=0.001, hi=10.0, units="deg",
                                           doc="prior sigma of the attitude sensor's roll and pitch biases")
    bias_floor_deg: float = param(0.03, lo=0.0, hi=10.0, units="deg",
                                  doc="added to each view's tilt correction sigma (the views are not independent)")
    bias_gate_chi2: float = param(13.8, lo=1.0, hi=1e6, doc="a view's tilt correction against the prediction "
                                                            "(2 dof) above this: not used")
    bias_apply_ratio: float = param(0.6, lo=0.0, hi=1.0, doc="the map frame's tilt sigma under this fraction of "
                                                             "its prior: the map is levelled")
    bias_level_chi2: float = param(0.0, lo=0.0, hi=1e6, doc="the map frame's estimated tilt against its "
                                   "posterior (2 dof chi-square) at least this: the map is levelled (0: always)")
    bias_drop_variance: bool = param(False, doc="a levelled map's cells lose the frame variance the estimate "
                                                "removed (false: they keep the prior's: it may be optimistic)")
    bias_min_step_deg: float = param(0.02, lo=0.0, hi=10.0, units="deg",
                                     doc="the map is levelled again when the frame correction moved this much")


@dataclass
class Registration:
    """Outcome for one view: ``status`` is ``registered``, ``reference`` (empty map: this
    view defines it), or ``unregistered`` with ``reason``."""

    status: str
    reason: str = ""
    correction: F64 = field(default_factory=lambda: np.zeros(6))  # dtheta (rad), dt (m)
    cov: F64 = field(default_factory=lambda: np.zeros((6, 6)))
    points: int = 0
    residual_sigma: float = math.nan
    constrained: tuple[bool, ...] = (False,) * 6
    split_chi2: float = math.nan  # the halves' disagreement (chi-square, 6 dof); nan: not checked
    ref_cov: F64 = field(default_factory=lambda: np.zeros((6, 6)))  # the reference's part of cov

    def summary(self, view: int = -1) -> RegistrationSummary:
        """The per-view report (telemetry, events, the mission summary's ``registration``)."""
        d, s = self.correction, np.sqrt(np.maximum(np.diag(self.cov), 0.0))
        r = np.sqrt(np.maximum(np.diag(self.ref_cov), 0.0))
        return {
            "view": view, "status": self.status, "reason": self.reason, "points": self.points,
            "droll_deg": math.degrees(d[0]), "dpitch_deg": math.degrees(d[1]), "dyaw_deg": math.degrees(d[2]),
            "dx_m": float(d[3]), "dy_m": float(d[4]), "dz_m": float(d[5]),
            "sigma": [round(float(v), 6) for v in (*np.degrees(s[:3]), *s[3:])],
            "constrained": "".join(n for n, c in zip(("R", "P", "Y", "x", "y", "z"), self.constrained,
                                                      strict=True) if c),
            "residual_sigma": float(self.residual_sigma),
            "split_chi2": float(self.split_chi2),
            "ref_sigma": [round(float(v), 6) for v in (*np.degrees(r[:3]), *r[3:])],
        }


def apply_correction(pose: CameraPose, d: F64) -> CameraPose:
    """The pose moved by the correction ``d = (dtheta, dt)`` (§5 convention)."""
    return CameraPose(so3_exp(d[:3]) @ pose.R, pose.t + d[3:])


def inflate(cov: F64, cfg: RegistrationConfig) -> F64:
    """The pose covariance of a view that could not be registered."""
    add = np.r_[np.full(3, math.radians(cfg.inflate_rot_deg) ** 2), np.full(3, cfg.inflate_pos_m**2)]
    return np.asarray(cov, dtype=np.float64) + np.diag(add)


def _surface(grid: MapGrid, z: F64, var: F64, ref: NDArray[np.bool_], x: F64, y: F64
             ) -> tuple[F64, F64, F64, F64, NDArray[np.bool_]]:
    """Bilinear map height, its gradient and variance at ``(x, y)``; valid where the four
    surrounding cell centres are reference cells."""
    fx = np.nan_to_num((x - grid.x0) / grid.cell - 0.5, nan=-1.0, posinf=-1.0, neginf=-1.0)
    fy = np.nan_to_num((y - grid.y0) / grid.cell - 0.5, nan=-1.0, posinf=-1.0, neginf=-1.0)
    ix, iy = np.floor(fx).astype(np.intp), np.floor(fy).astype(np.intp)
    ok = (ix >= 0) & (iy >= 0) & (ix < grid.nx - 1) & (iy < grid.ny - 1)
    ix, iy = np.where(ok, ix, 0), np.where(ok, iy, 0)
    ok &= ref[iy, ix] & ref[iy, ix + 1] & ref[iy + 1, ix] & ref[iy + 1, ix + 1]
    ax, ay = fx - ix, fy - iy
    z00, z01, z10, z11 = z[iy, ix], z[iy, ix + 1], z[iy + 1, ix], z[iy + 1, ix + 1]
    h = (z00 * (1 - ax) + z01 * ax) * (1 - ay) + (z10 * (1 - ax) + z11 * ax) * ay
    gx = ((z01 - z00) * (1 - ay) + (z11 - z10) * ay) / grid.cell
    gy = ((z10 - z00) * (1 - ax) + (z11 - z01) * ax) / grid.cell
    v = (var[iy, ix] * (1 - ax) + var[iy, ix + 1] * ax) * (1 - ay) + (
        var[iy + 1, ix] * (1 - ax) + var[iy + 1, ix + 1] * ax) * ay
    return h, gx, gy, v, ok


def reference_cells(z: F64, var: F64, n: NDArray[np.int32], cfg: RegistrationConfig) -> NDArray[np.bool_]:
    """Map cells good enough to register against: mapped, finite, and sigma below
    ``ref_max_sigma_m`` or in the better-measured half of the map (choice: a map whose every
    cell carries a large common pose error, e.g. begun while the attitude was unknown, is
    still a consistent surface to align to)."""
    known = (n >= 1) & np.isfinite(z) & np.isfinite(var)
    if not known.any():
        return np.asarray(known)
    limit = max(cfg.ref_max_sigma_m**2, float(np.median(var[known])))
    return np.asarray(known & (var <= limit))


def register_points(pts_w: F64, cov_w: F64, pose: CameraPose, pose_cov: F64, grid: MapGrid, z: F64, var: F64,
                    ref: NDArray[np.bool_], cfg: RegistrationConfig, frames: ReferenceFrames | None = None
                    ) -> Registration:
    """Register a view's world points ``pts_w`` (their stereo covariances ``cov_w``, (N, 3, 3))
    against the map; ``pose`` / ``pose_cov`` are the view's prior (§5.1); ``frames``: the
    map cells' source views (their pose error joins the correction's covariance)."""
    return run_to_end(register_steps(pts_w, cov_w, pose, pose_cov, grid, z, var, ref, cfg, frames))


@dataclass
class _Fit:
    """One Gauss-Newton fit: the correction, its normal matrix (data only, scaled to
    ``n_eff``), the Jacobian rows and weights of the used points, and their indices."""

    d: F64
    N: F64
    J: F64
    w: F64
    used: NDArray[np.intp]
    r: F64
    sig2: F64
    scale: float


def _fit(q0: F64, cov_p: F64, t: F64, P_inv: F64, grid: MapGrid, z: F64, var: F64, ref: NDArray[np.bool_],
         cfg: RegistrationConfig, n_eff: float, min_points: int, free: list[int]
         ) -> Generator[None, None, _Fit | tuple[str, int]]:
    """Gauss-Newton from the prior (``d = 0``) in the ``free`` directions (the others held at
    the prior), one iteration per step; or why not (and the points left). ``N`` is the full
    6x6 normal matrix."""
    d = np.zeros(6)
    f = np.ix_(free, free)
    for _ in range(cfg.iterations):
        q = q0 @ so3_exp(d[:3]).T
        p = q + t + d[3:]
        h, gx, gy, v, ok = _surface(grid, z, var, ref, p[:, 0], p[:, 1])
        a = np.column_stack([-gx, -gy, np.ones_like(gx)])
        sig2 = np.einsum("ni,nij,nj->n", a, cov_p, a) + v
        r = p[:, 2] - h
        good = ok & np.isfinite(r) & (sig2 > 0)
        if good.sum() < min_points:
            return f"too little overlap: {int(good.sum())} points stay on the map", int(good.sum())
        med = float(np.median(r[good]))
        mad = 1.4826 * float(np.median(np.abs(r[good] - med)))
        used = good & (np.abs(r - med) <= cfg.gate_sigma * np.sqrt(sig2 + mad**2))
        if used.sum() < min_points:
            return f"too few consistent points ({int(used.sum())})", int(used.sum())
        J = np.column_stack([np.cross(q, a), a])[used]  # d r / d (dtheta, dt)
        # A posteriori variance factor (robust): the map's variance includes the pose error
        # common to all its cells, which does not blur the surface the view is fitted to.
        s2 = float(np.clip((1.4826 * np.median(np.abs(r[used] - med) / np.sqrt(sig2[used]))) ** 2, 0.25, 100.0))
        w = 1.0 / (s2 * sig2[used])
        scale = min(1.0, n_eff / float(used.sum()))
        N = (J * w[:, None]).T @ J * scale
        b = (J * w[:, None]).T @ r[used] * scale
        step = np.zeros(6)
        step[free] = np.linalg.solve(N[f] + P_inv[f], -(b + P_inv @ d)[free])
        d = d + step
        yield
        if np.abs(step[:3]).max() < 1e-7 and np.abs(step[3:]).max() < 1e-6:
            break
    return _Fit(d, N, J, w, np.flatnonzero(used), r, sig2, scale)


def register_steps(pts_w: F64, cov_w: F64, pose: CameraPose, pose_cov: F64, grid: MapGrid, z: F64, var: F64,
                   ref: NDArray[np.bool_], cfg: RegistrationConfig, frames: ReferenceFrames | None = None
                   ) -> Generator[None, None, Registration]:
    """:func:`register_points` as a step generator: the point selection, then one Gauss-Newton
    iteration per step (the fit, then each half of the consistency check)."""
    if not ref.any():
        return Registration("reference", "empty map: this view begins it")
    pts_w = np.asarray(pts_w, dtype=np.float64)
    z, var = np.where(ref, z, 0.0), np.where(ref, var, 0.0)  # only reference cells are ever read
    keep = np.isfinite(pts_w).all(axis=1)
    _, _, _, _, on = _surface(grid, z, var, ref, pts_w[:, 0], pts_w[:, 1])
    idx = np.flatnonzero(keep & on)
    if idx.size < cfg.min_points:
        return Registration("unregistered", f"too little overlap: {idx.size} points on the map", points=int(idx.size))
    if idx.size > cfg.max_points:
        idx = idx[np.linspace(0, idx.size - 1, cfg.max_points).astype(np.intp)]
    yield  # the selection above is one slice, each iteration below another
    q0 = pts_w[idx] - pose.t
    cov_p = np.asarray(cov_w, dtype=np.float64)[idx]
    S = np.asarray(pose_cov, dtype=np.float64)
    P_inv = np.linalg.inv(S + np.diag(np.r_[np.full(3, 1e-10), np.full(3, 1e-8)]))
    out = yield from _solve(q0, cov_p, pose.t, S, P_inv, grid, z, var, ref, cfg, ALL, pts_w[idx], frames)
    if out.status != "registered" and out.reason.startswith(("halves disagree", "unchecked")):
        full = out  # ambiguous in yaw, x, y: height and tilt alone (what any overlap fixes)
        out = yield from _solve(q0, cov_p, pose.t, S, P_inv, grid, z, var, ref, cfg, HEIGHT_TILT, pts_w[idx],
                                frames)
        out.reason = (f"height and tilt only: {full.reason}; yaw, x, y kept at the prior"
                      if out.status == "registered" else f"{full.reason}; height and tilt alone: {out.reason}")
    if out.status != "registered":
        out.correction, out.cov, out.ref_cov = np.zeros(6), np.zeros((6, 6)), np.zeros((6, 6))
    return out


def _solve(q0: F64, cov_p: F64, t: F64, S: F64, P_inv: F64, grid: MapGrid, z: F64, var: F64,
           ref: NDArray[np.bool_], cfg: RegistrationConfig, free: list[int], pts: F64,
           frames: ReferenceFrames | None) -> Generator[None, None, Registration]:
    """One fit in the ``free`` directions, its covariance and the checks (module docstring)."""
    fit = yield from _fit(q0, cov_p, t, P_inv, grid, z, var, ref, cfg, cfg.n_eff, cfg.min_points, free)
    if isinstance(fit, tuple):
        return Registration("unregistered", fit[0], points=fit[1])
    d, used = fit.d, fit.used
    flat, N = _curvature_check(fit, P_inv, q0, t, grid, z, var, ref, cfg, free) if cfg.curvature_sigma > 0 else (
        "", fit.N)
    C, Cf = posterior(N, P_inv, S, free)
    ref_cov = np.zeros((6, 6)) if frames is None else reference_covariance(N, Cf, free, pts[used], t, grid, frames)
    res_sigma = float(np.sqrt(np.mean(fit.r[used] ** 2 / fit.sig2[used])))  # against the predicted sigmas
    prior_sd = np.sqrt(np.maximum(np.diag(S), 1e-20))
    constrained = tuple(bool(c) for c in np.sqrt(np.maximum(np.diag(C), 0.0)) < 0.5 * prior_sd)
    out = Registration("registered", "", d, C + ref_cov, int(used.size), res_sigma, constrained, ref_cov=ref_cov)
    # Does the data fix height, roll and pitch together? Its information there, tilt times the lever.
    lever = float(np.sqrt(np.mean(np.sum(q0[used][:, :2] ** 2, axis=1))))
    sub, unit = HEIGHT_TILT, np.array([lever, lever, 1.0])
    N3 = N[np.ix_(sub, sub)] / np.outer(unit, unit)
    lam = np.linalg.eigvalsh(N3)
    if not lam[0] > 0 or lam[-1] / lam[0] > cfg.max_condition:
        out.status, out.reason = "unregistered", "ill-conditioned: height and tilt not fixed by the overlap"
    elif res_sigma > cfg.max_residual_sigma:
        out.status, out.reason = "unregistered", f"residual {res_sigma:.1f} sigma after the fit"
    elif float(d @ P_inv @ d) > cfg.gate_chi2:
        out.status, out.reason = "unregistered", f"correction implausible (chi2 {float(d @ P_inv @ d):.0f})"
    elif cfg.split_alpha > 0:
        out.split_chi2 = yield from _split_check(q0[used], cov_p[used], t, S, P_inv, grid, z, var, ref, cfg, free)
        # the chi-square quantile from scipy.special (loaded with the visibility kernel); never
        # scipy.stats, whose import costs the flight process ~45 MB (tests/fsw/test_flight_imports.py)
        limit = float(chdtri(len(free), cfg.split_alpha))
        if math.isinf(out.split_chi2):
            out.status, out.reason = "unregistered", "unchecked: a half of the overlap too small to fit alone"
        elif out.split_chi2 > limit:
            out.status = "unregistered"
            out.reason = (f"halves disagree (chi2 {out.split_chi2:.0f} > {limit:.1f}, {len(free)} dof): "
                          "a false or ambiguous minimum")
    if out.status == "registered" and flat:
        out.reason = f"{flat}: the data's information there dropped"
    return out


def _curvature_check(fit: _Fit, P_inv: F64, q0: F64, t: F64, grid: MapGrid, z: F64, var: F64,
                     ref: NDArray[np.bool_], cfg: RegistrationConfig, free: list[int]) -> tuple[str, F64]:
    """Does the data's cost rise as the linearised fit says (issue 27)? The normal matrix takes
    the map's local gradients at face value; on near-level ground they are the map's own
    millimetre relief, and a shift of a few centimetres in yaw, x or y lands the points on other
    relief of the same size: the cost stays flat where the normal matrix claims information
    (cliff-team seed 1: a view 4.8 deg off in yaw, registered to 1.1 deg sigma with its error
    3.7 deg, the truth's cost no higher than the fit's). Along each principal direction ``v`` of
    the fitted directions' posterior given the held ones (``Cf``, sigma ``s``), the points are moved by ``+-k s v``
    (``k = curvature_sigma``) and the data's cost (the fit's weights and scale, the points that
    stay on the reference at both) compared
    with the rise ``k^2 s^2 v^T N v`` the fit predicts; a direction whose predicted rise is
    under 1 (the prior holds it: its sigma stays near the prior's) is not checked. A rise between
    ``curvature_ratio`` and ``CURVATURE_OK`` of the prediction scales the data's information
    along ``v`` by the ratio (the cost's own curvature at that scale); under ``curvature_ratio``
    it is a flat minimum and the information along ``v`` is dropped (the prior's sigma there).
    The fit's correction is kept: height and tilt were fitted jointly with the rest, so they
    carry no error of a direction held at the prior. The check is repeated at the new sigmas
    (at most ``CURVATURE_PASSES`` times). Returns what was flat (empty: nothing) and the normal
    matrix to take the covariance from."""
    u = fit.used
    f, held = np.ix_(free, free), [i for i in range(6) if i not in free]
    N = fit.N.copy()

    def cost(d: F64) -> tuple[F64, NDArray[np.bool_]]:
        q = q0[u] @ so3_exp(d[:3]).T
        p = q + t + d[3:]
        h, _, _, _, ok = _surface(grid, z, var, ref, p[:, 0], p[:, 1])
        return fit.w * (p[:, 2] - h) ** 2, ok & np.isfinite(h)

    c0, ok0 = cost(fit.d)
    flat = ""
    for _ in range(CURVATURE_PASSES):
        lam, V = np.linalg.eigh(np.linalg.inv(N[f] + P_inv[f]))
        rho = np.ones(len(free))
        for j in range(len(free)):
            step = np.zeros(6)
            step[free] = V[:, j] * cfg.curvature_sigma * math.sqrt(max(float(lam[j]), 0.0))
            predicted = float(step @ N @ step)
            if predicted < 1.0:
                continue
            (cp, okp), (cm, okm) = cost(fit.d + step), cost(fit.d - step)
            both = ok0 & okp & okm
            rise = 0.5 * fit.scale * float(np.sum(cp[both] + cm[both] - 2.0 * c0[both]))
            rise *= u.size / max(int(both.sum()), 1)  # the points that left the reference counted as the rest
            if rise < cfg.curvature_ratio * predicted:  # flat: the data say nothing along v
                rho[j] = 0.0
                main = ("roll", "pitch", "yaw", "x", "y", "z")[free[int(np.argmax(np.abs(V[:, j])))]]
                flat = (f"flat cost: a rise of {rise:.1f} where the fit predicts {predicted:.1f}, "
                        f"{cfg.curvature_sigma:g} sigma along its direction mostly in {main}")
            elif rise < CURVATURE_OK * predicted:
                rho[j] = rise / predicted
        if rho.min() >= 1.0:
            break
        D = V * np.sqrt(rho)[None, :] @ V.T  # the information along each v scaled by its ratio
        N[f] = D @ N[f] @ D.T
        if held:
            fh = np.ix_(free, held)
            N[fh] = D @ N[fh]
            N[np.ix_(held, free)] = N[fh].T
    return flat, N


def _split_check(q0: F64, cov_p: F64, t: F64, S: F64, P_inv: F64, grid: MapGrid, z: F64, var: F64,
                 ref: NDArray[np.bool_], cfg: RegistrationConfig, free: list[int]) -> Generator[None, None, float]:
    """Consistency of the fit (a false minimum, issue 13): the used points split into two
    spatially disjoint halves (:func:`fsw.core.registration.registration_stats.halves`), each fitted
    on its own from the prior with
    half the view's independent points (``n_eff / 2``: the halves share no matching window).
    Two unbiased fits differ by ``D = d_A - d_B`` with a covariance at most ``C_A + C_B`` (the
    shared prior only correlates them positively), so ``D^T (C_A + C_B)^-1 D`` is at most
    chi-square with as many dof as ``free`` directions; above its ``1 - split_alpha`` quantile
    the data hold two different answers. With directions held at the prior, both halves
    shift with their error: ``(K_A - K_B) S_hh (K_A - K_B)^T`` joins the covariance
    (:func:`fsw.core.registration.registration_stats.posterior`). A half too small to fit (under
    ``min_points / 2``) gives ``inf``."""
    first = halves(q0[:, :2])
    held = [i for i in range(6) if i not in free]
    fits: list[tuple[F64, F64, F64]] = []
    for half in (first, ~first):
        f = yield from _fit(q0[half], cov_p[half], t, P_inv, grid, z, var, ref, cfg, 0.5 * cfg.n_eff,
                            max(1, cfg.min_points // 2), free)
        if isinstance(f, tuple):
            return math.inf
        _, Cf = posterior(f.N, P_inv, S, free)
        K = -Cf @ (f.N + P_inv)[np.ix_(free, held)]
        fits.append((f.d[free], Cf, K))
    D = fits[0][0] - fits[1][0]
    dK = fits[0][2] - fits[1][2]  # both halves see the same error of the held directions
    try:
        m2 = float(D @ np.linalg.solve(fits[0][1] + fits[1][1] + dK @ S[np.ix_(held, held)] @ dK.T, D))
    except np.linalg.LinAlgError:
        return math.inf
    return m2 if np.isfinite(m2) else math.inf


