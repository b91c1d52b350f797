"""Team views on the truth: imaging cycles of the RECON-bot alone or of both agents
(docs/team.md, "Team views"; ``safer-hil experiment team-sensing``).

A cycle: the agents' candidate views are rated on the one shared map and chosen by the flight's
team planner (``fsw.core.planning.team_views``: sequential greedy, the RECON-bot favouring the
Cliff-bot's corridor, the Cliff-bot paying tether motion); each chosen view is then *sensed* on
the TRUE ground and fused into the shared map and into that agent's own map with the flight's
fusion (``ElevationMap.merge_parts_steps``, §1, with that agent's flight fusion settings from its
camera centre: ``hil_sim.team.agent_fusion``; the shared map a ``TeamElevation``, §8: of two
inconsistent heights of a cell a tighter one above displaces the other).

The sensing is a model, not a rendering (so 30 scenes x two runs fit in minutes): a cell is
measured when its centre lies in the view's field and depth of field, its texture allows stereo
(``World.textureless_on_grid``) and the line of sight to it clears the TRUE ground (sampled every
2 cm, 2 cm of grazing allowed); four points are drawn on the true surface, one in each quarter of
the cell (jittered), each displaced by an error drawn from the stereo covariance (depth
deviation ``range^2 sigma_d / (f B)`` along the ray, ``range sigma_d / f`` across it, ``sigma_d``
= ``SIGMA_D_PX``) and fused with that covariance; the cells a view was expected to see and did
not record their misses (§3.4). The face map (§8.1) is fitted on the shared map once it holds
enough of the face and fed with every view's face share, one view at a time with its camera
centre, as the flight's pipeline feeds it (its free-space, facing and slab tests). Each map
keeps the lips its views found (``fsw.core.map.known_lips``; a view's lips as its stereo would find them:
:meth:`TeamViewsRun._lips`) and, as the flight's pipeline does, keeps the points under them out of
its gravity grid (docs/algorithm.md §4, the lip guard): a view from below the lip sees the face
under it, which the lip's cell must not average with the lip.

The Cliff-bot's corridor is its plan on the true ground on the scenario's map grid
(``face_planner.plan_targets``: start to every target it reaches, path +- ``corridor_half_m``);
with no target reachable, the straight way from its start toward the nearest target as far as
the tethers hold it there on the true ground (:meth:`TeamViewsRun._toward_nearest`: known
ground, neither slack nor over-tension, on the face where steeper than ``free_slope_deg``), the
way it would have to map to get closer. Team views choose where in that corridor it stops to
look (any place on the path within ``max_travel_m`` of where it stands, either way, and any
place across the corridor on ground the shared map knows where the tethers hold it) and where it
looks; its task is to map the corridor. The route is taken as planned beforehand, so where the
shared map does not know the ground yet its tether lengths come from the route's ground (the
truth), and before the face map is fitted the rating's face is the plane of the ground under
the route (``_plan_face``). Both agents are rated on the face's own cells where it lies (the
RECON-bot too: on the gravity grid the lip's height stands for the face below it, and views over
the lip are rated onto ground that is not there). Both agents' bits are weighted on the corridor
(``team_views.corridor_weights``), and each agent is rated with its own interest, decayed by its
own misses (``team_views.AgentInterest``, §8.2).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from fsw.core.geometry import CameraConfig, CameraPose, MapGrid
from fsw.core.map.elevation_map import ElevationMap, TeamElevation
from fsw.core.map.face_map import FaceFrame, FaceMap, FaceMapConfig, fit_face_map, split_parts
from fsw.core.map.face_plane import equal_memory_cell
from fsw.core.map.known_lips import KnownLips
from fsw.core.planning.face_rating import FaceCells, face_cells
from fsw.core.planning.info_planners import InformationPlanner
from fsw.core.planning.nbv import NbvConfig, info_n_max, predicted_visibility
from fsw.core.planning.planners import PlannerState
from fsw.core.planning.team_views import (
    AgentInterest,
    AgentViews,
    TeamView,
    TeamViewConfig,
    ViewCentre,
    choose_team_views,
    cliffbot_centres,
    corridor_mask,
    corridor_weights,
    recon_centres,
)
from fsw.core.planning.view_candidates import Station
from fsw.core.planning.visibility import in_view
from fsw.core.stereo.occlusion import LipGuard
from fsw.core.team.climber_ground import ClimberConfig
from fsw.core.team.face_planner import plan_targets
from fsw.core.team.standing_plane import surface_normal
from fsw.core.team.tether import TetherConfig, anchor_points, tether_states
from hil_sim.team.agent_fusion import agent_settings, merge_as
from hil_sim.team.team_figures import TeamFigures
from hil_sim.world.world import World

F64 = NDArray[np.float64]
B = NDArray[np.bool_]
SIGMA_D_PX = 0.3  # disparity deviation of the sensing model (px)
RECON_SETBACK_M = 0.8  # the RECON-bot's stations behind the edge


@dataclass
class CycleRecord:
    """One imaging cycle: each agent's view, expected and obtained new cells, and the team's figures."""

    cycle: int
    views: list[dict[str, Any]] = field(default_factory=list)
    new_cells: int = 0  # cells the cycle mapped for the first time (team)
    overlap: float | None = None  # cells both agents' views measured / cells either measured (two agents)
    overlap_of_smaller: float | None = None  # cells both agents' views measured / the smaller agent's cells
    # the overlap on the cells with information left for Eq 3 (measured fewer than info_n_max times
    # before the cycle): a view's rating gives the cells measured that often nothing, so two views
    # may share them at no cost
    overlap_open: float | None = None
    face_frac: float = 0.0  # of the face (truth slope > 45 deg) mapped after the cycle
    corridor_frac: float = 0.0  # of the corridor mapped after the cycle
    agent_face_frac: dict[str, float] = field(default_factory=dict)
    agent_corridor_frac: dict[str, float] = field(default_factory=dict)


class TeamViewsRun:
    """One scene, ``team=True`` (both agents) or the RECON-bot alone, deterministic per seed."""

    def __init__(self, world: World, seed: int, *, team: bool, cell_m: float = 0.08,
                 nbv: NbvConfig | None = None, tv: TeamViewConfig | None = None) -> None:
        from fsw.settings import load_settings

        if world.team is None:
            raise ValueError("the scene has no team")
        self.world, self.seed, self.team = world, seed, team
        self.rng = np.random.default_rng([seed, 2806, int(team)])
        cfg = load_settings(check_calibration=False)
        self.fusion = cfg.fusion  # the shared maps' own; each view is fused with its agent's (agent_settings)
        self.agent_fusion = {a: s.fusion for a, s in agent_settings(cfg).items()}
        self.camera: CameraConfig = dataclasses.replace(cfg.camera, calibration_file="")
        # the Cliff-bot's camera as its flight program has it ([cliffbot_sensing]: its usable depth
        # among the rest), for its candidates' rating and its views' sensing alike
        self.cliff_camera: CameraConfig = agent_settings(cfg)["cliffbot"].camera
        self.mast = cfg.mast
        self.nbv = nbv or dataclasses.replace(cfg.nbv, station_spacing_m=0.5, coarse_cell_m=0.0)
        self.tv = tv or TeamViewConfig()
        g0 = MapGrid.from_config(world.map_grid)
        k = max(1, int(round(cell_m / g0.cell)))
        self.grid = MapGrid(g0.x0, g0.y0, g0.cell * k, g0.nx // k, g0.ny // k)
        self.truth = np.asarray(world.ground_on_grid(self.grid), float)
        self.textured = ~world.textureless_on_grid(self.grid)
        self.map: ElevationMap = TeamElevation(self.grid, self.fusion)  # both agents' views meet here (§8)
        self.by_agent = {a: ElevationMap(self.grid, self.fusion) for a in ("recon", "cliffbot")}
        # the lips each map's views found: the shared map's ("team") and each agent's own
        self.lips = {a: KnownLips(self.grid) for a in ("team", "recon", "cliffbot")}
        # the interest each agent is rated with, decayed by its own misses only (§8.2)
        self.interest = AgentInterest(self.grid.shape, self.fusion.interest_beta)
        t = world.team
        self.tcfg, self.ccfg = TetherConfig(), ClimberConfig()
        self.anchors = anchor_points(self.truth, self.grid, t.anchors_xy, self.tcfg)
        fine = np.asarray(world.ground_on_grid(g0), float)  # its plan on the scenario's own grid
        plan = plan_targets(fine, g0, anchor_points(fine, g0, t.anchors_xy, self.tcfg), t.cliffbot_start_xy,
                            t.targets_xyz[:, :2], self.tcfg, self.ccfg)
        legs = [p for p in plan.paths if p is not None]
        start = np.asarray(t.cliffbot_start_xy, float).reshape(1, 2)
        self.reachable = bool(legs)
        if not legs:  # no target reachable: the way toward the nearest, as far as the tethers hold it
            legs = [self._toward_nearest(start[0], np.asarray(t.targets_xyz, float)[:, :2])]
        self.path = np.concatenate([start] + [np.vstack([p, p[::-1]]) for p in legs])  # out to each target and back
        self.corridor = corridor_mask(self.grid, self.path, self.tv.corridor_half_m)
        slope = _slope_deg(self.truth, self.grid.cell)
        self.face = np.isfinite(self.truth) & (slope > 45.0)
        self.cliff_xy = start[0].copy()
        self.head = (0.0, 0.0)
        edge = np.asarray(world.edge_xy, float)
        self.edge = edge[np.argsort(edge[:, 0])]
        self.rover = (float(t.cliffbot_start_xy[0]) - 2.0, self._edge_y(float(t.cliffbot_start_xy[0]) - 2.0)
                      + RECON_SETBACK_M, 0.0)
        self.joints = (-math.pi / 2, math.radians(-45.0), 0.5)
        self.records: list[CycleRecord] = []
        self.face_map: FaceMap | None = None
        self._path_face: FaceMap | bool | None = None  # the rating's face before the fit (False: none)
        self._pending: list[tuple[list[tuple[F64, F64, F64 | None]], F64, float]] = []  # views before the fit
        self.figures = TeamFigures(self.grid.cell, self.ccfg.wheel_d_m, seed)
        self.events: list[dict[str, object]] = []

    def _toward_nearest(self, start: F64, targets: F64, step_m: float = 0.1) -> F64:
        """The straight way from the start to the nearest target, up to the first place where the
        tethers do not hold the Cliff-bot on the true ground (unknown, slack, over-tension, off
        the face where it is steeper than ``free_slope_deg``): the corridor of a scene with no
        reachable target (module docstring)."""
        goal = targets[int(np.argmin(np.linalg.norm(targets - start, axis=1)))]
        k = max(1, int(math.ceil(float(np.linalg.norm(goal - start)) / step_m)))
        line = start + (goal - start) * np.linspace(0.0, 1.0, k + 1)[:, None]
        held = [st is not None and (st.statics.ok or st.statics.tilt_deg <= self.ccfg.free_slope_deg)
                for st in tether_states(self.truth, self.grid, self.anchors, line, self.tcfg)]
        n = int(np.argmin(held)) if not all(held) else len(held)
        return line[:max(n, 1)]

    def _edge_y(self, x: float) -> float:
        return float(np.interp(x, self.edge[:, 0], self.edge[:, 1]))

    # -- candidates ---------------------------------------------------------------------------
    def _recon(self) -> AgentViews:
        """Stations behind the edge every ``station_spacing_m`` within ``max_travel_m`` of the rover,
        heading along the edge (either way), the mast's grid at each."""
        cfg = self.nbv
        xs = self.rover[0] + np.arange(-cfg.max_travel_m, cfg.max_travel_m + 1e-9, cfg.station_spacing_m)
        return AgentViews("recon", self.camera, self._recon_centres(xs), self.interest.of("recon"),
                          weight=corridor_weights(self.corridor, self.tv), face=self._face_cells())

    def _recon_centres(self, xs: F64) -> tuple[ViewCentre, ...]:
        """The RECON-bot's camera centres at stations behind the edge at ``xs`` (those on the grid,
        a metre in from its sides), heading along the edge away from the rover, the mast's grid at
        each, each with its motion from where the rover stands."""
        lo, hi = self.grid.x0 + 1.0, self.grid.x0 + self.grid.nx * self.grid.cell - 1.0
        stations = []
        for x in xs[(xs >= lo) & (xs <= hi)]:
            y = self._edge_y(float(x)) + RECON_SETBACK_M
            travel = math.hypot(float(x) - self.rover[0], y - self.rover[1])
            stations.append(Station((float(x), y, 0.0 if x >= self.rover[0] else math.pi), travel))
        planner = InformationPlanner("team", self.nbv, self.camera, self.mast, use_interest=True)
        state = PlannerState(self.map, self.rover, self.joints, np.zeros((0, 2)), lambda *_: None, None,
                             float(np.nan_to_num(self.truth_at(self.rover[:2]))))
        return recon_centres(planner.view_centres(state, stations))

    def _face_cells(self) -> FaceCells | None:
        """The face as both agents' ratings see it (``face_rating.face_cells``): the face map once
        fitted, before that the plane under the Cliff-bot's route (:meth:`_plan_face`)."""
        face = self.face_map or self._plan_face(np.where(self.map.mapped, self.map.z, self.truth))
        return None if face is None else face_cells(face, self.map, self.nbv.visibility, self.tv.face_prior_m)

    def _cliff(self) -> AgentViews:
        # its route was planned beforehand (module docstring): where the shared map does not know
        # the ground yet, the tether lengths and the head's place come from the route's own ground
        z = np.where(self.map.mapped, self.map.z, self.truth)
        centres = cliffbot_centres(z, self.grid, self.anchors, self.path, self.cliff_xy, self.head, self.tcfg,
                                   self.tv, both_ways=True, known=self.map.mapped,
                                   free_slope_deg=self.ccfg.free_slope_deg)
        k = int(np.argmin(np.linalg.norm(self.path - self.cliff_xy, axis=1)))
        ahead = self.path[min(k + 1, len(self.path) - 1):]
        step = next((p for p in ahead if np.linalg.norm(p - self.path[k]) > 0.5), ahead[-1])
        d = step - self.path[k]
        yaw = math.atan2(float(d[1]), float(d[0])) if float(np.hypot(*d)) > 1e-6 else -math.pi / 2
        # the corridor is its own task's focus too
        return AgentViews("cliffbot", self.cliff_camera, centres, self.interest.of("cliffbot"),
                          corridor_weights(self.corridor, self.tv), (yaw, math.radians(-50.0)),
                          self._face_cells(), views=self.tv.cliffbot_views)

    def _plan_face(self, z: F64) -> FaceMap | None:
        """Before the face map is fitted on the shared map: an empty face map in the plane of the
        ground under the Cliff-bot's planned path (where steeper than 45 deg: the mean of its
        points and of their normals), over that stretch of the dip; None when the path stays off
        the face."""
        if self._path_face is None:
            run = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(self.path, axis=0), axis=1))])
            s = np.arange(0.0, run[-1] + 1e-9, 0.1)
            xy = np.column_stack([np.interp(s, run, self.path[:, 0]), np.interp(s, run, self.path[:, 1])])
            pts, normals = [], []
            for p in xy:
                n = surface_normal(z, self.grid, p, 0.3)
                iy, ix, inside = self.grid.cell_index(p[:1], p[1:2])
                if n is not None and inside[0] and n[2] < math.cos(math.radians(45.0)):
                    pts.append([p[0], p[1], float(z[iy[0], ix[0]])])
                    normals.append(n)
            if len(pts) < 3:
                self._path_face = False
                return None
            try:
                frame = FaceFrame.from_normal(np.mean(pts, axis=0), np.mean(normals, axis=0))
            except ValueError:
                self._path_face = False
                return None
            q = frame.to_face(np.asarray(pts, float))
            x0, x1, y0, y1 = self.grid.extent
            cx, cy = np.array([x0, x1, x1, x0]), np.array([y0, y0, y1, y1])
            corners = frame.to_face(np.column_stack([cx, cy, frame.plane_z(cx, cy)]))
            fc = dataclasses.replace(FaceMapConfig(), cell_m=equal_memory_cell(self.grid.cell, frame.slope_deg))
            self._path_face = FaceMap(frame, (float(corners[:, 0].min()), float(corners[:, 0].max())),
                                      (float(q[:, 1].min()), float(q[:, 1].max()) + fc.cell_m), fc, self.fusion)
        return self._path_face or None

    def truth_at(self, xy: tuple[float, ...]) -> float:
        iy, ix, inside = self.grid.cell_index(np.array([xy[0]]), np.array([xy[1]]))
        return float(self.truth[iy[0], ix[0]]) if inside[0] else 0.0

    # -- one cycle ----------------------------------------------------------------------------
    def cycle(self) -> CycleRecord:
        agents = [self._recon()] + ([self._cliff()] if self.team else [])
        candidates = {a.agent: sum(c.yaws.size * c.tilts.size for c in a.centres) for a in agents}
        views, _ = choose_team_views(self.map, agents, self.nbv, self.corridor)
        rec = CycleRecord(len(self.records) + 1)
        before = self.map.mapped.copy()
        open_cells = self.map.n < info_n_max(self.map, self.nbv)
        seen: dict[str, B] = {}
        start = np.asarray(self.world.team.cliffbot_start_xy if self.world.team else (0.0, 0.0), float)
        for v in views:
            cam = self.cliff_camera if v.agent == "cliffbot" else self.camera
            known = self.map.mapped.copy()
            cells = self._sense(v, cam)
            seen[v.agent] = seen[v.agent] | cells if v.agent in seen else cells  # an agent's views together
            new = cells & ~before
            rec.views.append({**v.event(), "candidates": candidates[v.agent], "obtained_cells": int(cells.sum()),
                              "obtained_new_cells": int(new.sum()),
                              # what this view itself made known (the views before it in the cycle taken)
                              "added_cells": int((self.map.mapped & ~known).sum()),
                              "travel_m": round(float(np.hypot(v.place[0] - start[0], v.place[1] - start[1])), 2)})
            self.events.append({"cycle": rec.cycle, "event": "TEAM_VIEW", **v.event()})
            self._move(v)
        rec.new_cells = int((self.map.mapped & ~before).sum())
        if len(seen) == 2:
            a, b = seen["recon"], seen["cliffbot"]
            small, either = min(int(a.sum()), int(b.sum())), int((a | b).sum())
            rec.overlap = float((a & b).sum()) / either if either else 0.0
            rec.overlap_of_smaller = float((a & b).sum()) / small if small else 0.0
            either_open = int(((a | b) & open_cells).sum())
            rec.overlap_open = float((a & b & open_cells).sum()) / either_open if either_open else 0.0
        rec.face_frac = _frac(self.map.mapped, self.face)
        rec.corridor_frac = _frac(self.map.mapped, self.corridor)
        for name, m in self.by_agent.items():
            rec.agent_face_frac[name] = _frac(m.mapped, self.face)
            rec.agent_corridor_frac[name] = _frac(m.mapped, self.corridor)
        self.records.append(rec)
        self.figures.add_cycle({a: np.where(m.mapped, m.z, np.nan) for a, m in self.by_agent.items() if a in seen
                                or a == "recon" or self.team}, rec.views, rec.overlap)
        return rec

    def _move(self, v: TeamView) -> None:
        if v.agent == "recon":
            self.rover = (v.place[0], v.place[1], v.place[2])
            self.joints = (v.yaw - v.place[2], v.tilt, v.place[3])
            return
        self.cliff_xy = np.array(v.place[:2])
        self.head = (v.yaw, v.tilt)

    def _sense(self, v: TeamView, cam: CameraConfig) -> B:
        """The cells the view measures on the truth (module docstring), fused into the shared map
        and the agent's own."""
        g = self.grid
        pose = CameraPose.from_pan_tilt(*v.xyz, v.yaw, v.tilt)
        iy, ix = np.nonzero(np.isfinite(self.truth) & self.textured)
        pts = np.column_stack([g.x0 + (ix + 0.5) * g.cell, g.y0 + (iy + 0.5) * g.cell, self.truth[iy, ix]])
        vis = in_view(pose, cam, pts)
        out = np.zeros(g.shape, bool)
        ok = self._line_of_sight(pose.t, pts[vis]) if vis.any() else np.zeros(0, bool)
        iy, ix = iy[vis][ok], ix[vis][ok]
        out[iy, ix] = True
        lips = LipGuard(g, *self._lips(pose, cam, pts[vis][ok]), self.fusion.lip_min_drop_m)
        sub = np.array([0.25, 0.75])  # four points per cell, one in each quarter (jittered)
        fx = (sub[None, :, None] + 0.2 * (self.rng.random((ix.size, 2, 2)) - 0.5)).reshape(ix.size, 4)
        fy = (sub[None, None, :] + 0.2 * (self.rng.random((ix.size, 2, 2)) - 0.5)).reshape(ix.size, 4)
        x = (g.x0 + (ix[:, None] + fx) * g.cell).ravel()
        y = (g.y0 + (iy[:, None] + fy) * g.cell).ravel()
        z = np.asarray(self.world.ground_at(x, y), float)
        z = np.where(np.isfinite(z), z, np.repeat(self.truth[iy, ix], 4))
        p = np.column_stack([x, y, z])
        ray = p - pose.t
        rng_m = np.linalg.norm(ray, axis=1)
        d = ray / rng_m[:, None]
        f = cam.width_px / (2.0 * math.tan(math.radians(cam.hfov_deg) / 2.0))
        s_depth = rng_m**2 * SIGMA_D_PX / (f * cam.baseline_m)
        s_lat = rng_m * SIGMA_D_PX / f
        dd = d[:, :, None] * d[:, None, :]
        cov = s_depth[:, None, None] ** 2 * dd + s_lat[:, None, None] ** 2 * (np.eye(3)[None] - dd)
        e = np.einsum("nij,nj->ni", np.linalg.cholesky(cov + 1e-12 * np.eye(3)[None]),
                      self.rng.standard_normal((x.size, 3)))
        xyz = p + e
        # the misses of §3.4, against the visibility the view was chosen with (the face's own cells
        # for a view rated on the face)
        expect = v.p_visible if v.p_visible is not None else predicted_visibility(self.map, pose, cam,
                                                                                   self.nbv.visibility)
        self._merge(self.map, "team", v.agent, pose.t, lips, xyz, cov, expect)
        hy, hx, inside = g.cell_index(xyz[:, 0], xyz[:, 1])
        hit = np.zeros(g.shape, bool)
        hit[hy[inside], hx[inside]] = True
        self.interest.record(v.agent, np.clip(expect, 0.0, 1.0), hit)  # this agent's misses only (§8.2)
        self._merge(self.by_agent[v.agent], v.agent, v.agent, pose.t, lips, xyz, cov, None)
        if xyz.size:
            self._to_face([(xyz, cov, None)], pose.t, cam.max_range_m)
        return out

    def _merge(self, emap: ElevationMap, owner: str, agent: str, eye: F64, lips: LipGuard, xyz: F64, cov: F64,
               p_visible: F64 | B | None) -> None:
        """A view of ``agent`` (camera centre ``eye``) into one gravity grid, as that agent's flight
        pipeline fuses it (``SensingPipeline.remember_lips`` and ``fuse_steps``, with the agent's
        fusion settings: ``hil_sim.team.agent_fusion``): the view's lips join the lips that map
        knows (the harness's poses are exact: no pose variance), and the points under them stay
        out of it."""
        fusion = self.agent_fusion[agent]
        known = self.lips[owner]
        known.add(lips.near, lips.toward, np.zeros(lips.near.shape[0]))
        parts = [(xyz.copy(), cov.copy(), None)]
        guard = known.guard(fusion.lip_min_drop_m)
        merge_as(emap, parts if guard is None else guard.gravity_parts(parts, fusion.lip_guard_sigma), fusion, eye,
                 p_visible)

    def _lips(self, pose: CameraPose, cam: CameraConfig, pts: F64, step_m: float = 0.02,
              tol_m: float = 0.02) -> tuple[F64, F64]:
        """The view's occluding lips as its stereo finds them (``fsw.core.stereo.occlusion``): of
        the cell centres it sees (``pts``), those whose sight line, continued past the centre, runs
        on through air (it is not in the ground one cell further) and meets textured ground again
        inside the image and the depth range, as the pixels just above the cell's see it: ``(near,
        far)``, the centre and that ground (``LipGuard`` counts those that drop more than
        ``lip_min_drop_m``)."""
        near: list[F64] = []
        far: list[F64] = []
        g, eye = self.grid, pose.t
        for a in range(0, len(pts), 2000):
            p = pts[a:a + 2000]
            ray = p - eye
            rng_m = np.linalg.norm(ray, axis=1)
            q1 = p + ray * (g.cell / rng_m)[:, None]
            go_on = ~(q1[:, 2] < np.asarray(self.world.ground_at(q1[:, 0], q1[:, 1]), float) - tol_m)
            p, ray, rng_m = p[go_on], ray[go_on], rng_m[go_on]
            if not p.size:
                continue
            s_max = cam.max_range_m / np.einsum("ij,j->i", ray, pose.R[:, 2])  # depth grows with s
            k = int(np.ceil(float(np.max((s_max - 1.0) * rng_m)) / step_m))
            if k < 1:
                continue
            s = 1.0 + np.arange(1, k + 1)[None, :] * (step_m / rng_m)[:, None]
            q = eye[None, None, :] + s[:, :, None] * ray[:, None, :]
            ground = np.asarray(self.world.ground_at(q[..., 0], q[..., 1]), float)
            hit = (q[..., 2] < ground - tol_m) & (s <= s_max[:, None])
            first = np.argmax(hit, axis=1)
            rows = np.nonzero(hit.any(axis=1))[0]
            f = q[rows, first[rows]]
            fy, fx, inside = g.cell_index(f[:, 0], f[:, 1])
            seen = np.zeros(rows.size, bool)
            seen[inside] = self.textured[fy[inside], fx[inside]]
            seen &= in_view(pose, cam, f)
            near.append(p[rows[seen]])
            far.append(f[seen])
        if not near:
            return np.zeros((0, 3)), np.zeros((0, 3))
        return np.concatenate(near), np.concatenate(far)

    def _to_face(self, parts: list[tuple[F64, F64, F64 | None]], eye: F64, reach_m: float) -> None:
        """The face map beside the gravity grid (docs/algorithm.md §8.1): fitted on the shared map
        once it holds enough of the face (the views before the fit are fused then, one by one),
        fed with the face's share of every view as the flight's pipeline feeds it: one view at a
        time, with its camera centre ``eye`` (the free space and facing tests, the steps' term)
        and all its points (the slab test), ``reach_m`` its camera's usable depth."""
        if self.face_map is None:
            self._pending.append((parts, eye, reach_m))
            try:
                self.face_map = fit_face_map(self.map, self.fusion)
            except ValueError:
                return
            views, self._pending = self._pending, []
        else:
            views = [(parts, eye, reach_m)]
        for view, at, reach in views:
            self.face_map.merge_parts(split_parts(view, self.face_map)[0], eye=at, rays=view, max_range_m=reach)

    def section(self) -> dict[str, Any]:
        """The team figures of the summary (``hil_sim.team.team_figures``) for this run."""
        face = None if self.face_map is None else (self.world, self.face_map, self.map)
        return self.figures.section(face, "" if face else "the face plane could not be fitted on the map")

    def _line_of_sight(self, eye: F64, pts: F64, step_m: float = 0.02, tol_m: float = 0.02) -> B:
        """Whether the segment from ``eye`` to each point stays above the TRUE ground (sampled every
        ``step_m``, the last ``3 tol_m`` before the point excepted, ``tol_m`` of grazing allowed)."""
        out = np.zeros(len(pts), bool)
        for a in range(0, len(pts), 2000):
            p = pts[a:a + 2000]
            ray = p - eye
            rng_m = np.linalg.norm(ray, axis=1)
            k = int(np.ceil(rng_m.max() / step_m))
            s = np.linspace(0.0, 1.0, k + 1)[None, :] * np.maximum(0.0, 1.0 - 3 * tol_m / rng_m)[:, None]
            q = eye[None, None, :] + s[:, :, None] * ray[:, None, :]
            ground = np.asarray(self.world.ground_at(q[..., 0], q[..., 1]), float)
            out[a:a + 2000] = np.all(~(q[..., 2] < ground - tol_m), axis=1)
        return out

    # -- figures ------------------------------------------------------------------------------
    def fused_vs_better(self) -> dict[str, float | int | None]:
        """RMS error against the truth on the cells both agents mapped: each agent's own map and the
        shared (fused) one; and the share of cells whose error is within 2 sigma of the map's own
        variance, on those cells (``in2sig_*``) and on every cell each map holds (``in2sig_*_own``):
        a map whose variance is too small there leans the fused estimate its way."""
        a, b = self.by_agent["recon"], self.by_agent["cliffbot"]
        both = a.mapped & b.mapped & self.map.mapped & np.isfinite(self.truth)
        out: dict[str, float | int | None] = {"both_cells": int(both.sum())}
        for name, m in (("recon", a), ("cliffbot", b), ("fused", self.map)):
            e = m.z[both] - self.truth[both]
            out[f"rmse_{name}_m"] = float(np.sqrt(np.mean(e * e))) if e.size else None
            out[f"in2sig_{name}"] = _within_2_sigma(m, self.truth, both)
            out[f"in2sig_{name}_own"] = _within_2_sigma(m, self.truth, m.mapped & np.isfinite(self.truth))
        return out

    def corridor_left(self) -> dict[str, int]:
        """What bounds the corridor's coverage: its cells still unmapped, and how many of them lie
        in range and in line of sight (on the truth) of some camera centre the agents' next
        candidates offer (any pointing)."""
        g = self.grid
        iy, ix = np.nonzero(self.corridor & ~self.map.mapped & np.isfinite(self.truth))
        pts = np.column_stack([g.x0 + (ix + 0.5) * g.cell, g.y0 + (iy + 0.5) * g.cell, self.truth[iy, ix]])
        seen = np.zeros(len(pts), bool)
        agents = [self._recon()] + ([self._cliff()] if self.team else [])
        for a in agents:
            seen |= self._seen_from(pts, a.centres, a.camera)
        return {"corridor_left_cells": int(len(pts)), "corridor_left_seeable": int(seen.sum())}

    def _seen_from(self, pts: F64, centres: Sequence[ViewCentre], cam: CameraConfig) -> B:
        """Which of ``pts`` some of the camera ``centres`` has in range and in line of sight on
        the truth (any pointing)."""
        seen = np.zeros(len(pts), bool)
        for c in centres:
            r = np.linalg.norm(pts - np.asarray(c.xyz, float), axis=1)
            k = np.nonzero(~seen & (r >= cam.min_range_m) & (r <= cam.max_range_m))[0]
            if k.size:
                seen[k[self._line_of_sight(np.asarray(c.xyz, float), pts[k])]] = True
        return seen

    def recon_reach_left(self) -> int:
        """The ground left within the RECON-bot's reach: the unmapped cells stereo could map (on
        the grid, textured) that some camera centre of a RECON-bot station anywhere behind the
        edge (every ``station_spacing_m`` along it) has in range and in line of sight on the
        truth, any pointing. Where it is small the scene is used up for the RECON-bot: its views
        can add few new cells wherever it goes, whichever agent mapped the rest."""
        g, cam = self.grid, self.camera
        iy, ix = np.nonzero(~self.map.mapped & np.isfinite(self.truth) & self.textured)
        pts = np.column_stack([g.x0 + (ix + 0.5) * g.cell, g.y0 + (iy + 0.5) * g.cell, self.truth[iy, ix]])
        xs = np.arange(g.x0, g.x0 + g.nx * g.cell, self.nbv.station_spacing_m)
        return int(self._seen_from(pts, self._recon_centres(xs), cam).sum())

    def cycles_to_corridor(self, frac: float, cap: int) -> int | None:
        """The first cycle after which the corridor is mapped to ``frac``: the cycles run so far,
        then more cycles (the same choice and sensing) until it is or ``cap`` cycles have run
        (None: not within ``cap``). A run that reached it stops there, so a slow arm costs
        cycles only until it gets there."""
        hit = next((r.cycle for r in self.records if r.corridor_frac >= frac), None)
        while hit is None and len(self.records) < cap:
            rec = self.cycle()
            hit = rec.cycle if rec.corridor_frac >= frac else None
        return hit

    def cells_by_agent(self) -> dict[str, int]:
        return {k: int(m.mapped.sum()) for k, m in self.by_agent.items()}


def _within_2_sigma(m: ElevationMap, truth: F64, cells: B) -> float | None:
    """The share of ``cells`` whose height in ``m`` is within 2 sigma (its own variance) of the truth."""
    if not cells.any():
        return None
    return float(np.mean(np.abs(m.z[cells] - truth[cells]) <= 2.0 * np.sqrt(m.var[cells])))


def _frac(mapped: B, region: B) -> float:
    n = int(region.sum())
    return float((mapped & region).sum()) / n if n else 1.0


def _slope_deg(z: F64, cell: float) -> F64:
    gy, gx = np.gradient(np.nan_to_num(z), cell)
    return np.asarray(np.degrees(np.arctan(np.hypot(gx, gy))), float)


def run_scene(spec: str, seed: int, *, team: bool, cycles: int, cell_m: float = 0.08,
              tv: TeamViewConfig | None = None) -> TeamViewsRun:
    """``cycles`` imaging cycles of one seeded scene (``tv``: the team views' configuration)."""
    from hil_sim.world import load_scenario

    run = TeamViewsRun(load_scenario(spec, seed), seed, team=team, cell_m=cell_m, tv=tv)
    for _ in range(cycles):
        run.cycle()
    return run
