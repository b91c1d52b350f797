"""The motion task's part of a mission checkpoint (docs/hil.md, "Resuming a mission").

What a resumed mission needs from the motion task (``fsw.tasks.motion``): the dead-reckoned
pose and its sigma growth terms (the covariance of ``nav.pose`` is a function of them, from
the last navigation fix, whose id is kept too), the
move counters, the steering held between moves and the motor set-points held, so the wheels
are commanded as before the restart, and the drive encoder baseline. The baseline is kept only
if the first reading after the restart agrees with it within ``RESUME_ENCODER_TOL_RAD`` (the
controllers kept their counts and the rover stood still); otherwise it is taken afresh from
that reading, so a controller that rebooted with its counts at zero is never a jump.
"""

from __future__ import annotations

from typing import Any

import numpy as np


def checkpoint_state(self: Any) -> dict[str, Any]:
    """The odometry (``fsw.core.localization.odometry.Odometry.state``), move counters, held steering and
    motor set-points of the motion task."""
    motors = self._motors()
    a = self.attitude
    attitude = {"roll": a.roll, "pitch": a.pitch, "z_m": a.z_m, "z_sigma_m": a.z_sigma_m,
                "att_cov": a.att_cov.tolist(), "valid": a.valid}
    return {**self.odo.state(), "attitude": attitude, "done": self.done, "aborted": self.aborted,
            "steer_hold": self.steer_hold.tolist(), "fix_id": self.fix_id, "fix_seen": self.fix_seen,
            "setpoints": None if motors is None else dict(motors.setpoints)}


def restore_state(self: Any, st: dict[str, Any]) -> None:
    last = st.get("last_drive")
    x, y, yaw = (float(v) for v in st["pose"])
    self.odo.restore((x, y, yaw), float(st["path_m"]), float(st["turned_rad"]), float(st["yaw_acc"]),
                     None if last is None else np.asarray(last, dtype=np.float64).reshape(4))
    if "base_cov" in st:  # the last navigation fix (fsw.core.localization.nav_fix)
        lever = st.get("lever", (0.0, 0.0))
        self.odo.restore_correction(np.asarray(st["base_cov"], dtype=np.float64), float(st["path0"]),
                                    float(st["turned0"]), (float(lever[0]), float(lever[1])))
    self.fix_id, self.fix_seen = int(st.get("fix_id", 0)), int(st.get("fix_seen", 0))
    att = st.get("attitude")
    if att is not None:  # the attitude sensor's last reading and the dead-reckoned body height
        a = self.attitude
        a.roll, a.pitch, a.z_m, a.z_sigma_m = (float(att[k]) for k in ("roll", "pitch", "z_m", "z_sigma_m"))
        a.att_cov = np.asarray(att["att_cov"], dtype=np.float64).reshape(2, 2)
        a.valid = bool(att["valid"])
    self.done, self.aborted = int(st["done"]), int(st["aborted"])
    self.steer_hold = np.asarray(st["steer_hold"], dtype=np.float64).reshape(4)
    motors = self._motors()
    if motors is not None and st["setpoints"] is not None:  # hold what was held (wheels still)
        for axis, sp in st["setpoints"].items():
            motors.set_setpoint(axis, None if sp is None else float(sp))
