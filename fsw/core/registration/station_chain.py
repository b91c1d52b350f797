"""The chain of registered stations: where each view's registration starts from, what its
merged pose covariance is, and the correction fed back to the rover's pose estimate
(docs/algorithm.md §5, §5.1; the perception task's bookkeeping, kept pure here).

- The first view of a map is its reference; its pose covariance is the map's frame error
  (``anchor_cov``).
- A view from the station of the last registered view (same camera centre: the rover has
  not moved; pan and tilt turn the head about it) starts from that view's correction: the
  body pose error it found holds until the rover moves.
- A view from a new station starts from the last station's dead-reckoning correction with
  the odometry covariance grown since (``carried_prior``), unless that correction was fed
  back into the odometry (``fsw.core.localization.nav_fix``): then the view's own pose already holds it and
  only the roll/pitch residual is carried at the same station.
- A correction is fed back once a second registered view from the same station confirms it
  (its own fit, started from the first view's correction, moves it by less than the 0.1 %
  chi-square of both covariances): one view alone may be a false minimum of a weakly
  constrained fit, and fed back it would move the rover and every later view.
- A registered view's merged covariance is its correction's (relative to the map) plus the
  frame error of the map it was aligned to: the anchor's, and with ``carry`` each station's
  registration error added to the next (a chain).

Which frame a view's pose is in is told by ``NavPose.fix_id`` (the last fix the odometry
applied) carried on the camera frame: a fix is relative to the frame of the view that found
it (``base_id``), and the motion task applies it only on that frame.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from fsw.core.geometry import CameraPose
from fsw.core.localization.localization import so3_exp, so3_log
from fsw.core.localization.nav_fix import DEAD_RECKONED, NavFix, residual_correction
from fsw.core.map.reference_frames import about
from fsw.core.registration.registration import Registration, RegistrationConfig, apply_correction, inflate

F64 = NDArray[np.float64]
STATION_TOL_M = 0.03  # views whose camera centres are this close share a station
CONFIRM_CHI2 = 18.47  # chi-square, 4 dof, 0.1 %: a second view confirms a station's correction


@dataclass(frozen=True)
class StationFix:
    """What the last registered station found: its camera centre, its total correction
    ``(dtheta, dt)`` (§5 convention, about that centre), the correction's covariance and the
    view's prior pose covariance there (odometry, attitude, mast), and the frame error of the
    map it was aligned to (``frame_cov``: the views before it placed that part of the map).
    ``base_id`` is the navigation fix the view's pose already held (``NavPose.fix_id``) and
    ``fix_id`` the one this station's correction was fed back as (0: none; ``fsw.core.localization.nav_fix``).
    ``ref_cov`` is the part of ``cov`` from the reference cells' own placement (absolute, not
    relative to the map; ``fsw.core.map.reference_frames``)."""

    centre: F64
    correction: F64
    cov: F64
    pose_cov: F64
    frame_cov: F64
    base_id: int = 0
    fix_id: int = 0
    ref_cov: F64 = field(default_factory=lambda: np.zeros((6, 6)))


def carried_prior(pose: CameraPose, pose_cov: F64, fix: StationFix) -> tuple[F64, F64]:
    """The prior of a view from a new station (§5.1): the dead-reckoning part of the last
    station's correction carried as a rigid motion of the world, and its covariance.

    Odometry drifts: its yaw, x, y and height errors at the new station are those found at the
    last one plus what the drive since added. The yaw correction turns the world about the
    last camera centre ``c``, so at this view's centre ``t`` the correction is ``(0, 0, dyaw,
    dt + (Rz(dyaw) - I)(t - c))`` with the covariance ``A C A^T`` (``A``: that lever). The drive
    adds the growth of the odometry covariance since then (its dead-reckoned block, clipped
    to positive semidefinite); roll and pitch come fresh from the attitude sensor each view
    and keep the view's own prior. Returns ``(d0, cov)``.
    """
    lever = np.asarray(pose.t, np.float64) - fix.centre
    d0 = np.zeros(6)
    d0[2] = fix.correction[2]
    d0[3:] = fix.correction[3:] + so3_exp(d0[:3]) @ lever - lever
    carried = about(fix.cov, fix.centre, pose.t)
    I = np.ix_(DEAD_RECKONED, DEAD_RECKONED)
    S = np.asarray(pose_cov, np.float64)
    grown = S[I] - np.asarray(fix.pose_cov, np.float64)[I]
    lam, vec = np.linalg.eigh(0.5 * (grown + grown.T))
    grown = (vec * np.maximum(lam, 0.0)) @ vec.T
    out = S.copy()
    out[np.ix_([0, 1], DEAD_RECKONED)] = 0.0  # attitude (sensor) and dead reckoning: independent
    out[np.ix_(DEAD_RECKONED, [0, 1])] = 0.0
    out[I] = grown + carried[I]
    return d0, 0.5 * (out + out.T)


def apply_about(pose: CameraPose, omega: F64, centre: F64) -> CameraPose:
    """The pose moved with the map when the map turns by the small world rotation ``omega``
    (x, y, rad) about ``centre`` (``fsw.core.registration.mount_bias``)."""
    Rw = so3_exp(np.r_[np.asarray(omega, np.float64)[:2], 0.0])
    return CameraPose(Rw @ pose.R, Rw @ (np.asarray(pose.t, np.float64) - centre) + centre)


@dataclass(frozen=True)
class ViewPrior:
    """Where a view's registration starts: the correction ``d0`` applied to its pose, the
    prior covariance, the frame covariance of the map it will be aligned to, and whether it
    stands at the last registered station."""

    d0: F64
    cov: F64
    frame: F64
    same_station: bool


class StationChain:
    """The registration state of one map (reset with the map)."""

    def __init__(self) -> None:
        self.anchor_cov: F64 | None = None  # pose covariance of the view that began the map
        self.fix: StationFix | None = None  # the last registered station
        self.fixes = 0  # navigation fixes published (the id of the last)

    def clear(self) -> None:
        """A new map (CLEAR_MAP): no reference, no station; fix ids go on counting."""
        self.anchor_cov, self.fix = None, None

    def _fed(self, nav_fix_id: int) -> bool:
        """The view's pose already holds the last station's fed-back correction."""
        return self.fix is not None and self.fix.fix_id > 0 and nav_fix_id >= self.fix.fix_id

    def prior(self, pose: CameraPose, pose_cov: F64, nav_fix_id: int, cfg: RegistrationConfig) -> ViewPrior:
        """The start of a view's registration (module docstring)."""
        zero, fix = np.zeros(6), self.fix
        cov = np.asarray(pose_cov, dtype=np.float64)
        if fix is None:
            return ViewPrior(zero, cov, np.zeros((6, 6)), False)
        fed = self._fed(nav_fix_id)
        aligned = nav_fix_id == fix.base_id  # the same frame as the station's view
        centre = fix.centre + fix.correction[3:] if fed else fix.centre
        if (fed or aligned) and float(np.linalg.norm(pose.t - centre)) < STATION_TOL_M:
            return ViewPrior(residual_correction(fix.correction) if fed else fix.correction, cov,
                             np.zeros((6, 6)), True)
        if not cfg.carry:
            return ViewPrior(zero, cov, np.zeros((6, 6)), False)
        if fed or not aligned:  # nothing left to carry (fed back), or a frame it cannot be carried to
            return ViewPrior(zero, cov, fix.frame_cov, False)
        d0, carried = carried_prior(pose, cov, fix)
        return ViewPrior(d0, carried, fix.frame_cov, False)

    def relevel(self, omega: F64, centre: F64) -> None:
        """The map turned by ``omega`` about ``centre`` (levelled, ``fsw.core.registration.mount_bias``):
        the last station's correction turns with it. A correction fed back keeps its translation
        (the odometry holds it; the next registration finds the height the turn moved)."""
        f = self.fix
        if f is None:
            return
        Rw = so3_exp(np.r_[np.asarray(omega, np.float64)[:2], 0.0])
        rot = so3_log(Rw @ so3_exp(f.correction[:3]))
        t = f.correction[3:] if f.fix_id > 0 else Rw @ (f.centre + f.correction[3:] - centre) + centre - f.centre
        self.fix = replace(f, correction=np.r_[rot, t])

    def reference(self, pose_cov: F64) -> None:
        if self.anchor_cov is None:
            self.anchor_cov = np.asarray(pose_cov, dtype=np.float64)

    def unregistered(self, pose: CameraPose, vp: ViewPrior, reg: Registration,
                     cfg: RegistrationConfig) -> tuple[CameraPose, F64]:
        """A view that could not be registered: its prior pose, the covariance inflated."""
        if vp.d0.any():
            reg.reason += "; the station's correction applied"
            reg.correction = vp.d0
        return apply_correction(pose, vp.d0), inflate(vp.cov + vp.frame, cfg)

    def registered(self, pose: CameraPose, pose_cov: F64, nav_fix_id: int, time_s: float, vp: ViewPrior,
                   reg: Registration, cfg: RegistrationConfig) -> tuple[CameraPose, F64, NavFix | None]:
        """A registered view: its corrected pose, the covariance to merge with, and the
        navigation fix to feed back (None with ``feed_back`` off). ``reg.correction`` becomes
        the total correction relative to the view's own pose."""
        confirmed = self._confirms(vp, reg)
        fixed = apply_correction(apply_correction(pose, vp.d0), reg.correction)
        total = np.r_[so3_log(fixed.R @ pose.R.T), fixed.t - pose.t]
        reg.correction = total
        frame = self.anchor_cov if self.anchor_cov is not None else np.zeros((6, 6))
        if cfg.carry and self.fix is not None:
            frame = self.fix.frame_cov if vp.same_station else self.fix.frame_cov + self.fix.cov
        if reg.ref_cov.any():  # reg.cov holds the reference cells' own placement error: the frame
            frame = np.zeros((6, 6))
        nav: NavFix | None = None
        if cfg.feed_back and confirmed:
            self.fixes += 1
            nav = NavFix.from_correction(self.fixes, time_s, pose.t, total, reg.cov, base_id=nav_fix_id)
        self.fix = StationFix(pose.t.copy(), total, reg.cov, np.asarray(pose_cov, dtype=np.float64), frame,
                              base_id=nav_fix_id, fix_id=0 if nav is None else nav.fix_id,
                              ref_cov=np.asarray(reg.ref_cov, dtype=np.float64).copy())
        return fixed, reg.cov + frame, nav

    def _confirms(self, vp: ViewPrior, reg: Registration) -> bool:
        """A second view from the station agrees with the first: it started from that view's
        correction and moved its dead-reckoned part (yaw, x, y, z) by less than the 0.1 %
        chi-square of both covariances. One view alone never moves the rover's pose: a false
        minimum of a weakly constrained fit (terrain seed 6: 11 deg of yaw, 3 sigma of its
        prior) would otherwise carry into every later view and the geofence."""
        if not vp.same_station or self.fix is None:
            return False
        i = np.ix_(DEAD_RECKONED, DEAD_RECKONED)
        inc = np.asarray(reg.correction, np.float64)[DEAD_RECKONED]
        # relative to the map (both views align to the same cells: their error is common)
        S = np.asarray(reg.cov - reg.ref_cov, np.float64)[i] + self.fix.cov[i] - self.fix.ref_cov[i]
        try:
            m2 = float(inc @ np.linalg.solve(S, inc))
        except np.linalg.LinAlgError:
            return False
        return bool(np.isfinite(m2) and m2 <= CONFIRM_CHI2)

    # -- checkpoint (a resumed mission) -------------------------------------------------------
    def state(self) -> dict[str, Any]:
        f = self.fix
        return {
            "anchor_cov": None if self.anchor_cov is None else self.anchor_cov.tolist(),
            "fix": None if f is None else {
                "centre": f.centre.tolist(), "correction": f.correction.tolist(), "cov": f.cov.tolist(),
                "pose_cov": f.pose_cov.tolist(), "frame_cov": f.frame_cov.tolist(),
                "base_id": f.base_id, "fix_id": f.fix_id, "ref_cov": f.ref_cov.tolist()},
            "fixes": self.fixes,
        }

    def restore(self, state: dict[str, Any]) -> None:
        anchor, fix = state.get("anchor_cov"), state.get("fix")
        self.anchor_cov = None if anchor is None else np.asarray(anchor, dtype=np.float64).reshape(6, 6)
        self.fixes = int(state.get("fixes", 0))
        if isinstance(fix, dict):
            def arr(key: str, shape: tuple[int, ...]) -> F64:
                return np.asarray(fix[key], dtype=np.float64).reshape(shape)

            self.fix = StationFix(arr("centre", (3,)), arr("correction", (6,)), arr("cov", (6, 6)),
                                  arr("pose_cov", (6, 6)), arr("frame_cov", (6, 6)),
                                  int(fix.get("base_id", 0)), int(fix.get("fix_id", 0)),
                                  arr("ref_cov", (6, 6)) if "ref_cov" in fix else np.zeros((6, 6)))
