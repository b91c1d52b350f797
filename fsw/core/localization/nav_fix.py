"""The registration's correction fed back into the rover's own pose estimate (docs/algorithm.md
§5, §5.1: the map's "known spatial points" localize the rover, not only the view).

A registered view corrects its camera pose by ``d = (dtheta, dt)`` (``fsw.core.localization.localization``
convention: a small rotation about the world axes through the camera centre ``c``, then a
translation). Of that, odometry integrated yaw, x, y and the body height (the attitude sensor
gives roll and pitch afresh at every view), so that part is the dead-reckoning error at the
view: the rover's pose estimate takes it as a rigid motion of the world about ``c``,

    b' = Rz(dyaw) (b - c) + c + dt,   yaw' = yaw + dyaw,   z' = z + dt_z,

which moves the camera centre computed from the corrected body pose to exactly ``c + dt``
(the mast offset turns with the body) and its rotation to ``Rz(dyaw) R``. The body's
covariance is the correction's, carried by that lever: ``db = dt + [e_z]x (b - c) dyaw``.
Where the terrain did not constrain x, y or yaw, the registration's posterior keeps their
prior variance (the odometry's), so a fix never claims more than the map showed.

What is left of the correction once the odometry holds its dead-reckoned part is the roll and
pitch residual, ``exp(dtheta_res) = exp(dtheta) Rz(-dyaw)``, ``dt_res = 0``
(:func:`residual_correction`): further views from the same station start from it.

The geofence and the planner then work in the map's frame, where the edge and the known
ground are, instead of in one that drifted away from it (issue 13: 0.38 m after a long drive
across a slope put a wheel on unknown ground).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from fsw.core.localization.localization import so3_exp, so3_log

F64 = NDArray[np.float64]
DEAD_RECKONED = [2, 3, 4, 5]  # yaw, x, y, z of a 6-vector (dtheta, dt): what odometry integrates


@dataclass(frozen=True)
class NavFix:
    """One correction of the dead-reckoned pose from a registered view: its id (counting from
    1; ``NavPose.fix_id`` says the last one applied), the fix the view's pose already held
    (``base_id``: the fix applies only to that frame), the view's time and camera centre ``c``
    (m, in that frame), the yaw and translation correction, and their 4x4 covariance over
    ``(dyaw, dx, dy, dz)`` relative to the map."""

    fix_id: int
    base_id: int
    time_s: float
    centre: tuple[float, float, float]
    dyaw: float
    dt: tuple[float, float, float]
    cov: F64

    @staticmethod
    def from_correction(fix_id: int, time_s: float, centre: F64, correction: F64, cov6: F64,
                        base_id: int = 0) -> NavFix:
        """The dead-reckoned part of a camera correction ``(dtheta, dt)`` with covariance ``cov6``."""
        c = np.asarray(correction, np.float64)
        cov = np.asarray(cov6, np.float64)[np.ix_(DEAD_RECKONED, DEAD_RECKONED)]
        cx, cy, cz = (float(v) for v in centre)
        return NavFix(fix_id, base_id, time_s, (cx, cy, cz), float(c[2]), (float(c[3]), float(c[4]), float(c[5])),
                      0.5 * (cov + cov.T))

    def valid(self) -> bool:
        return bool(np.isfinite([self.dyaw, *self.dt, *self.centre]).all()
                    and self.cov.shape == (4, 4) and np.isfinite(self.cov).all())


def apply_to_body(pose: tuple[float, float, float], fix: NavFix) -> tuple[tuple[float, float, float], F64]:
    """The body pose ``(x, y, yaw)`` with the fix applied, and its 3x3 covariance over
    ``(x, y, yaw)`` (the correction's, carried from the camera centre to the body)."""
    x, y, yaw = pose
    cx, cy, _ = fix.centre
    c, s = math.cos(fix.dyaw), math.sin(fix.dyaw)
    lx, ly = x - cx, y - cy
    new = (cx + c * lx - s * ly + fix.dt[0], cy + s * lx + c * ly + fix.dt[1],
           math.remainder(yaw + fix.dyaw, math.tau))
    # d(x, y, yaw) / d(dyaw, dx, dy): the lever of the rotation about c.
    J = np.array([[-ly, 1.0, 0.0], [lx, 0.0, 1.0], [1.0, 0.0, 0.0]])
    cov = J @ fix.cov[:3, :3] @ J.T
    return new, 0.5 * (cov + cov.T)


def residual_correction(correction: F64) -> F64:
    """What is left of a camera correction ``(dtheta, dt)`` once the odometry took its yaw and
    translation: the roll/pitch rotation ``exp(dtheta) Rz(-dyaw)``, no translation."""
    d = np.asarray(correction, np.float64)
    out = np.zeros(6)
    out[:3] = so3_log(so3_exp(d[:3]) @ so3_exp(np.array([0.0, 0.0, -d[2]])))
    return out
