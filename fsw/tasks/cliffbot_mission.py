"""The Cliff-bot's mission: to each science target and back up, on the map it received
(docs/team.md, "The Cliff-bot's flight code").

Sans I/O: :meth:`CliffbotMission.step` takes the devices' latest statuses and the
navigation's latest estimate (:meth:`CliffbotMission.on_estimate`) and returns the commands
(winch rates, wheel rates, enable, clear-faults) and whether to ask the RECON-bot for a fix.
The navigation is not the mission's: the EKF (:class:`fsw.core.team.cliffbot_nav.Navigator`)
runs beside it (the ``cb_nav`` task, or a bench loop through :func:`navigate`); it plans on
the map the mission filled by contact, judges each fix (the mission stops on a refused one)
and takes the estimate the mission hands it back (:attr:`CliffbotMission.nav_reset`: after a
recovery from a refused fix, or a checkpoint). States:

``WAIT_MAP`` (no map yet) -> [``WAIT_FIX`` -> ``SENSE``] -> ``PLAN`` (every target planned from the
start on the received map with :func:`fsw.core.team.face_planner.plan_targets`; a target it cannot reach is
reported with its reason, event ``TARGET_UNREACHABLE``, and never attempted) ->
``WAIT_FIX`` (before each leg: a fiducial fix from the RECON-bot) -> ``DRIVE`` (the leg's
path, waypoint by waypoint: each waypoint's tether lengths on the map are the winches'
set-points, both tethers paced to arrive together; re-planned from the estimate when a
fix or a newer map arrives) -> ``DWELL`` (at the target) -> the next leg; after the last
target, the leg home (the start) -> ``DONE``. A leg home with no way home on the map retraces
the way it came by the tether lengths it held (:meth:`CliffbotMission._retrace`, event ``RETRACE``).

``SENSE`` (with ``[cliffbot_sensing] enabled``; docs/team.md, "Both agents sense"): before its
first plan (after a first fix: before it the start's heading is known to 10 deg, and the sensing
pipeline drops the far and steep ground a look exists for; the first leg, where it stands, needs
no other fix), and before a leg when it has moved ``move_m`` since it last looked, the mission
asks for its own views (``Commands.sense``) and waits, holding still, until the map with them
arrives (:meth:`CliffbotMission.sensed`: the received map with the cells its own views made
known) or ``sense_timeout_s`` passes (it then plans on what it has, event ``SENSE_TIMEOUT``).

Approach (docs/team.md, "Approach: making the unknown known"): with its own views on, a target
refused on the map for a reason a look can change (``unknown ground``, ``tether over unknown
ground``, ``no safe path``) keeps its leg (event ``APPROACH``). The leg drives to the known,
safe, tether-feasible node nearest the target (:meth:`fsw.tasks.cliffbot.legs.Route.approach`,
nearer the target than where it stands), asks for a fix there and looks (``LOOK``, then
``SENSE``), and is planned again on the map with its views; with no such node and a look
taken from where it stands, it looks from elsewhere along its known ground (``EXPLORE``,
:meth:`fsw.tasks.cliffbot.legs.Route.vantage`: each standing leaves blind spots of the head's
scan): until the target is planned, a
reason on known ground gives it up, or ``approach_looks`` looks in a row leave it no nearer the
target (its reason then says how many looks it took in all, ``unknown ground (7 looks)``): each
approach node is nearer the target than the last by more than a lattice spacing, so the approach
ends. With ``retry_given_up``, a target given up so is tried again once, after the other targets,
on the map their looks have grown (:meth:`CliffbotMission._retry_later`). It never drives onto
ground its map does not know.
The legs' ways, margins and approach nodes are :mod:`fsw.tasks.cliffbot.legs`'.

The tension guard (docs/team.md, "The Cliff-bot's flight code"): while it drives a way, a winch's
measured tension near its limit (:func:`fsw.tasks.cliffbot.winches.near_limit`) stops it (event
``TENSION_GUARD``); the place joins :attr:`CliffbotMission.refused`, which every later plan
refuses, it backs off to the last place of its trail and the leg is planned again from there
(:meth:`CliffbotMission._guard`).

``SAFE`` (winches braked, wheels stopped, event ``SAFE`` with the reason) on: a winch fault
bit (stall, slip, over-tension, spool, timeout), a device whose status stopped, no fix
within ``fix_timeout_s`` of the request (the link is lost), a fix refused by the
navigation's gate (it disagrees with the estimate beyond both covariances), a leg with no
usable start. :meth:`recover` (a ground command) clears the winches' faults, takes the
last fix as the estimate if that was the cause (``nav_reset``), and re-plans the leg it was
on from there.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from fsw.comm.team.fix_packets import Fix, FixRequest
from fsw.comm.team.team_can import WINCHES, WinchStatus
from fsw.core.geometry import MapGrid
from fsw.core.team.cliffbot_nav import NavConfig, Navigator
from fsw.core.team.climber_ground import ClimberConfig, standing_cells
from fsw.core.team.contact_ground import StoodGround, fill_under_body
from fsw.core.team.face_planner import OFF_THE_WAY, plan_targets
from fsw.core.team.tether import TetherConfig, tether_state
from fsw.drivers.cliffbot_devices import CliffbotDevices
from fsw.sections import CliffbotMissionConfig, CliffbotSensingConfig
from fsw.tasks.cliffbot.head_sight import look_rating
from fsw.tasks.cliffbot.legs import UNKNOWN_REASONS, Leg, Route
from fsw.tasks.cliffbot.winches import near_limit, winch_rates

F64 = NDArray[np.float64]
MAX_GUARDS = 4  # ways of one leg the tension guard may stop before the leg is given up
BACK_OFF_TOL = 0.25  # a back-off ends within this fraction of length_tol_m of the place it backs off to
BODY_MARGIN_M = 0.1  # the body's box as mapped (stereo smear, the estimate's error) beyond the footprint
VIEW_RANGE_M = 2.0  # a look's far ground: the pose error a point this far carries (sharper: a new look shows more)
# a place to look from elsewhere lies no farther from the target than where it stands by more than
# this (about the body's half width: along the known ground's edge, not back up); a place this far
# from every place it looked from gives a new sight line on ground a look should have shown
LOOK_APART_M = 0.25
MAX_ELSEWHERE = 3  # a leg re-planned this often in a row, without getting nearer its goal, is given up
FAULT_BITS = ("FaultStall", "FaultSlip", "FaultOverTension", "FaultSpool", "FaultTimeout")


@dataclass(frozen=True)
class Commands:
    rates_mps: tuple[float, float]
    enable: bool
    clear_faults: bool
    wheels_radps: tuple[float, float]
    request_fix: bool
    sense: bool = False  # take the Cliff-bot's own views now (docs/team.md, "Both agents sense")


@dataclass
class Estimate:
    """The navigation's estimate as the mission knows it: ``s = (x, y, yaw)`` and its covariance."""

    s: F64
    P: F64

    @property
    def xy(self) -> F64:
        return self.s[:2].copy()


class CliffbotMission:
    def __init__(self, cfg: CliffbotMissionConfig, tcfg: TetherConfig, ccfg: ClimberConfig, ncfg: NavConfig,
                 anchors: F64, start_xy: F64, start_yaw: float, targets_xy: F64,
                 sensing: CliffbotSensingConfig | None = None) -> None:
        self.cfg, self.tcfg, self.ccfg = cfg, tcfg, ccfg
        self.sensing = sensing if sensing is not None and sensing.enabled else None
        # its body's outline (half length, half width): the ground under it is where it stands
        self.body_half = (float(sensing.body_half_m[0]), float(sensing.body_half_m[1])) if sensing is not None else None
        self.sense_seq = 0  # the views asked for (Commands.sense), each answered by a map (sensed)
        self.sense_asked_at: float | None = None
        self.sensed_xy: F64 | None = None  # where it last looked
        self.look_sigma = math.inf  # the pose error a point VIEW_RANGE_M away carried when it last looked
        self.looked_from: list[F64] = []  # every place it looked from (an approach looks next from elsewhere)
        self.anchors = np.asarray(anchors, float)
        self.start = np.asarray(start_xy, float)
        self.targets = np.asarray(targets_xy, float).reshape(-1, 2)
        s0 = np.array([float(self.start[0]), float(self.start[1]), float(start_yaw)])
        self.est = Estimate(s0, np.diag([ncfg.init_sigma_m ** 2, ncfg.init_sigma_m ** 2, math.radians(10.0) ** 2]))
        self.nav_reset: Estimate | None = None  # an estimate the navigation is to take (recovery, checkpoint)
        self.state = "WAIT_MAP"
        self.events: list[tuple[float, str, str]] = []
        self.safe_reason = ""
        self.z: F64 | None = None
        self.carried: NDArray[np.bool_] | None = None  # cells of z no sensor measured (the plane carried on)
        self.carried_from = self.start.copy()  # where it stood when they were filled
        self.stood: StoodGround | None = None  # the ground under every pose it held when a map came
        self.grid: MapGrid | None = None
        self.error_bound_m = 0.0  # the received map's height error bound (the codec's)
        self._route: Route | None = None  # the map as the legs use it (made again for every map)
        self.look_now = False  # at an approach node: look before the leg is planned again
        self.map_version = 0
        self.legs: list[Leg] = []
        self.leg_i = 0
        self.wp_i = 0
        self.reasons: list[str] = ["" for _ in range(len(self.targets))]
        self.reached: list[bool] = [False for _ in range(len(self.targets))]
        self.planned_lengths: list[float] = [math.inf for _ in range(len(self.targets))]
        self.looks: list[int] = [0 for _ in range(len(self.targets))]  # per target, looks taken to approach it
        self.fix_asked_at: float | None = None
        self.fix_wanted = False  # a fix asked for by ground command
        self.fix_seq = 0
        self.last_fix: Fix | None = None
        self.fixes_used = 0
        self.fixes_refused = 0
        self.fix_log: list[tuple[float, ...]] = []  # t, fix x y yaw, estimate x y yaw (before), NIS
        self.fixed_xy: F64 | None = None  # the estimate when the last fix was fused (a leg there needs no other)
        self.replan = False
        self.elsewhere = 0  # re-plans of this leg in a row, without progress, because the lengths held it elsewhere
        self.elsewhere_left = math.inf  # the leg's planned length left at its last such re-plan
        self.dwell_until = 0.0
        self.clear_frames = 0
        self.now = 0.0
        # the way it came since it left its start: (tether lengths, estimate) where each driven
        # stretch began and at each waypoint it reached; the leg home retraces it when its map
        # shows no way home (:meth:`_retrace`)
        self.trail: list[tuple[float, float, float, float]] = []
        self.trail_from_here = False  # the next drive step notes where it begins
        # places where the winches' measured tensions stopped a way (:meth:`_guard`) and the limit
        # they neared ("slack", "over-tension"): every plan after refuses the lattice round them
        self.refused: list[tuple[F64, str]] = []

    # -- inputs -----------------------------------------------------------------------------
    def event(self, name: str, text: str) -> None:
        self.events.append((round(self.now, 3), name, text))

    def set_map(self, z: F64, grid: MapGrid, error_bound_m: float = 0.0) -> None:
        """A map received (``error_bound_m``: the codec's bound on its heights' error)."""
        # the ground under its own body is hidden from every camera (the RECON-bot maps the body's
        # box there) but known by contact
        # (the footprint of the lattice node nearest to where it stands: a node spacing more)
        r = self.ccfg.footprint_m + self.cfg.track_margin_m + self.ccfg.node_m
        # (a ring is as flat as the map can tell: half the codec's error bound, at least 3 cm)
        flat = max(0.03, 0.5 * error_bound_m) if math.isfinite(error_bound_m) else 0.03
        self.error_bound_m = error_bound_m if math.isfinite(error_bound_m) else 0.0
        z_in = np.asarray(z, np.float64)
        # the ground it stood on before, which it measured by standing there (no camera saw it
        # the while): given back where this map does not know it or holds its box there
        if self.stood is None or self.stood.z.shape != z_in.shape:
            self.stood = StoodGround.empty(z_in.shape)
        z_back, stood_on = self.stood.restore(z_in, flat)
        self.z, filled = fill_under_body(z_back, grid, self.est.xy, r, body_m=r + BODY_MARGIN_M, max_rms_m=flat)
        # the cells filled beyond where it stands are the plane carried on, not ground a sensor
        # measured: no node a leg ends on or crosses counts them as known (legs.Route,
        # climber_ground.ground_layers). Where it stands: its footprint round its estimate, the
        # footprint of the lattice node nearest it (the node it stands at) and its body's outline
        filled_here = np.isfinite(self.z) & ~(np.isfinite(z_in) & (z_in == self.z))
        body = None if self.body_half is None else (float(self.est.s[2]), *self.body_half)
        under = standing_cells(grid, self.est.xy, self.ccfg, self.anchors, body)
        self.carried = filled_here & ~under & ~stood_on
        self.carried_from = self.est.xy
        # (a cell given back keeps how it was known then: a sensor's height stays a sensor's)
        self.stood.record(self.z, under, filled_here & ~(stood_on & ~self.stood.by_contact))
        self.grid = grid
        self._route = None
        self.map_version += 1
        back = int(stood_on.sum())
        self.event("MAP", f"map {self.map_version}: {int(np.isfinite(self.z).sum())} known cells"
                   + (f", {filled} under the body known by contact" if filled else "")
                   + (f", {back} stood on before" if back else ""))
        if self.state == "WAIT_MAP":
            # with its own views: a fix first, then the look (_leg_ready), then the plan
            self.state = "PLAN" if self.sensing is None else "WAIT_FIX"
            self.fix_asked_at = None
        elif self.state == "DRIVE":
            self.replan = True

    def sensed(self, seq: int) -> None:
        """The map with the views of request ``seq`` has been given (:meth:`set_map`): plan on it."""
        if self.state != "SENSE" or seq != self.sense_seq or self.sense_asked_at is None:
            return
        self.event("SENSED", f"views {seq} in the map")
        self._after_sense()

    def route(self) -> Route:
        """The map as the legs use it (:class:`fsw.tasks.cliffbot.legs.Route`), made once per map
        (also for a map a checkpoint put back)."""
        assert self.z is not None and self.grid is not None
        r = self._route
        if r is None or r.z is not self.z or r.grid is not self.grid or r.error_bound_m != self.error_bound_m:
            r = self._route = Route(self.z, self.grid, self.error_bound_m, self.cfg, self.tcfg, self.ccfg,
                                    self.anchors, carried=self.carried, carried_from=self.carried_from,
                                    refused=self.refused)
        return r

    def _after_sense(self) -> None:
        self.sense_asked_at = None
        self.look_now = False
        self.sensed_xy = self.est.xy
        self.looked_from.append(self.est.xy)
        if self.legs:
            self._plan_leg()
        else:
            self.state = "PLAN"

    def _wants_views(self) -> bool:
        """Before a leg: whether it moved far enough since it last looked to look again."""
        if self.sensing is None or self.sensed_xy is None or self.look_now:
            return self.sensing is not None
        return float(np.linalg.norm(self.est.xy - self.sensed_xy)) >= self.sensing.move_m

    def _leg_ready(self) -> None:
        """The leg's fix is in (or none will come): look first if it moved, else plan it."""
        if self._wants_views():
            self.state = "SENSE"
            self.sense_asked_at = None
        else:
            self._plan_leg()

    def set_targets(self, targets_xy: F64) -> None:
        """A ground command: new targets (planned again from where the Cliff-bot is)."""
        t = np.asarray(targets_xy, float).reshape(-1, 2)
        if not np.isfinite(t).all():
            self.event("COMMAND_REFUSED", "targets with non-finite coordinates")
            return
        self.targets = t
        self.reasons = ["" for _ in range(len(t))]
        self.reached = [False for _ in range(len(t))]
        self.planned_lengths = [math.inf for _ in range(len(t))]
        self.looks = [0 for _ in range(len(t))]
        self.start = self.est.xy if self.state not in ("WAIT_MAP",) else self.start
        if self.state != "WAIT_MAP" and self.state != "SAFE":
            self.state = "PLAN"

    def on_estimate(self, s: F64, cov: F64) -> None:
        """The navigation's latest estimate."""
        self.est = Estimate(np.asarray(s, float).reshape(3).copy(), np.asarray(cov, float).reshape(3, 3).copy())

    def on_fix(self, fix: Fix, ok: bool, nis: float) -> None:
        """A fiducial fix from the RECON-bot and the navigation's verdict on it (:func:`fix_xyyaw`):
        fused, or refused (SAFE) when it disagrees with the estimate beyond both covariances."""
        self.last_fix = fix
        self.fix_log.append((self.now, float(fix.position[0]), float(fix.position[1]), fix.yaw,
                             float(self.est.s[0]), float(self.est.s[1]), float(self.est.s[2]), nis))
        if not ok:
            self.fixes_refused += 1
            self.event("FIX_REFUSED", f"fix {fix.seq} disagrees with the estimate (NIS {nis:.1f})")
            self._safe(f"fix disagrees with the estimate (NIS {nis:.1f})")
            return
        self.fixes_used += 1
        self.fixed_xy = self.est.xy
        self.event("FIX", f"fix {fix.seq} fused (NIS {nis:.2f})")
        if self.state == "WAIT_FIX":
            self.fix_asked_at = None
            self._leg_ready()
        elif self.state == "DRIVE":
            self.replan = True

    def on_no_fix(self, seq: int, reason: str) -> None:
        """The RECON-bot cannot localize the Cliff-bot now: the leg goes on the estimate."""
        self.event("FIX_UNAVAILABLE", f"request {seq}: {reason}")
        if self.state == "WAIT_FIX":
            self.fix_asked_at = None
            self._leg_ready()

    def recover(self) -> None:
        """Ground command: leave SAFE (clear the winches' faults, re-plan the leg from the estimate)."""
        if self.state != "SAFE":
            return
        if self.safe_reason.startswith("fix disagrees") and self.last_fix is not None:
            xy, yaw, cov3 = fix_xyyaw(self.last_fix)
            self.est = Estimate(np.array([xy[0], xy[1], yaw]), cov3)
            self.nav_reset = self.est
        self.event("RECOVER", f"leaving SAFE ({self.safe_reason})")
        self.fixed_xy = None
        self.safe_reason = ""
        self.clear_frames = 3
        self.fix_asked_at = None
        self.state = "WAIT_FIX" if self.legs else ("PLAN" if self.z is not None else "WAIT_MAP")

    # -- the step ---------------------------------------------------------------------------
    def _safe(self, reason: str) -> None:
        if self.state == "SAFE":
            return
        self.state = "SAFE"
        self.safe_reason = reason
        self.event("SAFE", reason)

    def _hold(self, request: bool = False) -> Commands:
        clear = self.clear_frames > 0
        self.clear_frames = max(0, self.clear_frames - 1)
        return Commands((0.0, 0.0), self.state not in ("SAFE",), clear, (0.0, 0.0), request)

    def request_fix(self) -> None:
        """Ground command: ask the RECON-bot for a fix now (on a leg or at a target; a leg's start
        asks by itself). The answer is fused like any fix; on a leg it re-plans from there."""
        if self.state in ("DRIVE", "DWELL"):
            self.fix_wanted = True
        else:
            self.event("FIX_REQUEST", f"not now: {self.state}")

    def step(self, now: float, dev: CliffbotDevices) -> Commands:
        """One step on the devices' statuses and the estimate last given (:meth:`on_estimate`)."""
        cmd = self._step(now, dev)
        if self.fix_wanted and self.state in ("DRIVE", "DWELL"):
            self.fix_wanted = False
            self.fix_seq += 1
            self.event("FIX_REQUEST", f"request {self.fix_seq} on command, leg {self.leg_i + 1}")
            cmd = dataclasses.replace(cmd, request_fix=True)
        return cmd

    def _step(self, now: float, dev: CliffbotDevices) -> Commands:
        self.now = now
        if self.state == "SAFE":
            return self._hold()
        if self.clear_frames == 0:
            for w in WINCHES:
                st = dev.winch.get(w)
                bad = sorted(st.faults & set(FAULT_BITS)) if st is not None else []
                if bad:
                    self.event("WINCH_FAULT", f"{w}: {', '.join(bad)}")
                    self._safe(f"{w} {bad[0]}")
                    return self._hold()
            stale = dev.stale(now)
            if stale and now > 1.0:
                self._safe(f"no status from {', '.join(stale)}")
                return self._hold()
        if self.state == "WAIT_MAP":
            return self._hold()
        if self.state == "SENSE":
            assert self.sensing is not None
            if self.sense_asked_at is None:
                self.sense_asked_at = now
                self.look_sigma = self._view_sigma()
                self.sense_seq += 1
                self.event("SENSE_REQUEST", f"views {self.sense_seq} before "
                           + (f"leg {self.leg_i + 1}" if self.legs else "the plan"))
                return dataclasses.replace(self._hold(), sense=True)
            if now - self.sense_asked_at > self.sensing.sense_timeout_s:
                self.event("SENSE_TIMEOUT", f"no map with views {self.sense_seq} after "
                                            f"{self.sensing.sense_timeout_s:.0f} s: planning on the map it has")
                self._after_sense()
            return self._hold()
        if self.state == "PLAN":
            self._plan_all()
            return self._hold()
        if self.state == "WAIT_FIX":
            if self.fix_asked_at is None:
                if self.legs and self._fixed_here():
                    self._leg_ready()  # a fix was fused where it stands (before the look that preceded the plan)
                    return self._hold()
                self.fix_asked_at = now
                self.fix_seq += 1
                self.event("FIX_REQUEST", f"request {self.fix_seq} before "
                           + (f"leg {self.leg_i + 1}" if self.legs else "the first look"))
                return self._hold(request=True)
            if now - self.fix_asked_at > self.cfg.fix_timeout_s:
                self.event("LINK_LOST", f"no fix {self.cfg.fix_timeout_s:.0f} s after request {self.fix_seq}")
                self._safe("lost link: no fix from the RECON-bot")
            return self._hold()
        if self.state == "DWELL":
            if now >= self.dwell_until:
                self._next_leg()
            return self._hold()
        if self.state == "DRIVE":
            return self._drive(dev)
        return self._hold()

    def _fixed_here(self) -> bool:
        """Whether a fix was fused where it stands (within a lattice spacing)."""
        return self.fixed_xy is not None and float(np.hypot(*(self.est.xy - self.fixed_xy))) <= self.ccfg.node_m

    def _approaching(self, why: str) -> bool:
        """Whether a target refused for ``why`` is approached (its ground made known by looking
        from the known ground nearest it) rather than given up: a reason a look can change, with
        the Cliff-bot's own views on and a budget of looks."""
        return why in UNKNOWN_REASONS and self.sensing is not None and self.cfg.approach_looks > 0

    def _plan_all(self) -> None:
        assert self.z is not None and self.grid is not None
        route = self.route()
        plan = plan_targets(self.z, self.grid, self.anchors, self.est.xy, self.targets, self.tcfg, self.ccfg,
                            route.margins(), unseen=self.carried, ground=route.ground)
        self.legs = []
        for k, why in enumerate(plan.reasons):
            self.reasons[k] = why
            self.planned_lengths[k] = plan.lengths_m[k]
            if why and not plan.start_reason and self._approaching(why):
                self.event("APPROACH", f"target {k + 1}: {why} on its map: to the known ground nearest it, "
                                       f"to look (up to {self.cfg.approach_looks} looks in a row "
                                       f"without getting nearer)")
                self.legs.append(Leg(self.targets[k], k))
            elif why:
                self.event("TARGET_UNREACHABLE", f"target {k + 1}: {why}")
            else:
                self.legs.append(Leg(self.targets[k], k))
        if self.cfg.return_home:
            self.legs.append(Leg(self.start.copy(), None))
        self.leg_i = 0
        self.event("PLAN", f"{len(self.legs)} legs; {sum(1 for r in self.reasons if not r)} of "
                           f"{len(self.targets)} targets reachable on the map")
        self.state = "WAIT_FIX" if self.legs else "DONE"

    def _plan_leg(self) -> None:
        """Plan the current leg from the estimate and start driving it; a target whose ground is
        not known yet is approached (:meth:`_approach`)."""
        assert self.z is not None and self.grid is not None
        if self.leg_i >= len(self.legs):
            self.state = "DONE"
            self.event("DONE", "all legs driven")
            return
        leg = self.legs[self.leg_i]
        plan, wps = self.route().plan(self.est.xy, leg.goal)
        if plan.paths[0] is None:
            why = plan.reasons[0]
            if leg.target is None and self._retrace(leg, why):
                return
            if plan.start_reason:
                self._safe(f"leg {self.leg_i + 1}: {why}")
                return
            # (a leg the tension guard stopped finds no path round the places it refused: no look helps)
            looks_help = self._approaching(why) and not (leg.guards and why == "no safe path")
            if leg.target is not None and looks_help and self._approach(leg, why):
                return
            retry = leg.target is not None and self._retry_later(leg, why)
            if leg.target is not None:
                why = f"{why} ({leg.looks} looks)" if leg.looks else why
                self.reasons[leg.target] = why
            self.event("TARGET_UNREACHABLE", f"leg {self.leg_i + 1}: {why}"
                       + ("; tried again after the other targets" if retry else ""))
            self._next_leg()
            return
        if leg.target is not None and self.reasons[leg.target]:
            # a target refused before (approached, or given up and tried again) is planned now
            self.reasons[leg.target] = ""
            self.planned_lengths[leg.target] = plan.lengths_m[0]
            self.event("APPROACH", f"target {leg.target + 1}: planned after {leg.looks} looks")
        leg.via = None
        self._drive_on(leg, wps, plan.lengths_m[0])

    def _retry_later(self, leg: Leg, why: str) -> bool:
        """The target of ``leg`` is given up for ``why``: with ``retry_given_up``, when a look can
        change that reason and another target's leg comes before the leg home, the target is tried
        again once after the other targets (a leg for it before the leg home, its looks carried
        on), on the map their legs' looks have grown meanwhile; with no other target left between,
        the map would be the same. A target is tried again at most once: a leg is its retry when an
        earlier leg is for the same target (so a mission resumed from its checkpoint's legs retries
        the same way). Off by default: a retry takes the approach (its looks, its steps down the
        face on the map) where the first attempt stopped, and each of those carries the approach's
        own risks (ways judged on the map near a lip, whose heights the truth may not share)."""
        if not self.cfg.retry_given_up or not self._approaching(why):
            return False
        if any(g.target == leg.target for i, g in enumerate(self.legs) if i != self.leg_i):
            return False
        end = len(self.legs) - 1 if self.legs[-1].target is None else len(self.legs)  # before the leg home
        if not any(g.target is not None for g in self.legs[self.leg_i + 1:end]):
            return False
        self.legs.insert(end, Leg(leg.goal.copy(), leg.target, looks=leg.looks))
        return True

    def _drive_on(self, leg: Leg, wps: list[F64], length_m: float) -> None:
        leg.waypoints, leg.length_m = wps, length_m
        leg.lengths, leg.back_to = None, None
        self.wp_i = 0
        self.replan = False
        self.state = "DRIVE"
        self.trail_from_here = True

    def _retrace(self, leg: Leg, why: str) -> bool:
        """The leg home finds no way home on its map (``why``): back the way it came, by the
        tether lengths it held (:attr:`trail`, last first). Each stretch it drove moved both
        lengths straight from one set-point to the next and the body rested where the statics put
        it; the same lengths in reverse put it back through the places it passed (quasi-static
        equilibrium depends on the lengths, not on the way there), on ground it stood on, its
        tethers over the contacts they had, whatever its map has come to show since (a view near
        the lip can put false rocks on the way it came up). False with no trail (it is at its
        start, or never left it)."""
        back = list(reversed(self.trail))
        if not back:
            return False
        leg.waypoints = [np.array([t[2], t[3]]) for t in back]
        leg.lengths = [(t[0], t[1]) for t in back]
        leg.length_m = 0.0
        self.wp_i = 0
        self.replan = False
        self.state = "DRIVE"
        self.event("RETRACE", f"leg {self.leg_i + 1} (home): {why} on its map: back the way it came, "
                              f"{len(back)} set-points of its tethers' lengths")
        return True

    def _note_trail(self, a: float, b: float) -> None:
        """Where a driven stretch begins or a waypoint was reached: its lengths and the estimate
        (a repeat of the last, within the winches' tolerance, is not noted again)."""
        if self.trail and max(abs(self.trail[-1][0] - a), abs(self.trail[-1][1] - b)) <= self.cfg.length_tol_m:
            return
        xy = self.est.xy
        self.trail.append((float(a), float(b), float(xy[0]), float(xy[1])))

    def _view_sigma(self) -> float:
        """The pose error a point ``VIEW_RANGE_M`` away carries from the estimate (its place and
        heading): the sensing pipeline drops points whose error is too large, so a look before a
        fix (the start's heading is known to 10 deg) keeps the near ground only."""
        P = self.est.P
        return math.sqrt(max(float(P[0, 0] + P[1, 1] + VIEW_RANGE_M ** 2 * P[2, 2]), 0.0))

    def _approach(self, leg: Leg, why: str) -> bool:
        """The target of ``leg`` is not reachable on the map for ``why`` (a reason a look can
        change): drive to the known, safe, tether-feasible node nearest it
        (:meth:`fsw.tasks.cliffbot.legs.Route.approach`), then look there and plan again; with no
        such node nearer than where it stands, look from here if it has not yet, or if its pose
        is known twice as well as when it last looked here (:meth:`_view_sigma`: after a fix its
        far views keep points they lost before). False when ``approach_looks`` looks in a row have
        found no approach node nearer the target than the nearest before (by more than a lattice
        spacing: the budget of looks without progress), or a look cannot help (the leg is then
        given up)."""
        assert leg.target is not None
        k = leg.target + 1
        got = self.route().approach(self.est.xy, leg.goal)
        gap = math.inf if got is None else float(np.hypot(*(got[0] - leg.goal)))
        if gap < leg.nearest_m - self.ccfg.node_m:
            leg.idle = 0  # progress: its looks brought it nearer
            leg.nearest_m = gap
        if leg.idle >= self.cfg.approach_looks:
            return False
        if got is None:
            here = self.sensed_xy is not None and float(np.hypot(*(self.est.xy - self.sensed_xy))) <= self.ccfg.node_m
            if here and self._view_sigma() >= 0.5 * self.look_sigma:
                # it looked from here already, as well placed: a look from elsewhere sees the blind
                # spots of its scan here (the ground beside the body, just below the lip beside the head)
                return self._explore(leg, why)
            leg.looks += 1
            leg.idle += 1
            self.looks[leg.target] = leg.looks
            self.event("LOOK", f"target {k}: {why}; no known ground nearer: look {leg.looks} from here")
            self.look_now = True
            self.state = "SENSE"
            self.sense_asked_at = None
            return True
        via, plan, wps = got
        self.event("APPROACH", f"target {k}: {why}; to {via.round(2).tolist()}, {gap:.2f} m from it "
                               f"({plan.lengths_m[0]:.2f} m of path)")
        leg.via = via
        self._drive_on(leg, wps, plan.lengths_m[0])
        return True

    def _explore(self, leg: Leg, why: str) -> bool:
        """No known node is nearer the target of ``leg`` than where it stands and it looked from
        here: drive to the known node whose look would show the most of the unknown ground the
        next step needs that no look it took showed (:meth:`_look_rating`,
        :meth:`fsw.tasks.cliffbot.legs.Route.vantage`) and look there (the look counts against
        ``approach_looks`` unless it brings an approach node nearer). False when no node rates
        above 0 or none can be driven to (the leg is then given up)."""
        assert leg.target is not None
        got = self.route().vantage(self.est.xy, leg.goal, self._look_rating(leg.goal), LOOK_APART_M)
        if got is None:
            return False
        via, plan, wps = got
        self.event("EXPLORE", f"target {leg.target + 1}: {why}; no known ground nearer: to look from "
                              f"{via.round(2).tolist()} ({plan.lengths_m[0]:.2f} m of path), "
                              f"{float(np.hypot(*(via - leg.goal))):.2f} m from it")
        leg.via = via
        self._drive_on(leg, wps, plan.lengths_m[0])
        return True

    def _look_rating(self, goal: F64) -> Callable[[F64], tuple[int, int]]:
        """A place to look from, rated for the unknown ground the next step toward ``goal`` needs
        (:func:`fsw.tasks.cliffbot.head_sight.look_rating`, from every place it looked from)."""
        assert self.z is not None and self.grid is not None and self.sensing is not None
        unseen = self.carried if self.carried is not None else np.zeros(self.z.shape, bool)
        return look_rating(self.z, unseen, self.grid, self.ccfg, self.anchors, self.sensing, self.est.xy, goal,
                           list(self.looked_from), LOOK_APART_M)

    def _arrived(self, leg: Leg) -> None:
        """At the end of a leg's waypoints: the target (dwell), the approach node (look, then
        plan the leg again), or home."""
        if leg.via is not None:
            leg.via = None
            leg.looks += 1
            leg.idle += 1
            assert leg.target is not None
            self.looks[leg.target] = leg.looks
            self.event("LOOK", f"target {leg.target + 1}: at the approach node, look {leg.looks}")
            self.look_now = True
            self.fix_asked_at = None
            self.state = "WAIT_FIX"  # a fix, then its views, then the leg planned again (_leg_ready)
        elif leg.target is not None:
            self.reached[leg.target] = True
            self.event("TARGET_REACHED", f"target {leg.target + 1}")
            self.state = "DWELL"
            self.dwell_until = self.now + self.cfg.dwell_s
        else:
            self.event("HOME", "back at the start")
            self.trail.clear()
            self._next_leg()

    def _next_leg(self) -> None:
        self.leg_i += 1
        self.elsewhere = 0
        self.elsewhere_left = math.inf
        if self.leg_i >= len(self.legs):
            self.state = "DONE"
            self.event("DONE", "all legs driven")
        else:
            self.fix_asked_at = None
            self.state = "WAIT_FIX"

    def _drive(self, dev: CliffbotDevices) -> Commands:
        assert self.z is not None and self.grid is not None
        if self.replan and self.legs[self.leg_i].back_to is None:  # (a back-off ends in a plan)
            self._plan_leg()
            if self.state != "DRIVE":
                return self._hold()
        leg = self.legs[self.leg_i]
        a, b = dev.winch.get(WINCHES[0]), dev.winch.get(WINCHES[1])
        if a is None or b is None:
            return self._hold()
        if leg.lengths is not None:
            return self._drive_back(leg, a.paid_out_m, b.paid_out_m)
        near = near_limit(dev, self.cfg, self.tcfg, self.ccfg)
        if near:
            return self._guard(leg, near, a, b)
        if self.trail_from_here:
            self.trail_from_here = False
            self._note_trail(a.paid_out_m, b.paid_out_m)
        while True:
            wp = leg.waypoints[self.wp_i]
            st = tether_state(self.z, self.grid, self.anchors, wp, self.tcfg, self.ccfg.footprint_m)
            if st is None:
                self._safe(f"waypoint {wp.round(2).tolist()} on unknown ground")
                return self._hold()
            err = np.asarray(st.lengths_m) - np.array([a.paid_out_m, b.paid_out_m])
            if float(np.max(np.abs(err))) > self.cfg.length_tol_m:
                break
            elsewhere, off, sd = self.route().elsewhere(self.est.xy, self.est.P[:2, :2], wp)
            if elsewhere:
                # the waypoint's lengths hold it elsewhere (the estimate, from those lengths, says
                # where): the rest of the leg is planned again from there; when that keeps
                # happening without getting nearer the goal, the leg is given up (never driven on blindly)
                self.elsewhere += 1
                text = (f"leg {self.leg_i + 1}: at the lengths of waypoint {wp.round(2).tolist()}, {off:.2f} m "
                        f"from it (sigma {sd:.2f} m)")
                if self.elsewhere > MAX_ELSEWHERE:
                    if leg.target is None and self._retrace(leg, OFF_THE_WAY):
                        return self._hold()  # the leg home: back the way it came, not left on the face
                    if leg.target is not None:
                        self.reasons[leg.target] = OFF_THE_WAY
                    self.event("TARGET_UNREACHABLE", f"{text}: {OFF_THE_WAY}")
                    self._next_leg()
                    return self._hold()
                self.event("OFF_THE_WAY", f"{text}; re-planned")
                self._plan_leg()
                if self.state == "DRIVE":
                    if leg.length_m < self.elsewhere_left - self.ccfg.node_m:
                        self.elsewhere = 0  # nearer the goal than at the last re-plan: not stuck
                    self.elsewhere_left = min(self.elsewhere_left, leg.length_m)
                return self._hold()
            self.wp_i += 1
            self._note_trail(a.paid_out_m, b.paid_out_m)
            if self.wp_i >= len(leg.waypoints):
                self._arrived(leg)
                return self._hold()
        return self._winch_rates(err)

    def _drive_back(self, leg: Leg, la: float, lb: float) -> Commands:
        """A retrace (:meth:`_retrace`): the winches to each set-point in turn; each one reached
        leaves the trail (a restart goes back from where it is)."""
        assert leg.lengths is not None
        # a back-off returns to the place itself (a place a tolerance away from the one it tripped
        # at can be as bad); a retrace's set-points are reached within the tolerance
        tol = self.cfg.length_tol_m * (BACK_OFF_TOL if leg.back_to is not None else 1.0)
        while True:
            err = np.asarray(leg.lengths[self.wp_i]) - np.array([la, lb])
            if float(np.max(np.abs(err))) > tol:
                return self._winch_rates(err)
            if leg.back_to is not None:
                # backed off from where the tension guard stopped it: the trail keeps the place it
                # is back at, and the leg is planned again round the refused place
                del self.trail[leg.back_to + 1:]
                leg.back_to, leg.lengths = None, None
                self._plan_leg()
                return self._hold()
            if self.trail:
                self.trail.pop()
            self.wp_i += 1
            if self.wp_i >= len(leg.lengths):
                self._arrived(leg)
                return self._hold()

    def _guard(self, leg: Leg, why: str, a: WinchStatus, b: WinchStatus) -> Commands:
        """The tension guard stopped the way (:func:`fsw.tasks.cliffbot.winches.near_limit`): the
        place is refused to every plan after (:attr:`refused`), and the body backs off to the last
        place of its trail it stood at (the lengths it held there, to a quarter of the tolerance:
        it passed there within the limits; at that place itself, the one before), then the leg is
        planned again round the place (:meth:`_drive_back`). ``MAX_GUARDS``
        stops in one leg give the leg up for ``why``; the leg home then retraces the way it came
        (:meth:`_retrace`)."""
        leg.guards += 1
        self.refused.append((self.est.xy, why))
        self._route = None
        self.event("TENSION_GUARD", f"leg {self.leg_i + 1}: tensions {a.tension_n:.1f} / {b.tension_n:.1f} N, within "
                                    f"{self.cfg.tension_guard_n:g} N of the {why} limit, at "
                                    f"{self.est.xy.round(2).tolist()}: backs off, that place refused")
        la, lb = a.paid_out_m, b.paid_out_m
        tol = self.cfg.length_tol_m
        back = [i for i, t in enumerate(self.trail) if max(abs(t[0] - la), abs(t[1] - lb)) > tol]
        if leg.guards > MAX_GUARDS:
            if leg.target is not None:
                self.reasons[leg.target] = why
                self.event("TARGET_UNREACHABLE", f"leg {self.leg_i + 1}: {why} (the tension guard stopped it "
                                                 f"{leg.guards} times)")
                self._next_leg()
            elif not self._retrace(leg, why):
                self._safe(f"leg {self.leg_i + 1} (home): {why} and no way back")
            return self._hold()
        if not back:
            self._plan_leg()
            return self._hold()
        i = back[-1]
        leg.back_to, leg.lengths = i, [self.trail[i][:2]]
        leg.waypoints = [np.array(self.trail[i][2:])]
        self.wp_i = 0
        return self._hold()

    def _winch_rates(self, err: F64) -> Commands:
        rates, wheels = winch_rates(err, self.cfg)
        return Commands(rates, True, False, wheels, False)


def fix_xyyaw(fix: Fix) -> tuple[F64, float, F64]:
    """A fix's place, heading and their 3x3 covariance (of its 6x6 over rotation and position)."""
    return np.asarray(fix.position[:2], float), float(fix.yaw), fix.cov[np.ix_([3, 4, 2], [3, 4, 2])]


def new_navigator(m: CliffbotMission, ncfg: NavConfig) -> Navigator:
    """The navigation that goes with mission ``m``: its start, anchors, tether and footprint."""
    return Navigator(m.est.xy, float(m.est.s[2]), ncfg, m.anchors, m.tcfg, m.ccfg.footprint_m)


def navigate(nav: Navigator, dev: CliffbotDevices, dt: float, wheel_radius_m: float) -> None:
    """One navigation step on the devices' statuses: the wheels' mean path, the IMU's pitch and
    heading, the winches' paid-out lengths."""
    att = dev.attitude
    wheel = None if dev.wheels is None else 0.5 * (dev.wheels.left_rad + dev.wheels.right_rad) * wheel_radius_m
    a, b = dev.winch.get(WINCHES[0]), dev.winch.get(WINCHES[1])
    nav.step(wheel, att.pitch_deg if att is not None else None, att.yaw_deg if att is not None else None,
             (a.paid_out_m, b.paid_out_m) if a is not None and b is not None else None, dt)


def fix_request(m: CliffbotMission, dev: CliffbotDevices) -> FixRequest:
    """The fix request mission ``m`` sends: its sequence number and leg, its estimate (where the
    RECON-bot points its mast) and its attitude sensor's roll and pitch (the gravity the fix
    must agree with; NaN when the sensor has not reported)."""
    att = dev.attitude
    roll, pitch = (att.roll_deg, att.pitch_deg) if att is not None else (math.nan, math.nan)
    xy = m.est.xy
    return FixRequest(m.fix_seq, m.leg_i, float(xy[0]), float(xy[1]), float(roll), float(pitch))
