"""The configuration sections the flight tasks own: ``[capture]``, ``[mission]``.

They are declared here, in the settings layer beside ``fsw.settings`` that assembles them, so
the whole configuration sits below the tasks: a task imports the settings, never the other
way round (``tests/test_structure.py`` holds the rule). Every field is validated on load
(``fsw.framework.params``).
"""

from __future__ import annotations

from dataclasses import dataclass

from fsw.core.planning.planners import METHODS
from fsw.framework.params import param


@dataclass(frozen=True)
class CaptureConfig:
    """Camera pose uncertainty from the mast (config ``[capture]``)."""

    joint_sigma_deg: float = param(0.2, lo=0.0, hi=10.0, units="deg", doc="pan and tilt encoder sigma")
    lift_sigma_m: float = param(0.002, lo=0.0, hi=0.1, units="m", doc="lift sigma")
    unknown_attitude_sigma_deg: float = param(
        5.0, lo=0.1, hi=90.0, units="deg", doc="roll/pitch sigma while the attitude sensor is faulted or absent"
    )
    z_sigma_per_m: float = param(
        0.02, lo=0.0, hi=1.0, units="m/m", doc="dead-reckoned body height: sigma per metre climbed"
    )


@dataclass(frozen=True, kw_only=True)
class MissionConfig:
    """The mapping mission (config ``[mission]``)."""

    method: str = param("5", choices=METHODS, doc="mapping method of docs/algorithm.md §7 (1-5, oracle)")
    auto_start: bool = param(True, doc="start at boot; otherwise wait for START")
    panorama_pans_deg: tuple[float, ...] = param(
        (-90.0,), lo=-180.0, hi=180.0, units="deg", doc="mast pans of the step-0 panorama"
    )
    panorama_tilt_deg: float = param(-35.0, lo=-90.0, hi=30.0, units="deg")
    panorama_lift_m: float = param(0.5, lo=0.0, hi=2.0, units="m")
    near_pans_deg: tuple[float, ...] = param(
        (90.0, -90.0), lo=-180.0, hi=180.0, units="deg", doc="step 0: pans that map the ground around the rover"
    )
    near_tilt_deg: float = param(-70.0, lo=-90.0, hi=30.0, units="deg", doc="their steep tilt (the turning circle)")
    max_looks_per_move: int = param(
        4, lo=1, hi=20, doc="looks at the unknown ground a refused move would sweep, while each maps some of it"
    )
    park_joints: tuple[float, float, float] = param((0.0, -30.0, 0.0), doc="SAFE mast pose: pan deg, tilt deg, lift m")
    capture_retries: int = param(2, lo=0, hi=20, doc="retries of a pair that did not arrive")
    step_timeout_s: float = param(300.0, lo=1.0, hi=1e5, units="s", doc="longest wait for one request")
    transmit: bool = param(True, doc="send the map to the Cliff-bot at the end")
    transmit_timeout_s: float = param(1800.0, lo=1.0, hi=1e6, units="s",
                                      doc="longest wait for the map's delivery; then SAFE, 'map not delivered'")
    safe_recover_s: float = param(0.0, lo=0.0, hi=1e5, units="s", doc="0: SAFE waits for RESUME")
    safe_clear_faults: bool = param(True, doc="the automatic recovery clears latched motor and mast faults first")
    safe_max_recoveries: int = param(
        3, lo=0, hi=1000, doc="automatic recoveries in a row without a completed step before SAFE is final"
    )
