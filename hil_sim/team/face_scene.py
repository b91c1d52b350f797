"""One cliff-team scene seen by both agents, for ``safer-hil experiment face-map`` and its tests.

:class:`FaceScene` places the team (RECON-bot mast poses behind the edge, the Cliff-bot on the
face on its two tethers), renders each view with the team in the picture, runs it through the
sensing pipeline on its agent's flight settings (``hil_sim.team.agent_fusion``) with the team
mask at the estimated poses and fuses it into the gravity-only grid, the face map with its
gravity grid, and the one-agent face maps; :meth:`FaceScene.measure` returns the figures
(``hil_sim.lab.experiments.experiment_face_map``).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage

from fsw.core.geometry import CameraPose, MapGrid, camera_pose_from_rover, point_mast
from fsw.core.map.body_mask import BodyBox, TeamGeometry, TetherLine, anchorbot_box
from fsw.core.map.elevation_map import ElevationMap
from fsw.core.map.face_map import FaceMap, FaceMapConfig, fit_face_map, split_parts
from fsw.core.pipeline import RegisteredPose, SensingPipeline, ViewPart
from fsw.core.registration.registration import Registration
from fsw.core.steps import run_to_end
from fsw.core.stereo.stereo import StereoPoints
from fsw.core.team.standing_plane import surface_normal
from fsw.core.team.tether import TetherConfig, anchor_points, tether_state
from fsw.tasks.perception import SITE_MASK
from hil_sim.team.agent_fusion import agent_settings, merge_as
from hil_sim.team.face_eval import (
    face_figures,
    frame_off_deg,
    frame_off_true_deg,
    relief_rise,
    truth_along_normal,
)
from hil_sim.team.team_sensing import (
    ANCHOR_HALF_M,
    RECON_HALF_M,
    TETHER_RADIUS_M,
    TeamPose,
    cliffbot_camera_pose,
    team_quads,
    yaw_box,
)
from hil_sim.world.cliffbot import build_cliffbot
from hil_sim.world.world import World

F32 = NDArray[np.float32]
F64 = NDArray[np.float64]
RECON_SIGMA = (math.radians(0.2), 0.01)  # camera pose error: rotation (rad), translation (m)
CLIFF_SIGMA = (math.radians(0.5), 0.02)
SURVEY_SIGMA_M = 0.03  # the Anchorbots' surveyed ground points (the flight's [cliffbot_site] start sigma)


def pose_cov(sigma: tuple[float, float]) -> F64:
    return np.diag([sigma[0] ** 2] * 3 + [sigma[1] ** 2] * 3)


def perturbed(pose: CameraPose, cov: F64, rng: np.random.Generator) -> CameraPose:
    """The pose with an error drawn from ``cov`` (rotation about world axes, then translation)."""
    import cv2

    e = rng.multivariate_normal(np.zeros(6), cov)
    dR = cv2.Rodrigues(e[:3].reshape(3, 1))[0]
    return CameraPose(dR @ pose.R, pose.t + e[3:])


def team_points(pts: StereoPoints, quad: NDArray[np.bool_], terrain: F32, grow_px: int = 3) -> NDArray[np.bool_]:
    """The truth's judge of a view's stereo points: on a robot or a tether when the point's left
    pixel is within ``grow_px`` of a pixel that sees one (``quad``; a matching window straddling
    an outline gives its pixels the robot's depth) and the point lies in front of the nearest
    terrain seen within ``grow_px`` of it (``terrain`` depth) by more than 5 cm and 3 sigma of
    its depth (a window straddling a terrain lip gives the lip's depth: that is terrain)."""
    h, w = quad.shape
    size = 2 * grow_px + 1
    near = ndimage.binary_dilation(quad, iterations=grow_px) if grow_px > 0 else quad
    nearest = ndimage.minimum_filter(np.nan_to_num(terrain, nan=np.inf), size=size)
    u = np.clip(np.rint(pts.uv[:, 0]).astype(np.intp), 0, w - 1)
    v = np.clip(np.rint(pts.uv[:, 1]).astype(np.intp), 0, h - 1)
    tol = np.maximum(0.05, 3.0 * np.sqrt(np.maximum(pts.cov_c[:, 2, 2], 0.0)))
    return np.asarray(near[v, u] & (pts.xyz_c[:, 2] < nearest[v, u] - tol), bool)


def true_points(pose: CameraPose, K: F64, depth: F32, quad: NDArray[np.bool_], most: int = 20000) -> F64:
    """World points ``(N, 3)`` of the true terrain a view sees (``depth``: the renderer's terrain
    depth per pixel, NaN none; pixels showing a robot or a tether left out), at most ``most``
    of them, evenly spread over the image."""
    v, u = np.nonzero(np.isfinite(depth) & ~quad)
    sel = np.unique(np.linspace(0, len(v) - 1, min(len(v), most)).astype(np.intp)) if len(v) else v
    v, u = v[sel], u[sel]
    z = depth[v, u].astype(np.float64)
    pc = np.column_stack([(u - K[0, 2]) * z / K[0, 0], (v - K[1, 2]) * z / K[1, 1], z])
    return np.asarray(pc @ pose.R.T + pose.t, float)


class FaceScene:
    def __init__(self, spec: str, seed: int, config: str, mask: bool = True,
                 resolve_cells: float | None = None) -> None:
        """``mask``: the team mask on (the flight's way); off shows what it keeps out.
        ``resolve_cells``: the face map's incidence limit (``FaceMapConfig.resolve_cells``;
        None: its default)."""
        from fsw.settings import load_settings
        from hil_sim.world import load_scenario

        self.world: World = load_scenario(spec, seed)
        if self.world.team is None:
            raise ValueError(f"{spec} has no team")
        self.seed = seed
        self.mask = mask
        self.resolve_cells = resolve_cells
        self.rng = np.random.default_rng([seed, 2801])
        cfg = load_settings(config, check_calibration=False)
        off = dataclasses.replace(cfg.registration, enabled=False)
        self.cfg = dataclasses.replace(cfg, camera=dataclasses.replace(cfg.camera, calibration_file=""),
                                       registration=off)
        # each agent's views through its own flight pipeline's settings (the Cliff-bot's camera,
        # disparity search and fusion: fsw.tasks.cliffbot.sensing.CliffbotPipelineSettings)
        self.settings = agent_settings(self.cfg)
        sc = self.world.config
        assert sc is not None
        self.grid = MapGrid.from_config(sc.map)
        self.gravity = ElevationMap(self.grid, self.cfg.fusion)  # every point: the one-grid map
        self.split_gravity = ElevationMap(self.grid, self.cfg.fusion)
        self.face: FaceMap | None = None
        self.fit_views: int | None = None  # the views fused when the face plane was fitted
        self.by_agent: dict[str, FaceMap] = {}
        self.pending: list[tuple[str, list[ViewPart], F64, float]] = []  # agent, parts, camera centre, window
        self.team_points = 0  # stereo points on a robot or a tether (truth): what the mask had to remove
        self.team_points_fused = 0  # of those, the ones that reached the maps
        self.team_cells: set[tuple[int, int]] = set()  # the gravity-grid cells those fell in
        self.views = 0
        self.true_rays: list[tuple[F64, F64]] = []  # per view: true camera centre, true surface points seen
        self.cells_by_agent = {"recon": 0, "cliffbot": 0}
        self.z_grid = self.world.ground_on_grid(self.grid)
        self.tcfg = TetherConfig()
        self.anchors = anchor_points(self.z_grid, self.grid, self.world.team.anchors_xy, self.tcfg)

    # -- the team ---------------------------------------------------------------------------
    def cliffbot_at(self, depth_frac: float, dx: float, rover: tuple[float, float, float]
                    ) -> tuple[F64, F64, TeamPose, Any]:
        """The Cliff-bot on the face at ``depth_frac`` of the drop, ``dx`` beside its start, the
        RECON-bot at ``rover``: body point, ground normal, the team's true pose, the world's
        Cliff-bot."""
        t = self.world.team
        assert t is not None
        x = float(t.cliffbot_start_xy[0]) + dx
        ys = np.linspace(t.edge_y_m + 0.5, t.edge_y_m - t.drop_m / math.tan(math.radians(t.face_slope_deg)) - 2.0, 800)
        zs = self.world.ground_at(np.full_like(ys, x), ys)
        y = float(ys[int(np.argmax(zs <= -depth_frac * t.drop_m))])
        zg = float(self.world.ground_at(x, y))
        n = surface_normal(self.z_grid, self.grid, np.array([x, y]), 0.3)
        n = np.array([0.0, -0.5, 0.87]) if n is None else n
        yaw = -math.pi / 2
        cb = self.world.cliffbot
        body = build_cliffbot(x, y, zg, yaw, size_m=(cb.length_m, cb.width_m, cb.height_m),
                              marker_size_m=cb.markers[0].size_m if cb.markers else 0.18)
        attach = np.array([x, y, zg + self.tcfg.attach_m])
        st = tether_state(self.z_grid, self.grid, self.anchors, np.array([x, y]), self.tcfg, 0.3)
        lines = []
        for k in range(2):
            mid = np.zeros((0, 3)) if st is None else st.paths[k].contacts
            lines.append(np.vstack([self.anchors[k], mid, attach]))
        recon = yaw_box(np.array([rover[0], rover[1], 0.3]), rover[2], RECON_HALF_M)
        anchors = tuple(yaw_box(np.array([a[0], a[1], 0.2]), -math.pi / 2, ANCHOR_HALF_M) for a in t.anchors_xy)
        # the whole robot: the body and its fiducial plates (the inclined one stands above the top)
        corners = np.concatenate([q.corners for q in body.quads]) - body.t
        local = corners @ body.R
        lo, hi = local.min(axis=0), local.max(axis=0)
        box = BodyBox(body.t + body.R @ (0.5 * (lo + hi)), body.R, 0.5 * (hi - lo))
        team = TeamPose(box, recon, (anchors[0], anchors[1]), (lines[0], lines[1]))
        return np.array([x, y, zg]), n, team, body

    def known(self, team: TeamPose, cliff_err: F64) -> TeamGeometry:
        """The team's geometry as the flight side knows it: the Cliff-bot (and the tethers' ends
        at it) off by its navigation error ``cliff_err``; the RECON-bot as placed; the Anchorbots
        as the flight's mask knows them (``anchorbot_box`` on their surveyed ground points, under
        the tethers' exits); the ground under each tether known over the plateau, from its anchor's
        ground to its first contact (the lip; on down the face, the line between contacts spans
        the face's hollows in the air: not known)."""
        sig = CLIFF_SIGMA[1]
        box = BodyBox(team.cliffbot.center + cliff_err, team.cliffbot.R, team.cliffbot.half, sig)
        exit_m = self.tcfg.anchor_exit_m
        anchors = tuple(anchorbot_box(a - np.array([0.0, 0.0, exit_m]), SURVEY_SIGMA_M) for a in self.anchors)
        lines = []
        for line in team.tethers:
            s = np.linspace(0.0, 1.0, len(line))[:, None]
            ground = np.full(len(line), np.nan)  # over the plateau: from the anchor to its first contact
            ground[0] = line[0, 2] - exit_m
            ground[1] = line[1, 2] if len(line) > 2 else np.nan
            lines.append(TetherLine(line + s * cliff_err, TETHER_RADIUS_M, sig, ground))
        return TeamGeometry((box, team.recon, *anchors), tuple(lines))

    # -- views ------------------------------------------------------------------------------
    def _view(self, agent: str, pose: CameraPose, cov: F64, team: TeamPose, body: Any, known: TeamGeometry) -> None:
        from hil_sim.render import StereoRenderer

        cfg = self.settings[agent]
        w = dataclasses.replace(self.world, cliffbot=body)
        rend = StereoRenderer(w, cfg.camera, self.world.noise_sigma, seed=int(self.rng.integers(1 << 30)))
        left, right, quad, terrain = rend.render_labelled(pose, team_quads(team, pose.t))
        self.true_rays.append((pose.t.copy(), true_points(pose, cfg.camera.K, terrain, quad)))
        est = perturbed(pose, cov, self.rng)
        pipe = SensingPipeline(cfg, None, emap=self.gravity)
        pipe.team = known if self.mask else None
        if agent == "recon":
            pipe.team_mask_cfg = SITE_MASK  # the RECON-bot's flight mask (fsw.tasks.perception)
        dm = run_to_end(pipe.matcher.match_steps(left, right))
        pts = run_to_end(pipe.matcher.triangulate_steps(dm.disparity_px, sigma_px=dm.sigma_px))
        placed = RegisteredPose(Registration("off", "bench pose"), est, cov, None)
        on_team = team_points(pts, quad, terrain)
        self.team_points += int(on_team.sum())
        if on_team.any():  # the same pipeline stage on the team's points alone: what survives the mask
            sub = dataclasses.replace(pts, xyz_c=pts.xyz_c[on_team], cov_c=pts.cov_c[on_team],
                                      uv=pts.uv[on_team], disparity_px=pts.disparity_px[on_team])
            for xyz, _, _ in run_to_end(pipe.world_parts_steps(placed, sub)):
                self.team_points_fused += len(xyz)
                iy, ix, inside = self.grid.cell_index(xyz[:, 0], xyz[:, 1])
                self.team_cells |= set(zip(iy[inside].tolist(), ix[inside].tolist(), strict=True))
        parts = run_to_end(pipe.world_parts_steps(placed, pts))
        self.views += 1
        merge_as(self.gravity, parts, cfg.fusion, est.t)
        if self.face is None:
            self.pending.append((agent, parts, est.t, pipe.matcher.window_rad))
            return
        self._fuse(agent, parts, est.t, pipe.matcher.window_rad)

    def _try_fit(self) -> None:
        base = FaceMapConfig()
        if self.resolve_cells is not None:
            base = dataclasses.replace(base, resolve_cells=self.resolve_cells)
        try:
            self.face = fit_face_map(self.gravity, self.cfg.fusion, base)
        except ValueError:
            return
        self.fit_views = self.views
        for a in ("recon", "cliffbot"):
            self.by_agent[a] = self.face.empty_like()
        for agent, parts, eye, window in self.pending:
            self._fuse(agent, parts, eye, window)
        self.pending = []

    def _fuse(self, agent: str, parts: list[ViewPart], eye: F64, window_rad: float) -> None:
        """One view into the face map and its gravity grid (the hand-over), and into the agent's
        own face map; ``eye``: the camera centre as estimated (the rays' free space, the
        incidence limit); ``window_rad``: its stereo matching window's angle (the limit)."""
        assert self.face is not None
        to_face, to_grav = split_parts(parts, self.face)
        before = int(self.face.map.mapped.sum() + self.split_gravity.mapped.sum())
        settings = self.settings[agent]
        reach = settings.camera.max_range_m
        self.face.merge_parts(to_face, eye=eye, rays=parts, window_rad=window_rad, max_range_m=reach)
        merge_as(self.split_gravity, to_grav, settings.fusion, eye)
        self.by_agent[agent].merge_parts(to_face, eye=eye, rays=parts, window_rad=window_rad, max_range_m=reach)
        self.cells_by_agent[agent] += int(self.face.map.mapped.sum() + self.split_gravity.mapped.sum()) - before

    def recon_poses(self, n: int) -> list[tuple[tuple[float, float, float], CameraPose]]:
        """Mast poses from the plateau: the rover ``0.7 m`` behind the edge, beside the face
        (alternately left and right of the Cliff-bot's fall line, heading along the edge), its
        camera aimed at a point of the face drawn from the seed (the mast's limits apply)."""
        t = self.world.team
        assert t is not None
        cx = float(t.cliffbot_start_xy[0])
        run = t.drop_m / math.tan(math.radians(t.face_slope_deg))
        out = []
        for k in range(n):
            side = -1.0 if k % 2 == 0 else 1.0
            x = cx + side * float(self.rng.uniform(1.5, 3.0))
            rover = (x, t.edge_y_m + 0.7, 0.0 if side < 0 else math.pi)
            depth = float(self.rng.uniform(0.2, 0.8))
            aim = np.array([cx + float(self.rng.uniform(-1.0, 1.0)), t.edge_y_m - depth * run, -depth * t.drop_m])
            joints, _reachable = point_mast(rover, aim, self.cfg.mast, 0.3)
            out.append((rover, camera_pose_from_rover(rover, joints, self.cfg.mast)))
        return out

    def measure(self, n_recon: int, n_cliff: int) -> dict[str, Any]:
        t = self.world.team
        assert t is not None
        rover = (0.0, 0.0, 0.0)
        for rover, pose in self.recon_poses(n_recon):
            team0 = self.cliffbot_at(0.45, 0.0, rover)
            err = self.rng.normal(0.0, CLIFF_SIGMA[1], 3)  # the Cliff-bot's fix error, as the RECON-bot knows it
            self._view("recon", pose, pose_cov(RECON_SIGMA), team0[2], team0[3], self.known(team0[2], err))
        self._try_fit()  # the face frame from the RECON-bot's survey, else from the first views on the face
        a = math.radians(t.face_slope_deg)
        for k in range(n_cliff):
            body_pt, n, team, body = self.cliffbot_at(float(self.rng.uniform(0.3, 0.7)),
                                                      float(self.rng.uniform(-0.6, 0.6)), rover)
            up = k % 2 == 0  # up the face first: the tethers and the anchors are in view
            yaw = math.pi / 2 if up else -math.pi / 2
            tilt = (a - math.radians(25.0)) if up else (-a - math.radians(20.0))
            tilt = max(-1.5, min(1.5, tilt))
            pan = float(self.rng.uniform(-0.5, 0.5))
            pose = cliffbot_camera_pose(body_pt, n, yaw, pan, tilt, 0.35 if up else -0.35)
            cov = pose_cov(CLIFF_SIGMA)
            est_body = self.rng.normal(0.0, CLIFF_SIGMA[1], 3)
            self._view("cliffbot", pose, cov, team, body, self.known(team, est_body))
            if self.face is None:
                self._try_fit()
        return self.figures()

    def figures(self) -> dict[str, Any]:
        t = self.world.team
        assert t is not None
        row: dict[str, Any] = {"seed": self.seed, "slope_deg": round(float(t.face_slope_deg), 1), "views": self.views,
                               "fit_views": self.fit_views}
        if self.face is None:  # no face fitted: only the team mask's figures
            nones = ("frame_off_deg", "frame_off_true_deg", "face_cells", "face_rmse_m", "face_rmse_gravity_m", "ratio",
                     "face_rmse_gravity_normal_m",
                     "ratio_normal", "rmse_recon_m", "rmse_cliff_m",
                     "rmse_fused_m", "in2s_recon", "in2s_cliff", "in2s_fused")
            zeros = {f"{k}_{a}{t}": 0 for k in ("cells", "within2s", "out2s") for a in ("recon", "cliff", "fused")
                     for t in ("", "_step")}
            return {**row, **{k: None for k in nones}, **zeros, "overhang_truth": 0, "overhang_flagged": 0,
                    "overhang_false": 0, "overhang_false_part": 0, "overhang_seen": 0, "overhang_seen_flagged": 0,
                    "overhang_shown": 0,
                    "overhang_shown_flagged": 0, "overhang_open": 0,
                    "overhang_open_flagged": 0, "both_cells": 0,
                    "team_points_seen": self.team_points,
                    "team_points_fused": self.team_points_fused, "team_cells_mapped": len(self.team_cells)}
        off = frame_off_deg(self.world, self.face)
        row["frame_off_deg"] = None if off is None else round(off, 1)
        off = frame_off_true_deg(self.world, self.face)
        row["frame_off_true_deg"] = None if off is None else round(off, 1)
        f = face_figures(self.world, self.face, self.gravity, self.cells_by_agent, self.true_rays)
        row.update({k: f[k] for k in ("face_cells", "face_rmse_m", "face_rmse_gravity_m", "face_rmse_gravity_normal_m",
                                       "overhang_truth", "overhang_flagged", "overhang_false",
                                       "overhang_false_part", "overhang_seen",
                                       "overhang_seen_flagged", "overhang_shown", "overhang_shown_flagged",
                                       "overhang_open", "overhang_open_flagged")})
        r, g, gn = f["face_rmse_m"], f["face_rmse_gravity_m"], f["face_rmse_gravity_normal_m"]
        row["ratio"] = r / g if r is not None and g else None
        row["ratio_normal"] = r / gn if r is not None and gn else None
        row.update(self._agents())
        row["team_points_seen"] = self.team_points
        row["team_points_fused"] = self.team_points_fused
        row["team_cells_mapped"] = len(self.team_cells)
        return row

    def _agents(self) -> dict[str, Any]:
        """RMS and 2-sigma rates on cells both agents mapped (single surface in the truth)."""
        assert self.face is not None
        fr, fc = self.by_agent["recon"], self.by_agent["cliffbot"]
        both = np.flatnonzero((fr.map.mapped & fc.map.mapped & self.face.map.mapped).reshape(-1))
        out: dict[str, Any] = {"both_cells": 0}
        w_true, over = truth_along_normal(self.world, self.face, both)
        ok = ~over & np.isfinite(w_true)
        out["both_cells"] = int(ok.sum())
        for name, fm in (("recon", fr), ("cliff", fc), ("fused", self.face)):
            e = fm.map.z.reshape(-1)[both][ok] - w_true[ok]
            s = np.sqrt(fm.map.var.reshape(-1)[both][ok])
            out[f"rmse_{name}_m"] = float(np.sqrt(np.mean(e * e))) if e.size else None
            out[f"in2s_{name}"] = float(np.mean(np.abs(e) <= 2 * s)) if e.size else None
        # every cell each map holds (single surface in the truth): cells and how many within 2 sigma;
        # of them, those beside a step: the true surface rises out of the face by the overhang gap
        # or more within 2 cells (what a grazing view sees in front of the cell)
        rise = relief_rise(self.world, self.face)
        gap = self.face.cfg.overhang_gap_m
        for name, fm in (("recon", fr), ("cliff", fc), ("fused", self.face)):
            cells = np.flatnonzero(fm.map.mapped.reshape(-1))
            w_true, over = truth_along_normal(self.world, self.face, cells)
            ok = ~over & np.isfinite(w_true)
            e = fm.map.z.reshape(-1)[cells][ok] - w_true[ok]
            s = np.sqrt(fm.map.var.reshape(-1)[cells][ok])
            step = rise[cells][ok] >= gap
            out[f"cells_{name}"] = int(ok.sum())
            out[f"within2s_{name}"] = int(np.sum(np.abs(e) <= 2 * s))
            out[f"cells_{name}_step"] = int(step.sum())
            out[f"within2s_{name}_step"] = int(np.sum(step & (np.abs(e) <= 2 * s)))
            out[f"out2s_{name}_step"] = int(np.sum(step & (e > 2 * s)))
            out[f"out2s_{name}"] = int(np.sum(e > 2 * s))
        return out
