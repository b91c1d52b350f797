"""The configuration sections the flight tasks own: ``[capture]``, ``[mission]``, and the
Cliff-bot's ``[cliffbot_mission]``, ``[cliffbot_site]``, ``[cliffbot_bus]``, ``[cliffbot_sensing]``.

They are declared here, in the settings layer beside ``fsw.settings`` that assembles them, so
the whole configuration sits below the tasks: a task imports the settings, never the other
way round (``tests/test_structure.py`` holds the rule). Every field is validated on load
(``fsw.framework.params``).
"""

from __future__ import annotations

import math
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


@dataclass(frozen=True)
class CliffbotMissionConfig:
    """The Cliff-bot's mission (config ``[cliffbot_mission]``; ``fsw.tasks.cliffbot_mission``)."""

    max_rate_mps: float = param(0.12, lo=0.005, hi=2.0, units="m/s", doc="winch rate limit the mission commands")
    gain_per_s: float = param(1.5, lo=0.05, hi=20.0, units="1/s", doc="length error to rate")
    length_tol_m: float = param(0.02, lo=0.001, hi=0.5, units="m", doc="a waypoint is reached within this")
    waypoint_every: int = param(3, lo=1, hi=50, doc="every n-th lattice node of a path is a waypoint")
    dwell_s: float = param(2.0, lo=0.0, hi=600.0, units="s", doc="time at a target (instrument placement)")
    fix_timeout_s: float = param(30.0, lo=0.5, hi=600.0, units="s", doc="no fix this long after asking: link lost")
    return_home: bool = param(True, doc="climb back to the start after the last target")
    wheel_radius_m: float = param(0.06, lo=0.01, hi=1.0, units="m")
    track_margin_m: float = param(0.08, lo=0.0, hi=2.0, units="m",
                                  doc="paths keep this clear of hazards where the ground leaves room (a soft cost)")
    margin_sigmas: float = param(2.326, lo=0.0, hi=10.0,
                                 doc="the length errors the tethers must hold the body at, and the off-the-way "
                                     "test, in standard deviations (2.326: one-sided 99 %)")
    plane_error_deg: float = param(2.0, lo=0.0, hi=45.0, units="deg",
                                   doc="the plane the map puts under the body may lean this far from the ground's: "
                                       "the tensions must stay inside their limits at every such lean")
    tension_guard_n: float = param(2.0, lo=0.0, hi=1e4, units="N",
                                   doc="while it drives on ground steeper than free_slope_deg, a measured tension "
                                       "this near a limit stops the way: it backs off to where it last stood and "
                                       "plans round the place (0: off)")
    guard_radius_m: float = param(0.1, lo=0.0, hi=5.0, units="m",
                                  doc="the planner's nodes within this of where the tension guard stopped it "
                                      "are refused")
    safe_recover_s: float = param(0.0, lo=0.0, hi=1e5, units="s",
                                  doc="the task leaves SAFE by itself after this long (0: waits for RECOVER)")
    approach_looks: int = param(3, lo=0, hi=20,
                                doc="looks in a row a target whose ground is not known may take without an "
                                    "approach node nearer it before it is given up (0: never approached)")
    retry_given_up: bool = param(False, doc="a target given up for a reason a look can change is tried again once, "
                                            "after the other targets, on the map their looks have grown")


@dataclass(frozen=True)
class CliffbotSiteConfig:
    """Where the Cliff-bot works (config ``[cliffbot_site]``), in the team's map frame: the two
    Anchorbots' tether exits' ground points, its start, its science targets, and the height of
    the received map's origin (the RECON-bot's start) in that frame. A bench run sets them from
    its scenario."""

    anchor_a_xyz: tuple[float, ...] = param((0.0, -1.5, 0.0), units="m", doc="Anchorbot A's ground point x, y, z")
    anchor_b_xyz: tuple[float, ...] = param((0.0, 1.5, 0.0), units="m", doc="Anchorbot B's ground point x, y, z")
    start_xy: tuple[float, ...] = param((0.5, 0.0), units="m", doc="the Cliff-bot's start x, y (and home)")
    start_yaw_deg: float = param(0.0, lo=-360.0, hi=360.0, units="deg", doc="its heading at the start")
    targets_xy: tuple[float, ...] = param((), units="m", doc="science targets: x1, y1, x2, y2, ...")
    map_datum_m: float = param(0.0, lo=-1e4, hi=1e4, units="m",
                               doc="height of the received map's zero in the team's frame")
    mask_team: bool = param(False, doc="the RECON-bot keeps the Cliff-bot (at its start), the Anchorbots and "
                                       "the tethers out of its map (docs/algorithm.md §8.1)")

    def __post_init__(self) -> None:
        for name in ("anchor_a_xyz", "anchor_b_xyz"):
            if len(getattr(self, name)) != 3:
                raise ValueError(f"{name}: three numbers (x, y, z)")
        if len(self.start_xy) != 2:
            raise ValueError("start_xy: two numbers (x, y)")
        if len(self.targets_xy) % 2:
            raise ValueError("targets_xy: pairs of numbers (x1, y1, x2, y2, ...)")
        values = (*self.anchor_a_xyz, *self.anchor_b_xyz, *self.start_xy, *self.targets_xy)
        if not all(math.isfinite(v) for v in values):
            raise ValueError("cliffbot_site: every coordinate must be finite")


@dataclass(frozen=True)
class CliffbotBusConfig:
    """The Cliff-bot's CAN bus to its winches, wheels and attitude sensor (config
    ``[cliffbot_bus]``; frames of ``config/team.dbc``). A bench hands in its own bus."""

    can_interface: str = param("none", choices=("none", "virtual", "udp_hub", "udp_multicast", "socketcan"),
                               doc="python-can interface of the team bus (none: no devices)")
    can_channel: str = param("cliffbot", doc="virtual: bus name; udp_hub: HOST:PORT; socketcan: can1")
    status_timeout_s: float = param(0.5, lo=0.05, hi=60.0, units="s",
                                    doc="a device whose status stopped this long is named (SAFE)")


@dataclass(frozen=True)
class CliffbotSensingConfig:
    """The Cliff-bot's own stereo views (config ``[cliffbot_sensing]``; ``fsw.tasks.cliffbot.sensing``,
    docs/team.md "Both agents sense"): its small stereo pair on a head above the body, the head's
    scan (one pointing per capture, in order, round the body), and when the mission looks."""

    enabled: bool = param(False, doc="the Cliff-bot takes its own views before planning (needs a camera)")
    width_px: int = param(320, lo=32, hi=4096, units="px")
    height_px: int = param(240, lo=32, hi=4096, units="px")
    hfov_deg: float = param(60.0, lo=10.0, hi=120.0, units="deg")
    baseline_m: float = param(0.07, lo=0.02, hi=1.0, units="m")
    min_range_m: float = param(0.3, lo=0.05, hi=50.0, units="m", doc="near end of the usable depth")
    max_range_m: float = param(2.5, lo=0.5, hi=100.0, units="m", doc="far end of the usable depth")
    head_m: float = param(0.45, lo=0.0, hi=3.0, units="m", doc="the camera above the body's ground, along its normal")
    head_end_m: float = param(0.45, lo=0.0, hi=2.0, units="m",
                              doc="the head at the body's front (looking ahead) or rear end, along its heading")
    pan_deg: tuple[float, ...] = param((0.0, 45.0, 90.0, 135.0, 180.0, -135.0, -90.0, -45.0, 25.0, -25.0, 180.0, 85.0,
                                        -85.0, 180.0, 60.0, -60.0),
                                       units="deg",
                                       doc="the head's scan: one pan from the heading per capture, in order")
    tilt_deg: float = param(-40.0, lo=-89.0, hi=60.0, units="deg",
                            doc="the head's elevation in every view (but those tilts_deg sets)")
    tilts_deg: tuple[float, ...] = param((-40.0,) * 8 + (-75.0, -75.0, -75.0, -60.0, -60.0, -89.0, -45.0, -45.0),
                                         units="deg",
                                         doc="per pan of the scan, its elevation (empty: tilt_deg for all); the "
                                             "steep ones look down over a lip, the ground below it")
    places: tuple[str, ...] = param(("front", "front") + ("rear",) * 5 + ("front",) * 6 + ("rear",) * 3,
                                    doc="per pan of the scan, where the head takes it: the body's 'front' or 'rear' "
                                        "end (empty: the front end when it looks ahead, the rear end else)")
    height_sigma_m: float = param(0.03, lo=0.0, hi=1.0, units="m", doc="the body's ground height on the map, sigma")
    tilt_sigma_deg: float = param(1.0, lo=0.0, hi=30.0, units="deg", doc="roll and pitch from the attitude sensor")
    body_half_m: tuple[float, ...] = param((0.31, 0.235, 0.28), units="m",
                                           doc="its body's box (half sizes: along, across, up), masked from its views")
    mask_sigma_m: float = param(0.005, lo=0.0, hi=1.0, units="m", doc="the team's known poses' sigma in the mask")
    move_m: float = param(0.5, lo=0.0, hi=100.0, units="m",
                          doc="a leg looks again first when the Cliff-bot moved this far since it last looked")
    capture_timeout_s: float = param(2.0, lo=0.1, hi=60.0, units="s", doc="no pair this long: that view is skipped")
    sense_timeout_s: float = param(300.0, lo=1.0, hi=3600.0, units="s",
                                   doc="the mission plans without its views after waiting this long")

    def __post_init__(self) -> None:
        if not self.pan_deg:
            raise ValueError("pan_deg: at least one pointing")
        if self.tilts_deg and len(self.tilts_deg) != len(self.pan_deg):
            raise ValueError(f"tilts_deg: one per pan ({len(self.pan_deg)}) or none")
        if any(not -89.0 <= t <= 60.0 for t in self.tilts_deg):
            raise ValueError("tilts_deg: each within -89 .. 60 deg")
        if self.places and len(self.places) != len(self.pan_deg):
            raise ValueError(f"places: one per pan ({len(self.pan_deg)}) or none")
        if any(p not in ("front", "rear") for p in self.places):
            raise ValueError("places: each 'front' or 'rear'")
        if len(self.body_half_m) != 3:
            raise ValueError("body_half_m: three numbers (along, across, up)")
        if self.min_range_m >= self.max_range_m:
            raise ValueError("min_range_m must be below max_range_m")

    def place_of(self, k: int) -> str:
        """Where the head takes the scan's ``k mod n``-th pointing: ``front``, ``rear``, or ``""`` (by its
        pan: ``fsw.core.team.cliffbot_head.head_end``)."""
        return self.places[k % len(self.places)] if self.places else ""

    def tilt_of(self, k: int) -> float:
        """The elevation (deg) of the scan's ``k mod n``-th pointing."""
        return self.tilts_deg[k % len(self.tilts_deg)] if self.tilts_deg else self.tilt_deg
