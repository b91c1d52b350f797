"""The Cliff-bot's navigation: an EKF on its place and heading on the face (docs/team.md).

State ``(x, y, yaw, b_a, b_b)``: the place and heading (world metres, rad), :attr:`CliffbotNav.s`
with its covariance :attr:`CliffbotNav.P`, and the taut-tether model's error in each tether's
length, ``b``. That error is not noise: it comes from the map under the Cliff-bot's footprint
(the plane the body stands on carries its attachment point), so it holds while the Cliff-bot
stands and changes as it moves. Averaged as noise over hundreds of length readings it would
make the estimate sure of a place centimetres off; as a state, a Gauss-Markov process in the
distance driven (sigma ``length_bias_sigma_m``, correlation length ``length_bias_corr_m``),
the lengths alone cannot make the place surer than the model is, and a fix, which pins the
place, calibrates the model for the lengths that follow. Sources:

* **wheel odometry** (prediction): a wheel-path increment ``d`` moves the Cliff-bot
  ``d cos(pitch)`` horizontally along the IMU's heading (pitch from the IMU); the process
  noise is a random walk in ``d`` (on a face the tethers, not the wheels, choose the
  direction) and in time;
* **tether-length kinematics** (update): the two paid-out lengths the winches report equal
  the taut tether lengths at the Cliff-bot's place on the map it received
  (:func:`fsw.core.team.tether.tether_state`) plus the model's error ``b``; Jacobian by
  central differences over one map cell; the noise is the winches' length accuracy plus the
  map's (a tether over a coarse map is only as long as the map says);
* **IMU heading** (update): the attitude sensor's yaw;
* **the RECON-bot's fiducial fix** (update, :meth:`CliffbotNav.fix`): position and heading
  with the fix's own covariance, gated by its normalised innovation squared (NIS) against
  the chi-square bound of 3 degrees of freedom: a fix that disagrees with the estimate beyond
  both covariances is refused (the mission stops safe and says so).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from fsw.core.geometry import MapGrid, wrap_angle
from fsw.core.team.tether import TetherConfig, ZMap, tether_states
from fsw.framework.params import param

F64 = NDArray[np.float64]
CHI2_3DOF = {0.95: 7.815, 0.99: 11.345, 0.999: 16.266}


@dataclass(frozen=True)
class NavConfig:
    length_sigma_m: float = param(0.02, lo=1e-4, hi=1.0, units="m", doc="tether-length measurement noise")
    yaw_sigma_deg: float = param(2.0, lo=0.01, hi=90.0, units="deg", doc="IMU heading noise")
    odo_sigma_frac: float = param(0.5, lo=0.0, hi=1.0, units="m/sqrt(m)",
                                  doc="wheel-odometry noise: its 1-sigma after 1 m driven (a random walk)")
    drift_mps: float = param(0.005, lo=0.0, hi=1.0, units="m/sqrt(s)", doc="process noise per sqrt(second)")
    yaw_rate_per_m: float = param(1.0, lo=0.0, hi=10.0, units="rad/sqrt(m)",
                                  doc="heading noise: its 1-sigma after 1 m driven (a random walk)")
    fix_gate: float = param(0.999, lo=0.9, hi=0.9999, doc="chi-square probability of the fix gate (3 dof)")
    init_sigma_m: float = param(0.1, lo=1e-3, hi=10.0, units="m")
    length_bias_sigma_m: float = param(0.03, lo=0.0, hi=1.0, units="m",
                                       doc="the taut-tether model's length error on the map (1-sigma, each tether)")
    length_bias_corr_m: float = param(0.3, lo=0.01, hi=100.0, units="m",
                                      doc="distance driven over which that error changes (its correlation length)")


class CliffbotNav:
    """The EKF; :attr:`s` and :attr:`P` are the place and heading estimate, :attr:`bias` the
    length model's error and :attr:`P_full` the covariance of all five states."""

    def __init__(self, xy: F64, yaw: float, cfg: NavConfig) -> None:
        self.cfg = cfg
        self.x = np.zeros(5)
        self.P_full = np.zeros((5, 5))
        self.reset(np.asarray(xy, float), yaw, np.diag([cfg.init_sigma_m ** 2, cfg.init_sigma_m ** 2,
                                                         math.radians(10.0) ** 2]))
        self.last_nis: float | None = None

    @property
    def s(self) -> F64:
        """``(x, y, yaw)``."""
        return self.x[:3].copy()

    @property
    def P(self) -> F64:
        """The covariance of :attr:`s`."""
        return self.P_full[:3, :3].copy()

    @property
    def xy(self) -> F64:
        return self.x[:2].copy()

    @property
    def bias(self) -> F64:
        """The taut-tether model's error in each tether's length (m), measured minus model."""
        return self.x[3:].copy()

    def predict(self, wheel_m: float, pitch_deg: float, dt: float, heading: float | None = None) -> None:
        """Wheel odometry: ``wheel_m`` along the ground in the direction ``heading`` (the IMU's,
        an input: the state's yaw is not coupled to the place). On a face the tethers, not the
        wheels, choose where the body goes, so it may slide sideways to its heading: the
        process noise, across and along alike, is a random walk of ``odo_sigma_frac`` per
        square root of a metre driven. The length model's error decorrelates over the distance
        driven."""
        c = self.cfg
        d = wheel_m * math.cos(math.radians(pitch_deg))
        yaw = self.x[2] if heading is None else heading
        self.x[:2] += d * np.array([math.cos(yaw), math.sin(yaw)])
        # Random walks in the distance driven (variance per metre), so the noise of a drive does
        # not depend on how many steps it is read in, as the length model's error does not.
        q = c.odo_sigma_frac ** 2 * abs(wheel_m) + c.drift_mps ** 2 * max(dt, 0.0)
        q_yaw = c.yaw_rate_per_m ** 2 * abs(wheel_m) + 1e-5 * max(dt, 0.0)  # the body turns as it moves
        phi = math.exp(-abs(wheel_m) / c.length_bias_corr_m)
        f = np.diag([1.0, 1.0, 1.0, phi, phi])
        self.x[3:] *= phi
        q_b = c.length_bias_sigma_m ** 2 * (1.0 - phi * phi)
        self.P_full = f @ self.P_full @ f.T + np.diag([q, q, q_yaw, q_b, q_b])

    def _update(self, r: F64, h: F64, rcov: F64) -> float:
        s_cov = h @ self.P_full @ h.T + rcov
        k = self.P_full @ h.T @ np.linalg.inv(s_cov)
        self.x = self.x + k @ r
        self.x[2] = wrap_angle(float(self.x[2]))
        i_kh = np.eye(5) - k @ h
        self.P_full = i_kh @ self.P_full @ i_kh.T + k @ rcov @ k.T  # Joseph form
        return float(r @ np.linalg.solve(s_cov, r))

    def lengths(self, lengths_m: tuple[float, float], z: ZMap, grid: MapGrid, anchors: F64,
                tcfg: TetherConfig, footprint_m: float) -> bool:
        """Update on the winches' paid-out lengths; False when the map cannot say (unknown ground)."""
        if not all(math.isfinite(v) for v in lengths_m):
            return False
        e = grid.cell
        # Here and a cell either way along x and y, in one batch (central differences).
        around = np.array([[0.0, 0.0], [e, 0.0], [-e, 0.0], [0.0, e], [0.0, -e]])
        st, *probes = tether_states(z, grid, anchors, self.x[:2] + around, tcfg, footprint_m)
        if st is None:
            return False
        hmat = np.zeros((2, 5))
        for k in range(2):
            hi, lo = probes[2 * k], probes[2 * k + 1]
            if hi is None or lo is None:
                return False
            hmat[:, k] = (np.asarray(hi.lengths_m) - np.asarray(lo.lengths_m)) / (2 * e)
        hmat[:, 3:] = np.eye(2)  # measured = model + the model's error
        r = np.asarray(lengths_m, float) - np.asarray(st.lengths_m) - self.x[3:]
        sig2 = self.cfg.length_sigma_m ** 2 + (0.5 * grid.cell) ** 2
        self._update(r, hmat, np.eye(2) * sig2)
        return True

    def heading(self, yaw_deg: float) -> None:
        if not math.isfinite(yaw_deg):
            return
        r = np.array([wrap_angle(math.radians(yaw_deg) - float(self.x[2]))])
        h = np.zeros((1, 5))
        h[0, 2] = 1.0
        self._update(r, h, np.array([[math.radians(self.cfg.yaw_sigma_deg) ** 2]]))

    def fix(self, xy: F64, yaw: float, cov3: F64) -> tuple[bool, float]:
        """A fiducial fix of ``(x, y, yaw)`` with its 3x3 covariance: (accepted, NIS)."""
        r = np.array([xy[0] - self.x[0], xy[1] - self.x[1], wrap_angle(yaw - float(self.x[2]))])
        h = np.eye(3, 5)
        s_cov = self.P_full[:3, :3] + cov3
        try:
            nis = float(r @ np.linalg.solve(s_cov, r))
        except np.linalg.LinAlgError:
            return False, math.inf
        self.last_nis = nis
        if not math.isfinite(nis) or nis > CHI2_3DOF.get(self.cfg.fix_gate, CHI2_3DOF[0.999]):
            return False, nis
        self._update(r, h, cov3)
        return True, nis

    def reset(self, xy: F64, yaw: float, cov3: F64) -> None:
        """Take a fix as the estimate (the recovery after a refused fix, on command); the length
        model's error starts again from its prior."""
        self.x = np.array([float(xy[0]), float(xy[1]), float(yaw), 0.0, 0.0])
        self.P_full = np.zeros((5, 5))
        self.P_full[:3, :3] = np.asarray(cov3, float)
        self.P_full[3:, 3:] = np.eye(2) * self.cfg.length_bias_sigma_m ** 2


class Navigator:
    """The navigation's sans-I/O step around :class:`CliffbotNav` (the ``cb_nav`` task, or a
    bench's loop): wheel odometry between two readings of the wheels' path, the IMU's
    heading, the winches' lengths on the map the mission plans on (:meth:`set_map`), the
    RECON-bot's fixes (gated) and the resets the mission asks for."""

    def __init__(self, xy: F64, yaw: float, cfg: NavConfig, anchors: F64, tcfg: TetherConfig,
                 footprint_m: float) -> None:
        self.nav = CliffbotNav(xy, yaw, cfg)
        self.anchors, self.tcfg, self.footprint_m = np.asarray(anchors, float), tcfg, footprint_m
        self.z: ZMap | None = None
        self.grid: MapGrid | None = None
        self.last_wheel: float | None = None

    def set_map(self, z: ZMap, grid: MapGrid) -> None:
        self.z, self.grid = z, grid

    def step(self, wheel_path_m: float | None, pitch_deg: float | None, yaw_deg: float | None,
             lengths_m: tuple[float, float] | None, dt: float) -> None:
        """One navigation step: ``wheel_path_m`` the wheels' mean path so far (m), the IMU's pitch
        and heading (deg), the winches' paid-out lengths; None for what is not known."""
        if wheel_path_m is not None and math.isfinite(wheel_path_m):
            # (the first reading is the baseline: no distance yet, but the time has passed)
            d = 0.0 if self.last_wheel is None else wheel_path_m - self.last_wheel
            self.nav.predict(d, pitch_deg if pitch_deg is not None else 0.0, dt,
                             math.radians(yaw_deg) if yaw_deg is not None else None)
            self.last_wheel = wheel_path_m
        if yaw_deg is not None:
            self.nav.heading(yaw_deg)
        if self.z is not None and self.grid is not None and lengths_m is not None:
            self.nav.lengths(lengths_m, self.z, self.grid, self.anchors, self.tcfg, self.footprint_m)

    def fix(self, xy: F64, yaw: float, cov3: F64) -> tuple[bool, float]:
        return self.nav.fix(xy, yaw, cov3)

    def reset(self, s: F64, cov: F64) -> None:
        """The estimate becomes ``s = (x, y, yaw)`` with covariance ``cov`` (a recovery, a checkpoint)."""
        s = np.asarray(s, float).reshape(3)
        self.nav.reset(s[:2], float(s[2]), np.asarray(cov, float).reshape(3, 3))
