"""The motion task's part of a mission checkpoint (docs/hil.md, "Resuming a mission").

What a resumed mission needs from the motion task (``fsw.tasks.motion``): the dead-reckoned
pose and its sigma growth terms (the covariance of ``nav.pose`` is a function of them, from
the last navigation fix, whose id is kept too), the
move counters, the steering held between moves and the motor set-points held, so the wheels
are commanded as before the restart, and the drive encoder baseline. The baseline is kept only
if the first reading after the restart agrees with it within ``RESUME_ENCODER_TOL_RAD`` (the
controllers kept their counts and the rover stood still); otherwise it is taken afresh from
that reading, so a controller that rebooted with its counts at zero is never a jump.

:class:`MotionSection` is that state, typed, with its JSON form: the odometry's keys
(``Odometry.state``) at the top level beside the task's own, as checkpoints have always
stored them. Keys added later (``attitude``, ``fix_id``, ``fix_seen``, the navigation fix's
``base_cov``/``path0``/``turned0``/``lever``) are optional, so older checkpoints still load.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from fsw.core.localization.attitude import AttitudeTracker
from fsw.core.localization.odometry import Odometry
from fsw.tasks.state_json import (
    JsonObject,
    StateError,
    as_float,
    as_object,
    floats,
    get_bool,
    get_float,
    get_int,
    get_opt_object,
    matrix,
    pose3,
)

_OWN = ("attitude", "done", "aborted", "steer_hold", "fix_id", "fix_seen", "setpoints")


@dataclass(frozen=True)
class AttitudeSection:
    """The attitude sensor's last reading and the dead-reckoned body height."""

    roll: float
    pitch: float
    z_m: float
    z_sigma_m: float
    att_cov: tuple[tuple[float, float], tuple[float, float]]
    valid: bool

    @classmethod
    def of(cls, a: AttitudeTracker) -> AttitudeSection:
        c = np.asarray(a.att_cov, dtype=np.float64).reshape(2, 2)
        return cls(a.roll, a.pitch, a.z_m, a.z_sigma_m,
                   ((float(c[0, 0]), float(c[0, 1])), (float(c[1, 0]), float(c[1, 1]))), bool(a.valid))

    def apply(self, a: AttitudeTracker) -> None:
        a.roll, a.pitch, a.z_m, a.z_sigma_m = self.roll, self.pitch, self.z_m, self.z_sigma_m
        a.att_cov = np.asarray(self.att_cov, dtype=np.float64).reshape(2, 2)
        a.valid = self.valid

    def to_json(self) -> JsonObject:
        return {"roll": self.roll, "pitch": self.pitch, "z_m": self.z_m, "z_sigma_m": self.z_sigma_m,
                "att_cov": [list(r) for r in self.att_cov], "valid": self.valid}

    @classmethod
    def from_json(cls, d: JsonObject) -> AttitudeSection:
        (a, b), (c, e) = matrix(d.get("att_cov"), "attitude.att_cov", 2, 2)
        return cls(get_float(d, "roll"), get_float(d, "pitch"), get_float(d, "z_m"), get_float(d, "z_sigma_m"),
                   ((a, b), (c, e)), get_bool(d, "valid"))


@dataclass(frozen=True)
class NavFixTerms:
    """The dead reckoning's state at its last navigation fix (``Odometry.restore_correction``)."""

    base_cov: NDArray[np.float64]
    path0: float
    turned0: float
    lever: tuple[float, float]
    frame_cov: NDArray[np.float64] | None = None  # the corrections' sum (older checkpoints: None)


@dataclass(frozen=True)
class MotionSection:
    """The motion task's checkpoint section (module docstring)."""

    odometry: JsonObject  # Odometry.state(): written as it gives it, read back field by field
    attitude: AttitudeSection | None
    done: int
    aborted: int
    steer_hold: tuple[float, float, float, float]
    fix_id: int
    fix_seen: int
    setpoints: dict[str, float | None] | None

    def to_json(self) -> JsonObject:
        return {**self.odometry, "attitude": None if self.attitude is None else self.attitude.to_json(),
                "done": self.done, "aborted": self.aborted, "steer_hold": list(self.steer_hold),
                "fix_id": self.fix_id, "fix_seen": self.fix_seen,
                "setpoints": None if self.setpoints is None else dict(self.setpoints)}

    @classmethod
    def from_json(cls, d: JsonObject) -> MotionSection:
        """The section of a checkpoint, validated (``StateError`` naming the key if not usable)."""
        odometry = {k: v for k, v in d.items() if k not in _OWN}
        pose3(odometry.get("pose"), "pose")  # the fields the odometry needs, checked here
        for key in ("path_m", "turned_rad", "yaw_acc"):
            get_float(odometry, key)
        att = get_opt_object(d, "attitude")
        sp = get_opt_object(d, "setpoints")
        steer = floats(d.get("steer_hold"), "steer_hold", 4)
        return cls(
            odometry=odometry,
            attitude=None if att is None else AttitudeSection.from_json(att),
            done=get_int(d, "done"), aborted=get_int(d, "aborted"),
            steer_hold=(steer[0], steer[1], steer[2], steer[3]),
            fix_id=get_int(d, "fix_id", 0), fix_seen=get_int(d, "fix_seen", 0),
            setpoints=None if sp is None else {k: None if v is None else as_float(v, f"setpoints.{k}")
                                                for k, v in sp.items()},
        )

    def pose(self) -> tuple[float, float, float]:
        return pose3(self.odometry["pose"], "pose")

    def last_drive(self) -> NDArray[np.float64] | None:
        last = self.odometry.get("last_drive")
        return None if last is None else np.asarray(floats(last, "last_drive", 4), dtype=np.float64)

    def fix_terms(self) -> NavFixTerms | None:
        """The last navigation fix's terms, if the section has them (``fsw.core.localization.nav_fix``)."""
        o = self.odometry
        if "base_cov" not in o:
            return None
        lever = floats(o.get("lever", [0.0, 0.0]), "lever", 2)
        frame = o.get("frame_cov")
        return NavFixTerms(np.asarray(matrix(o["base_cov"], "base_cov", 3, 3), dtype=np.float64),
                           get_float(o, "path0"), get_float(o, "turned0"), (lever[0], lever[1]),
                           None if frame is None else np.asarray(matrix(frame, "frame_cov", 3, 3), dtype=np.float64))

    def apply_odometry(self, odo: Odometry) -> None:
        o = self.odometry
        odo.restore(self.pose(), get_float(o, "path_m"), get_float(o, "turned_rad"), get_float(o, "yaw_acc"),
                    self.last_drive())
        fix = self.fix_terms()
        if fix is not None:
            odo.restore_correction(fix.base_cov, fix.path0, fix.turned0, fix.lever, fix.frame_cov)


def section(v: object) -> MotionSection:
    """A stored motion section (any JSON value) as a :class:`MotionSection`, or ``StateError``."""
    try:
        return MotionSection.from_json(as_object(v, "motion"))
    except (KeyError, TypeError, ValueError) as exc:
        if isinstance(exc, StateError):
            raise
        raise StateError(f"motion section: {type(exc).__name__}: {exc}") from None
