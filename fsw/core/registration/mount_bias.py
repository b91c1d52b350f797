"""The constant mounting biases estimated in flight, and the map's frame levelled with them
(docs/algorithm.md §5.1, "Choice: the mounting biases").

The camera pose of every view carries two constant errors: the mast's tilt calibration
offset ``dt`` (the optical axis points ``dt`` above the tilt encoder) and the attitude
sensor's roll and pitch biases ``br``, ``bp``. To first order each is a small rotation of the
estimated pose about a horizontal world axis: the tilt offset about the view's horizontal
axis (its world yaw ``psi_v`` = body yaw + pan), the roll bias about the body's forward axis
and the pitch bias about its left axis (body yaw ``psi_b``). The pose's rotation error
(world x, y components) is ``e = H(psi_v, psi_b) x`` with ``x = (dt, br, bp)`` and

    H = [[-sin psi_v,  cos psi_b,  sin psi_b],
         [ cos psi_v,  sin psi_b, -cos psi_b]]

The first view of a map defines its frame with its own error ``e_ref``; a view registered to
the map is corrected by ``e_ref - e_i`` plus the levelling ``F`` applied to the map so far, so
its total tilt correction ``y_i`` (registration and carried correction together) gives the
linear measurement ``y_i - F = (H_ref - H_i) x``, the registration's prior taken out
(:func:`data_only`) and a floor added to its covariance (the views are not independent). A Kalman filter from the prior
``diag(tilt_sigma, attitude_sigma, attitude_sigma)^2`` estimates ``x``; a measurement whose
innovation fails a chi-square gate is refused (a false registration must not bias it). Views
at several pans make the tilt offset observable; headings that differ make the attitude biases
observable (at one heading they act on every view alike: a frame error no registration sees).

Once the frame's own error ``e_ref = H_ref x`` is known well enough (its posterior trace under
``bias_apply_ratio`` squared times its prior's) and, when ``bias_level_chi2`` > 0, significant
(``e_ref^T C^-1 e_ref`` of its posterior ``C`` at least that), the map is levelled: rotated by
``F = -e_ref`` about the reference camera (heights only; the horizontal shift, under a
millimetre per metre of relief, is left), and later views' priors start from the predicted
correction ``(H_ref - H_i) x + F``. With ``bias_drop_variance`` the frame variance the cells
carry (the reference view's attitude variance times the lever) drops to the posterior's;
without (the default) it stays: the posterior is only as good as the model, and effects it
leaves out (the stereo head's own calibration) come out as confident, wrong biases. The switch is ``bias_estimate``
(``[registration]``).

Pan and lift offsets do not enter: a pan offset turns the view about the body's vertical (no
tilt), a lift offset raises every view alike (the map's datum).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import TypedDict

import numpy as np
from numpy.typing import NDArray

from fsw.core.geometry import CameraPose
from fsw.core.map.elevation_map import ElevationMap

F64 = NDArray[np.float64]
NAMES = ("mast_tilt", "imu_roll", "imu_pitch")


class MountBiasSummary(TypedDict):
    """The estimate for the mission summary (deg)."""

    enabled: bool
    estimate_deg: dict[str, float]  # mast tilt offset, attitude roll and pitch biases
    sigma_deg: dict[str, float]
    views_used: int
    views_refused: int
    levelled: bool
    frame_correction_deg: list[float]  # the rotation applied to the map (world x, y)
    frame_sigma_deg: list[float]  # the posterior sigma of the map frame's tilt (world x, y)


class MountBiasState(TypedDict):
    """The estimator's checkpoint (JSON: floats round-trip exactly)."""

    x: list[float]
    P: list[list[float]]
    ref: list[float] | None
    centre: list[float]
    F: list[float]
    frame_cov: list[list[float]]
    used: int
    refused: int


@dataclass(frozen=True)
class Levelling:
    """One levelling of the map: the rotation applied (world x, y, rad) about ``centre``, its
    posterior sigma, and the estimate it came from (rad)."""

    omega: F64
    centre: F64
    sigma: F64
    estimate: F64


def view_yaw(pose: CameraPose) -> float:
    """The world yaw of a camera's optical axis."""
    f = pose.R[:, 2]
    return math.atan2(float(f[1]), float(f[0]))


def design(psi_v: float, psi_b: float) -> F64:
    """``H``: the pose's tilt error (world x, y) per unit of (tilt offset, roll, pitch bias)."""
    sv, cv, sb, cb = math.sin(psi_v), math.cos(psi_v), math.sin(psi_b), math.cos(psi_b)
    return np.array([[-sv, cb, sb], [cv, sb, -cb]])


def data_only(moved: F64, cov_post: F64, cov_prior: F64) -> tuple[F64, F64] | None:
    """The registration's tilt increment ``moved`` (world x, y, rad, from the prior it started
    at) without its prior: the registration is a posterior (its prior pulls a weakly constrained
    tilt toward where the view started), the estimator needs the data's own measurement. With
    the marginal informations ``I_data = C^-1 - S^-1`` the data alone moved the tilt by
    ``I_data^-1 C^-1 moved``, covariance ``I_data^-1``; None when the data fixed no tilt (or
    the input is not finite)."""
    m, C, S = (np.asarray(a, np.float64) for a in (moved, cov_post, cov_prior))
    if not (np.isfinite(m).all() and np.isfinite(C).all() and np.isfinite(S).all()):
        return None
    try:
        Ci, Si = np.linalg.inv(0.5 * (C + C.T)), np.linalg.inv(0.5 * (S + S.T))
    except np.linalg.LinAlgError:
        return None
    lam, vec = np.linalg.eigh(0.5 * ((Ci - Si) + (Ci - Si).T))
    if lam[-1] <= 0.0:
        return None
    lam = np.maximum(lam, 1e-6 * lam[-1])  # a direction the data did not fix: (almost) no weight
    cov = (vec / lam) @ vec.T
    return cov @ Ci @ m, cov


def relevel_map(emap: ElevationMap, omega: F64, centre: F64, var_drop: F64) -> None:
    """Rotate the map's heights by the small world rotation ``omega`` (x, y, rad) about
    ``centre``; ``var_drop`` (2x2, rad^2) is the frame variance removed (each cell loses
    ``g^T var_drop g`` with its lever ``g``, no more than its common part)."""
    X, Y = emap.grid.centers()
    gx, gy = Y - centre[1], -(X - centre[0])  # dz = omega_x (y - cy) - omega_y (x - cx)
    known = emap.n > 0
    emap.z[known] += (omega[0] * gx + omega[1] * gy)[known]
    drop = var_drop[0, 0] * gx * gx + 2.0 * var_drop[0, 1] * gx * gy + var_drop[1, 1] * gy * gy
    drop = np.clip(np.where(known, drop, 0.0), 0.0, np.where(known, emap.var_common, 0.0))
    emap.var -= drop
    emap.var_common -= drop


class MountBias:
    """The estimator of one map (module docstring); cleared with the map."""

    def __init__(self, tilt_sigma_deg: float, attitude_sigma_deg: float, floor_deg: float, gate_chi2: float,
                 apply_ratio: float, min_step_deg: float, level_chi2: float = 0.0, drop_variance: bool = True
                 ) -> None:
        s = np.radians([tilt_sigma_deg, attitude_sigma_deg, attitude_sigma_deg])
        self.P0 = np.diag(s * s)
        self.floor2 = math.radians(floor_deg) ** 2
        self.gate_chi2, self.apply_ratio = gate_chi2, apply_ratio
        self.min_step = math.radians(min_step_deg)
        self.level_chi2, self.drop_variance = level_chi2, drop_variance
        self.clear()

    def clear(self) -> None:
        self.x = np.zeros(3)
        self.P = self.P0.copy()
        self.ref: tuple[float, float] | None = None  # the reference view's yaw and body yaw
        self.centre = np.zeros(3)
        self.F = np.zeros(2)  # the levelling applied to the map so far
        self.frame_cov = np.zeros((2, 2))  # the frame tilt variance the map's cells carry
        self.used, self.refused = 0, 0

    def reference(self, pose: CameraPose, body_yaw: float, pose_cov: F64) -> None:
        """The view that began the map: its yaw, camera centre and attitude covariance."""
        if self.ref is None and math.isfinite(body_yaw):
            self.ref = (view_yaw(pose), body_yaw)
            self.centre = np.asarray(pose.t, np.float64).copy()
            self.frame_cov = np.asarray(pose_cov, np.float64)[:2, :2].copy()

    def _relative(self, pose: CameraPose, body_yaw: float) -> F64:
        assert self.ref is not None
        return design(*self.ref) - design(view_yaw(pose), body_yaw)

    def update(self, pose: CameraPose, body_yaw: float, tilt: F64, cov: F64) -> str:
        """A registered view's total tilt correction ``tilt`` (world x, y, rad) with its 2x2
        covariance relative to the map: ``""`` when used, else why it was refused."""
        tilt, cov = np.asarray(tilt, np.float64), np.asarray(cov, np.float64)
        if self.ref is None:
            return "no reference view"
        if not math.isfinite(body_yaw) or not np.isfinite(pose.R).all():
            return "no body yaw"
        if tilt.shape != (2,) or cov.shape != (2, 2) or not (np.isfinite(tilt).all() and np.isfinite(cov).all()):
            self.refused += 1
            return "correction or covariance not finite"
        R = 0.5 * (cov + cov.T) + self.floor2 * np.eye(2)
        if np.linalg.eigvalsh(R)[0] <= 0.0:
            self.refused += 1
            return "covariance not positive definite"
        Hd = self._relative(pose, body_yaw)
        r = tilt - self.F - Hd @ self.x
        S = Hd @ self.P @ Hd.T + R
        m2 = float(r @ np.linalg.solve(S, r))
        if not m2 <= self.gate_chi2:
            self.refused += 1
            return f"inconsistent (chi2 {m2:.1f})"
        K = self.P @ Hd.T @ np.linalg.inv(S)
        self.x = self.x + K @ r
        IKH = np.eye(3) - K @ Hd
        P = IKH @ self.P @ IKH.T + K @ R @ K.T  # Joseph form: stays symmetric positive
        self.P = 0.5 * (P + P.T)
        self.used += 1
        return ""

    def frame(self) -> tuple[F64, F64]:
        """The map frame's tilt error ``e_ref`` (world x, y, rad) and its covariance."""
        if self.ref is None:
            return np.zeros(2), np.zeros((2, 2))
        H = design(*self.ref)
        return H @ self.x, H @ self.P @ H.T

    def confident(self) -> bool:
        if self.ref is None or self.used == 0:
            return False
        H = design(*self.ref)
        return float(np.trace(H @ self.P @ H.T)) <= self.apply_ratio**2 * float(np.trace(H @ self.P0 @ H.T))

    def predicted(self, pose: CameraPose, body_yaw: float) -> F64 | None:
        """The total tilt correction a view is expected to need (world x, y, rad), or None
        before the estimate is applied."""
        if self.ref is None or not self.confident() or not math.isfinite(body_yaw):
            return None
        return self._relative(pose, body_yaw) @ self.x + self.F

    def level(self, emap: ElevationMap) -> Levelling | None:
        """Level the map when the estimate is confident and its frame correction moved by
        ``min_step`` or more since the last levelling; the levelling, or None."""
        if not self.confident():
            return None
        e, C = self.frame()
        if not np.any(self.F) and not float(e @ np.linalg.solve(C, e)) >= self.level_chi2:
            return None  # no frame error told from the estimate's own noise: nothing invented
        omega = -e - self.F
        if float(np.abs(omega).max()) < self.min_step:
            return None
        drop = self.frame_cov - C
        lam, vec = np.linalg.eigh(0.5 * (drop + drop.T))
        drop = (vec * np.maximum(lam, 0.0)) @ vec.T  # only what the estimate removed
        if not self.drop_variance:
            drop = np.zeros((2, 2))
        relevel_map(emap, omega, self.centre, drop)
        self.F = -e
        self.frame_cov = self.frame_cov - drop
        return Levelling(omega, self.centre.copy(), np.sqrt(np.maximum(np.diag(C), 0.0)), self.x.copy())

    def summary(self, enabled: bool) -> MountBiasSummary:
        _, C = self.frame()
        return {
            "enabled": enabled,
            "estimate_deg": {n: round(math.degrees(float(v)), 5) for n, v in zip(NAMES, self.x, strict=True)},
            "sigma_deg": {n: round(math.degrees(math.sqrt(max(float(v), 0.0))), 5)
                          for n, v in zip(NAMES, np.diag(self.P), strict=True)},
            "views_used": self.used, "views_refused": self.refused,
            "levelled": bool(np.any(self.F)),
            "frame_correction_deg": [round(math.degrees(float(v)), 5) for v in self.F],
            "frame_sigma_deg": [round(math.degrees(math.sqrt(max(float(v), 0.0))), 5) for v in np.diag(C)],
        }

    # -- checkpoint (a resumed mission) -------------------------------------------------------
    def state(self) -> MountBiasState:
        return {"x": self.x.tolist(), "P": self.P.tolist(), "ref": None if self.ref is None else list(self.ref),
                "centre": self.centre.tolist(), "F": self.F.tolist(), "frame_cov": self.frame_cov.tolist(),
                "used": self.used, "refused": self.refused}

    def restore(self, state: Mapping[str, object]) -> None:
        """From :meth:`state` (an older checkpoint without it: a fresh estimate)."""
        self.clear()
        if "x" not in state:
            return
        ref = state.get("ref")
        self.x = np.asarray(state["x"], np.float64).reshape(3)
        self.P = np.asarray(state["P"], np.float64).reshape(3, 3)
        self.ref = None if not isinstance(ref, list) else (float(ref[0]), float(ref[1]))
        self.centre = np.asarray(state["centre"], np.float64).reshape(3)
        self.F = np.asarray(state["F"], np.float64).reshape(2)
        self.frame_cov = np.asarray(state["frame_cov"], np.float64).reshape(2, 2)
        used, refused = state.get("used", 0), state.get("refused", 0)
        self.used = used if isinstance(used, int) else 0
        self.refused = refused if isinstance(refused, int) else 0
