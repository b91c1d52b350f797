"""The winches as the Cliff-bot's mission drives them (docs/team.md, "The Cliff-bot's flight code"):
the rates that bring both tethers to a set-point together (:func:`winch_rates`), and the tension
guard on their load cells (:func:`near_limit`, docs/algorithm.md §8, "The measured tensions").
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from fsw.comm.team.team_can import WINCHES
from fsw.core.geometry import normal_from_attitude
from fsw.core.team.climber_ground import ClimberConfig
from fsw.core.team.tether import TetherConfig
from fsw.drivers.cliffbot_devices import CliffbotDevices
from fsw.sections import CliffbotMissionConfig

F64 = NDArray[np.float64]


def winch_rates(err: F64, cfg: CliffbotMissionConfig) -> tuple[tuple[float, float], tuple[float, float]]:
    """The winches' rates (m/s) for the length errors ``err`` (set-point minus paid out, per
    winch), proportional (``gain_per_s``) and paced so both arrive together under
    ``max_rate_mps``, and the wheels' rate (rad/s) that rolls with the tethers' motion."""
    rates = cfg.gain_per_s * np.asarray(err, float)
    peak = float(np.max(np.abs(rates)))
    if peak > cfg.max_rate_mps:
        rates *= cfg.max_rate_mps / peak  # both tethers paced to arrive together
    v = float(np.linalg.norm(rates)) / max(cfg.wheel_radius_m, 1e-3)
    return (float(rates[0]), float(rates[1])), (v, v)


def tilt_deg(roll_deg: float, pitch_deg: float) -> float:
    """The slope of the ground under the body, from its attitude sensor's roll and pitch (the
    normal of :func:`fsw.core.geometry.normal_from_attitude`, the sensor's convention)."""
    n = normal_from_attitude(0.0, math.radians(roll_deg), math.radians(pitch_deg))
    return math.degrees(math.acos(max(-1.0, min(1.0, float(n[2])))))


def near_limit(dev: CliffbotDevices, cfg: CliffbotMissionConfig, tcfg: TetherConfig, ccfg: ClimberConfig) -> str:
    """The tension guard: the limit (``"slack"``, ``"over-tension"``) a winch's measured tension
    is within ``tension_guard_n`` of, ``""`` when none is (or the guard is off, or a load cell has
    not reported a finite value). The upper limit counts everywhere; the lower where the body
    stands on ground steeper than ``free_slope_deg`` (its attitude sensor's roll and pitch; with
    none reported, taken as steep), where the tethers alone hold it."""
    g = cfg.tension_guard_n
    if g <= 0.0:
        return ""
    t = [w.tension_n for w in (dev.winch.get(WINCHES[0]), dev.winch.get(WINCHES[1])) if w is not None]
    if not t or not all(math.isfinite(v) for v in t):
        return ""
    if max(t) > tcfg.t_max_n - g:
        return "over-tension"
    att = dev.attitude
    steep = att is None or tilt_deg(att.roll_deg, att.pitch_deg) > ccfg.free_slope_deg
    if steep and min(t) < tcfg.t_min_n + g:
        return "slack"
    return ""
