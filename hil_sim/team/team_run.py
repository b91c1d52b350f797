"""A team mission on the lockstep bench (docs/team.md, "Running a team mission").

After the RECON-bot has mapped and delivered its map (``hil_sim.mission.mission_run``), the
Cliff-bot's flight code (:class:`fsw.tasks.cliffbot_mission.CliffbotMission` with its
devices and navigation) drives the bench's winches and wheels (:class:`hil_sim.team.cliffbot_rig.
CliffbotRig`, CAN frames of ``config/team.dbc``) on one stepped clock, on the map it received.
Before each leg it asks the RECON-bot for a fix over the same capped radio channel the map
crossed (:mod:`fsw.comm.team.fix_packets`): the RECON-bot, standing where its mission ended,
aims its mast at the Cliff-bot, renders the stereo pair of the world with the Cliff-bot at
its TRUE pose, runs the flight :class:`~fsw.core.localization.fiducials.CliffbotLocalizer`
and answers FIX (or NO_FIX). Everything is seeded: the same seed gives the same result.

:func:`run_team` returns the summary's ``team`` section (judged on the truth by
:mod:`hil_sim.team.team_eval`) and draws ``team.png``.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from fsw.comm.link_packets import PacketError
from fsw.comm.team import fix_packets
from fsw.core.geometry import CameraPose, MapGrid, point_mast
from fsw.core.localization.landmarks import Landmark, anchor_marker_corners
from fsw.core.team.cliffbot_nav import NavConfig
from fsw.core.team.climber_ground import ClimberConfig
from fsw.core.team.tether import TetherConfig
from fsw.drivers.cliffbot_devices import CliffbotDevices
from fsw.sections import CliffbotMissionConfig
from fsw.settings import FswConfig
from fsw.tasks.cliffbot_mission import CliffbotMission, fix_request, fix_xyyaw, navigate, new_navigator
from fsw.tasks.fixer.fix_pose import fix_camera, joints_covariance
from fsw.tasks.fixer.task import BODY_CENTRE_M, LIFT_M, NO_MARKERS, OUT_OF_REACH
from hil_sim.faults import FaultInjector, FaultSpec
from hil_sim.link.radio_channel import RadioChannel
from hil_sim.team.cliffbot_rig import CliffbotRig
from hil_sim.team.team_eval import FixError, TeamOutcome, fix_error, judge_team, winch_errors
from hil_sim.team.truth_way import truth_way_unknown
from hil_sim.world.world import World

F64 = NDArray[np.float64]
ToMap = Callable[[F64], F64]  # world points (N, 2) -> the received map's frame
RECON, CLIFF = "a", "b"  # the radio channel's sides, as in hil_sim.mission.mission_run


@dataclass
class TeamSetup:
    tether: TetherConfig = field(default_factory=TetherConfig)
    climber: ClimberConfig = field(default_factory=ClimberConfig)
    mission: CliffbotMissionConfig = field(default_factory=CliffbotMissionConfig)
    nav: NavConfig = field(default_factory=NavConfig)
    dt_s: float = 0.1
    max_s: float = 1800.0

    @classmethod
    def from_settings(cls, cfg: FswConfig, max_s: float = 1800.0) -> TeamSetup:
        """The Cliff-bot's tether, ground, navigation and mission sections of its flight file
        (``config/cliffbot.toml``, :func:`fsw.settings.load_settings`)."""
        return cls(cfg.tether, cfg.climber, cfg.cliffbot_mission, cfg.cliffbot_nav, max_s=max_s)


class ReconFixer:
    """The RECON-bot's side through the flight fixer's code (:mod:`fsw.tasks.fixer.task`):
    standing at ``recon_xy_yaw``, before its first answer it points the mast at each Anchorbot's
    plate and resects its camera on the plates it sees (:mod:`fsw.core.localization.landmarks`);
    per request it points the mast at the Cliff-bot's estimate (the request's ``x, y``, the
    ground there plus the marker band), renders the pair of the team (:meth:`CliffbotRig.world_now`:
    the Cliff-bot at its TRUE pose, the plates) and locates the markers with the camera pose the
    plates give (or the rover's pose, exact on this bench, when none was seen). NO_FIX reasons as
    the flight fixer's; ``answers`` counts each."""

    def __init__(self, world: World, recon_xy_yaw: tuple[float, float, float], seed: int,
                 fsw_config: Any | None = None) -> None:
        from fsw.core.localization.fiducials import CliffbotLocalizer
        from fsw.settings import DEFAULT_CONFIG, load_settings

        self.cfg = fsw_config or load_settings(DEFAULT_CONFIG)
        self.world, self.rover = world, recon_xy_yaw
        self.loc = CliffbotLocalizer(self.cfg.localization, self.cfg.cliffbot, self.cfg.camera.K,
                                     self.cfg.camera.baseline_m)
        self.rng = np.random.default_rng([seed, 2702])
        self.errors: list[FixError] = []
        self.landmarks: list[Landmark] | None = None  # the plates' views from where it stands
        self.answers: dict[str, int] = {}
        self.grid = MapGrid.from_config(world.map_grid)
        self.ground = np.asarray(world.ground_on_grid(self.grid), np.float64)

    def _view(self, rig: CliffbotRig, target: tuple[float, float, float]
              ) -> tuple[CameraPose, F64, NDArray[np.uint8], NDArray[np.uint8]] | None:
        """The pair of a view with the mast pointed at ``target`` and its joints' covariance;
        None when the mast does not reach it."""
        from fsw.core.geometry import camera_pose_from_rover
        from fsw.tasks.messages import NavPose
        from hil_sim.render import StereoRenderer

        joints, reachable = point_mast(self.rover, target, self.cfg.mast, LIFT_M)
        if not reachable:
            return None
        pose = camera_pose_from_rover(self.rover, joints, self.cfg.mast)
        nav = NavPose(0.0, self.rover[0], self.rover[1], self.rover[2], np.zeros((3, 3)), joints)
        rend = StereoRenderer(rig.world_now(), self.cfg.camera, self.world.noise_sigma,
                              seed=int(self.rng.integers(1 << 30)))
        left, right = rend.render(pose)
        return pose, joints_covariance(nav, self.cfg), left, right

    def _survey(self, rig: CliffbotRig) -> list[Landmark]:
        plates = anchor_marker_corners(rig.anchors[0], rig.anchors[1], self.cfg.localization)
        out: list[Landmark] = []
        for c in plates.values():
            view = self._view(rig, (float(c[:, 0].mean()), float(c[:, 1].mean()), float(c[:, 2].mean())))
            if view is None:
                continue
            est = self.loc.resect(plates, view[2], view[3])
            if est is not None and np.isfinite(est.cov).all():
                out.append(Landmark(est, view[0], view[1]))
        return out

    def _no_fix(self, seq: int, reason: int) -> bytes:
        name = fix_packets.NO_FIX_REASONS[reason]
        self.answers[name] = self.answers.get(name, 0) + 1
        return fix_packets.encode(fix_packets.NoFix(seq, reason))

    def answer(self, req: fix_packets.FixRequest, rig: CliffbotRig, now: float) -> bytes:
        from fsw.core.localization.localization import so3_log
        from fsw.core.team.tether import height_at

        cb = rig.cliffbot_truth()
        if self.landmarks is None:
            self.landmarks = self._survey(rig)
        if not (math.isfinite(req.x) and math.isfinite(req.y)):
            return self._no_fix(req.seq, OUT_OF_REACH)
        ground = height_at(self.ground, self.grid, (req.x, req.y))
        view = self._view(rig, (req.x, req.y, (ground if math.isfinite(ground) else cb.z) + BODY_CENTRE_M))
        if view is None:
            return self._no_fix(req.seq, OUT_OF_REACH)
        pose, joints_cov, left, right = view
        est = self.loc.locate(left, fix_camera(self.landmarks, pose, np.zeros((6, 6)), joints_cov), right,
                              req.attitude)
        if est is None or not np.isfinite(est.cov).all():
            return self._no_fix(req.seq, NO_MARKERS)
        self.errors.append(fix_error(est.t, so3_log(est.R @ cb.R.T), est.yaw - cb.yaw, est.cov, cb.t,
                                     float(np.linalg.norm(cb.t - pose.t))))
        self.answers["fix"] = self.answers.get("fix", 0) + 1
        return fix_packets.encode(fix_packets.Fix(req.seq, int(now * 1000), est.t, so3_log(est.R), est.cov))


class TruthFixer:
    """A stand-in for :class:`ReconFixer` without rendering: the TRUE pose plus noise drawn
    from the covariance it reports (``sigma_m``, ``sigma_deg``), offset by ``offset_m`` (a
    wrong fix, for the fault tests). Its errors are recorded like the real fixer's."""

    def __init__(self, seed: int, sigma_m: float = 0.01, sigma_deg: float = 0.5,
                 offset_m: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> None:
        self.rng = np.random.default_rng([seed, 2703])
        self.cov = np.diag([math.radians(sigma_deg) ** 2] * 3 + [sigma_m ** 2] * 3)
        self.offset = np.asarray(offset_m, float)
        self.errors: list[FixError] = []

    def answer(self, req: fix_packets.FixRequest, rig: CliffbotRig, now: float) -> bytes:
        from fsw.core.localization.localization import so3_log

        cb = rig.cliffbot_truth()
        e = self.rng.multivariate_normal(np.zeros(6), self.cov)
        e[3:] += self.offset
        yaw = cb.yaw + e[2]
        c, s_ = math.cos(yaw), math.sin(yaw)
        r = np.array([[c, -s_, 0.0], [s_, c, 0.0], [0.0, 0.0, 1.0]])
        self.errors.append(fix_error(cb.t + e[3:], e[:3], e[2], self.cov, cb.t))
        return fix_packets.encode(fix_packets.Fix(req.seq, int(now * 1000), cb.t + e[3:], so3_log(r), self.cov))


def run_team(world: World, grid: MapGrid, received_z: NDArray[np.floating], channel: RadioChannel, seed: int,
             setup: TeamSetup | None = None, recon_xy_yaw: tuple[float, float, float] | None = None,
             faults: tuple[FaultSpec, ...] = (), out: Path | None = None, t0: float = 0.0,
             fixer: ReconFixer | TruthFixer | None = None, recover_after_s: float | None = None,
             command_targets: F64 | None = None, error_bound_m: float = 0.0) -> dict[str, Any]:
    """The Cliff-bot's mission on the bench; returns the ``team`` summary section.

    ``recover_after_s``: a ground command leaves SAFE that long after it was entered (once);
    without it the run ends in SAFE. ``command_targets``: a ground command replacing the
    scenario's targets at the start. ``error_bound_m``: the received map's height error bound
    (the codec's, as the link delivers it)."""
    assert world.team is not None
    s = setup or TeamSetup()
    inj = FaultInjector(seed, faults)
    rig = CliffbotRig(world, grid, s.tether, s.climber, faults=inj, seed=seed)
    team = world.team
    recon = recon_xy_yaw or world.rover_start
    fixer = fixer if fixer is not None else ReconFixer(world, recon, seed)
    mission = CliffbotMission(s.mission, s.tether, s.climber, s.nav, rig.anchors, team.cliffbot_start_xy,
                              rig.yaw, team.targets_xyz[:, :2])
    nav = new_navigator(mission, s.nav)  # (the flight code's cb_nav task, here in the loop)
    dev = CliffbotDevices()
    mission.set_map(np.asarray(received_z, np.float64), grid, error_bound_m)
    assert mission.z is not None
    nav.set_map(mission.z, grid)
    if command_targets is not None:
        mission.set_targets(command_targets)
    sent0 = {side: channel.stats(side).air_bytes for side in (RECON, CLIFF)}
    now = t0
    est_path: list[tuple[float, float]] = []
    bad_packets = 0
    safe_at: float | None = None
    while now - t0 < s.max_s:
        now = round(now + s.dt_s, 6)
        rig.step(s.dt_s, now - t0)
        dev.receive(rig.poll(now - t0), now - t0)
        for d in channel.receive(CLIFF, now):
            try:
                p = fix_packets.decode(d)
            except PacketError:
                bad_packets += 1
                continue
            if isinstance(p, fix_packets.Fix):
                mission.on_fix(p, *nav.fix(*fix_xyyaw(p)))
            elif isinstance(p, fix_packets.NoFix):
                why = fix_packets.NO_FIX_REASONS[p.reason] if p.reason < len(fix_packets.NO_FIX_REASONS) else "?"
                mission.on_no_fix(p.seq, why)
        for d in channel.receive(RECON, now):
            try:
                q = fix_packets.decode(d)
            except PacketError:
                continue  # the map link's own packets (its acknowledgements) are the link's business
            if isinstance(q, fix_packets.FixRequest):
                channel.send(RECON, fixer.answer(q, rig, now), now)
        navigate(nav, dev, s.dt_s, s.mission.wheel_radius_m)
        mission.on_estimate(nav.nav.s, nav.nav.P)
        cmd = mission.step(now - t0, dev)
        if cmd.request_fix:
            channel.send(CLIFF, fix_packets.encode(fix_request(mission, dev)), now)
        rig.to_rig(dev.commands(cmd.rates_mps, cmd.enable, cmd.clear_faults, cmd.wheels_radps), now - t0)
        est_path.append((float(mission.est.s[0]), float(mission.est.s[1])))
        if mission.state == "SAFE":
            safe_at = now if safe_at is None else safe_at
            if recover_after_s is not None and now - safe_at >= recover_after_s:
                mission.recover()
                if mission.nav_reset is not None:
                    nav.reset(mission.nav_reset.s, mission.nav_reset.P)
                    mission.nav_reset = None
                safe_at = None
                recover_after_s = None  # one recovery attempt
            elif recover_after_s is None:
                break
        if mission.state == "DONE":
            break
    section = team_section(world, grid, received_z, rig, mission, fixer.errors,
                           link_bytes_down=channel.stats(RECON).air_bytes - sent0[RECON],
                           link_bytes_up=channel.stats(CLIFF).air_bytes - sent0[CLIFF],
                           link_bad_packets=bad_packets, can_bad_frames=dev.bad_frames, sim_s=now - t0,
                           est_path=est_path, out=out, setup=s)
    return section


def team_section(world: World, grid: MapGrid, received_z: NDArray[np.floating], rig: CliffbotRig,
                 mission: CliffbotMission, fixes: Sequence[FixError], *, link_bytes_down: int, link_bytes_up: int,
                 link_bad_packets: int, can_bad_frames: int, sim_s: float, est_path: list[tuple[float, float]],
                 out: Path | None = None, setup: TeamSetup | None = None, to_map: ToMap | None = None,
                 unknown_at_entry: frozenset[tuple[int, int]] | None = None) -> dict[str, Any]:
    """The summary's ``team`` section of a Cliff-bot mission (sequential, or on its own executive:
    ``hil_sim.team.team_bench``), judged on the truth by :mod:`hil_sim.team.team_eval`;
    ``team.png`` drawn in ``out``. ``to_map``: world points (N, 2) to the received map's frame
    (the RECON-bot's; None: the same frame); ``est_path`` is in the map's frame;
    ``unknown_at_entry``: the cells the driver saw the path enter unknown (None: judged on
    ``received_z``)."""
    s = setup or TeamSetup()
    to_map = to_map or _same
    outcome = TeamOutcome(
        reached=tuple(mission.reached), map_reasons=tuple(mission.reasons),
        true_path=tuple((float(x), float(y)) for x, y in to_map(np.asarray(rig.path, float))),
        violations=dict(rig.violations), hazard_cells=frozenset(rig.hazard_cells), fixes=tuple(fixes),
        fixes_used=mission.fixes_used, fixes_refused=mission.fixes_refused,
        link_bytes_down=link_bytes_down, link_bytes_up=link_bytes_up,
        link_bad_packets=link_bad_packets, can_bad_frames=can_bad_frames, final_state=mission.state,
        safe_reason=mission.safe_reason, events=tuple(tuple(e) for e in mission.events), sim_s=sim_s,
        looks=tuple(mission.looks), unknown_at_entry=unknown_at_entry)
    # the truth's planner on the truth's frame; the unknown cells on the received map's (the path above)
    section = judge_team(world, grid, received_z, rig.anchors, s.tether, s.climber, outcome,
                         winch_errors(s.mission.length_tol_m, s.mission.margin_sigmas)).section()
    section["truth_way"] = truth_way_unknown(world, grid, received_z, rig.anchors, s.tether, s.climber, to_map)
    if out is not None:
        section["picture"] = str(draw_team(out / "team.png", world, grid, received_z, rig, mission, est_path,
                                           to_map))
    return section


def _same(xy: F64) -> F64:
    return np.asarray(xy, float).reshape(-1, 2)


def draw_team(path: Path, world: World, grid: MapGrid, z: NDArray[np.floating], rig: CliffbotRig,
              mission: CliffbotMission, est_path: list[tuple[float, float]], to_map: ToMap = _same) -> Path:
    """The face map with the anchors, tethers, jumble, targets and the Cliff-bot's path, in the
    received map's frame (``to_map``: world points to it)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Ellipse

    assert world.team is not None
    fig, ax = plt.subplots(figsize=(7, 7))
    ext = (grid.x0, grid.x0 + grid.nx * grid.cell, grid.y0, grid.y0 + grid.ny * grid.cell)
    im = ax.imshow(np.ma.masked_invalid(np.asarray(z, float)), origin="lower", extent=ext, cmap="gray")
    fig.colorbar(im, ax=ax, shrink=0.7, label="received map height (m)")
    jx, jy, jax, jay = world.team.jumble_xy_r
    jx, jy = (float(v) for v in to_map(np.array([jx, jy]))[0])
    ax.add_patch(Ellipse((jx, jy), 2 * jax, 2 * jay, fill=False, color="orange", lw=1.5, label="rock jumble"))
    a = to_map(rig.anchors[:, :2])
    ax.plot(a[:, 0], a[:, 1], "bs", ms=8, label="Anchorbots")
    for k, p in enumerate(rig.state.paths):
        pts = to_map(np.vstack([rig.anchors[k, :2], p.contacts[:, :2] if len(p.contacts) else np.zeros((0, 2)),
                                rig.xy]))
        ax.plot(pts[:, 0], pts[:, 1], "b-", lw=1, label="tethers (final)" if k == 0 else None)
    tp = to_map(np.asarray(rig.path, float))
    ax.plot(tp[:, 0], tp[:, 1], "r-", lw=1.5, label="Cliff-bot path (truth)")
    if est_path:
        ep = np.asarray(est_path)
        ax.plot(ep[:, 0], ep[:, 1], "c--", lw=0.8, label="estimate")
    targets = to_map(world.team.targets_xyz[:, :2])
    for k, t in enumerate(targets):
        ok = mission.reached[k] if k < len(mission.reached) else False
        ax.plot(t[0], t[1], "g*" if ok else "mx", ms=12)
        ax.annotate(f"{k + 1}" + ("" if ok else f": {mission.reasons[k] or 'not reached'}"), (t[0], t[1]),
                    color="black", fontsize=8, xytext=(4, 4), textcoords="offset points",
                    bbox={"boxstyle": "round", "fc": "white", "alpha": 0.7})
    # the team's part of the map: anchors, targets, jumble and path with a margin
    pts = np.vstack([a, targets, tp, [[jx - jax, jy - jay], [jx + jax, jy + jay]]])
    lo, hi = pts.min(axis=0) - 0.8, pts.max(axis=0) + 0.8
    ax.set_xlim(max(lo[0], ext[0]), min(hi[0], ext[1]))
    ax.set_ylim(max(lo[1], ext[2]), min(hi[1], ext[3]))
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title("team mission: targets reached (*), not reached (x)")
    ax.legend(loc="lower left", fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
