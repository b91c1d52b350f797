"""Methods 3, 4, 5 and the oracle of docs/algorithm.md §7: information-based view selection.

Every reachable station along the edge path (``view_candidates.path_stations``) is rated by
its expected information (§3-§4, ``fsw.core.planning.nbv``); Method 3 straightens the path, Method 5
weighs P_V by the interest function, the oracle rates with the true terrain and texture.
"""

from __future__ import annotations

from collections.abc import Generator
from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from fsw.core.geometry import CameraConfig, CameraPose, MastConfig, camera_pose_from_rover
from fsw.core.planning.coarse_rating import (
    coarse_factor,
    coarse_visibility,
    fine_factor,
    prepare,
    rate_station_coarse_steps,
    rate_views_pooled_steps,
    rate_views_steps,
)
from fsw.core.planning.nbv import (
    AccuracyModel,
    MapLike,
    NbvConfig,
    focus_weights,
    info_n_max,
    localization_sigma,
    motion_cost,
    rate_station_steps,
    utility,
)
from fsw.core.planning.planners import Planner, PlannerState, SearchGen
from fsw.core.planning.view_candidates import (
    CandidateView,
    Station,
    as_polyline,
    joint_grid,
    path_stations_steps,
)
from fsw.core.planning.visibility import F64, Terrain, in_view, terrain_from_heights, terrain_from_map_steps
from fsw.core.steps import run_to_end

# a camera centre as team views rate it: (camera xyz, world yaws (P,), tilts (T,), Eq 9 cost and
# sigma_loc per view pan-major (P * T,), the place (x, y, yaw, lift))
CentreRow = tuple[tuple[float, float, float], F64, F64, F64, F64, tuple[float, ...]]


class InformationPlanner(Planner):
    """Methods 3, 4, 5 and the oracle: the reachable candidate of highest utility (§3.5)."""

    def __init__(self, name: str, cfg: NbvConfig, camera: CameraConfig, mast: MastConfig, *,
                 use_interest: bool = False, straight_edge: bool = False,
                 truth_z_m: F64 | None = None, textured: NDArray[np.bool_] | None = None) -> None:
        self.name, self.cfg, self.camera, self.mast = name, cfg, camera, mast
        self.use_interest, self.straight_edge = use_interest, straight_edge
        self._truth_z = truth_z_m
        self._textured = None if textured is None else np.asarray(textured, bool).astype(float)
        self._truth_terrain: Terrain | None = None
        self.last_stations = 0  # stations rated by the last search
        self.last_centres = 0  # camera centres (stations x lifts) rated by the last search
        self._focus: F64 | None = None  # the task's weights of the interest (cfg.focus_regions)
        # Method 5 weighs bits by the map accuracy a view gives (§3.2 choice; off when 0)
        self.accuracy = AccuracyModel.of(cfg, camera) if use_interest else None

    def _terrain(self, emap: MapLike) -> Generator[None, None, tuple[Terrain, F64 | None, F64 | None]]:
        """The terrain rated on, the interest (a probability term) and the task's weights of the
        bits (the focus regions; None: all 1), ``nbv.cell_values``."""
        if self._truth_z is None:
            terrain = yield from terrain_from_map_steps(emap.z, emap.var, emap.grid,
                                                        self.cfg.visibility)
            if not self.use_interest:
                return terrain, None, None
            if not self.cfg.focus_regions:
                return terrain, emap.interest, None
            if self._focus is None or self._focus.shape != emap.interest.shape:
                self._focus = focus_weights(emap.grid, self.cfg.focus_regions)
            return terrain, emap.interest, self._focus
        if self._truth_terrain is None:
            z = np.asarray(self._truth_z, dtype=np.float64)
            z = np.where(np.isfinite(z), z, np.nanmin(z) if np.isfinite(z).any() else 0.0)
            self._truth_terrain = terrain_from_heights(z, emap.grid, self.cfg.oracle_sigma_m)
        return self._truth_terrain, self._textured, None

    def search(self, state: PlannerState) -> SearchGen:
        """Rate every reachable camera centre (§3.5), coarse to fine (``coarse_rating``): every
        pan/tilt of every centre on the coarse terrain, then the best ``refine_views`` of them
        exactly; the best exact utility wins. With ``coarse_cell_m`` = 0 (or a coarse cell no
        larger than the map's) every centre is rated exactly, view by view, as before."""
        cfg = self.cfg
        terrain, interest, weight = yield from self._terrain(state.map)
        yield None
        path = straighten(state.path) if self.straight_edge else state.path
        stations = yield from path_stations_steps(path, state.rover, state.motion_ok,
                                                  cfg.station_spacing_m, cfg.max_travel_m)
        self.last_stations = len(stations)
        self.last_centres = 0
        leave = boxed_start(state, cfg)
        pans, tilts, lifts = joint_grid(self.mast, cfg.pan_step_deg, cfg.tilts_deg, cfg.lifts_m)
        n_max = info_n_max(state.map, cfg)
        centres = []
        for st in stations:  # motion and localization terms: a step per station (landmarks)
            for lift in lifts:
                centres.append(_Centre(st, float(lift), self._cam(st, float(lift), state), pans,
                                       tilts, state, self))
            yield None
        factor = coarse_factor(terrain.grid.cell, cfg.coarse_cell_m)
        best = _Best()
        if factor <= 1:
            for c in centres:
                r = yield from rate_station_steps(terrain, c.cam_xyz, c.yaws, tilts, state.map.n,
                                                  n_max, interest, self.camera, cfg.visibility,
                                                  accuracy=self.accuracy, weight=weight)
                best.offer(c, c.best(r.info_bits.ravel(), r.expected_new_cells.ravel(), None))
                self.last_centres += 1
            return best.choice(stations, path, leave, cfg.leave_start_tol)
        cs = prepare(terrain, factor, state.map.n, n_max, interest, self.accuracy, weight)
        vis_coarse = coarse_visibility(cfg.visibility, factor)
        yield None
        u_all = []
        for c in centres:
            r = yield from rate_station_coarse_steps(cs, c.cam_xyz, c.yaws, tilts, self.camera,
                                                     vis_coarse)
            u_all.append(utility(r.info_bits.ravel(), c.d, c.sig, cfg))
        u_flat = np.concatenate(u_all)
        top = np.argsort(-u_flat, kind="stable")[:cfg.refine_views]
        per = pans.size * tilts.size
        # a boxed-in rover's escape moves (view_candidates) each get their best view refined too
        escapes = [i * per + int(np.argmax(u_all[i])) for i, c in enumerate(centres) if c.st.escape]
        moves = [i for i, c in enumerate(centres) if c.st.travel_m > 0.0]
        if leave and moves:  # a boxed-in start: the best move's best view is rated exactly too
            j = max(moves, key=lambda i: float(u_all[i].max()))
            escapes.append(j * per + int(np.argmax(u_all[j])))
        top = np.concatenate([top, np.array(escapes, dtype=top.dtype)])
        # the refining pass resolves P_V down to fine_cell_m: a finer map is pooled to it there
        f_fine = fine_factor(terrain.grid.cell, cfg.fine_cell_m)
        fs = None if f_fine <= 1 else prepare(terrain, f_fine, state.map.n, n_max, interest,
                                              self.accuracy, weight)
        for i in sorted(set((top // per).tolist())):
            c = centres[i]
            views = np.unique(top[top // per == i] % per)
            if fs is not None:
                r2 = yield from rate_views_pooled_steps(fs, c.cam_xyz, c.yaws[views // tilts.size],
                                                        tilts[views % tilts.size], self.camera,
                                                        coarse_visibility(cfg.visibility, f_fine))
            else:
                r2 = yield from rate_views_steps(terrain, c.cam_xyz, c.yaws[views // tilts.size],
                                                 tilts[views % tilts.size], state.map.n, n_max,
                                                 interest, self.camera, cfg.visibility,
                                                 accuracy=self.accuracy, weight=weight)
            best.offer(c, c.best(r2.info_bits, r2.expected_new_cells, views))
            self.last_centres += 1
        return best.choice(stations, path, leave, cfg.leave_start_tol)

    def view_centres(self, state: PlannerState, stations: list[Station] | None = None) -> list[CentreRow]:
        """Every candidate camera centre as team views rate it (``team_views.recon_centres``):
        (camera xyz, world yaws, tilts, Eq 9 cost and sigma_loc per view pan-major, (x, y, yaw,
        lift)); ``stations``: these instead of the reachable ones along the edge path."""
        cfg = self.cfg
        if stations is None:
            stations = run_to_end(path_stations_steps(state.path, state.rover, state.motion_ok,
                                                      cfg.station_spacing_m, cfg.max_travel_m))
        pans, tilts, lifts = joint_grid(self.mast, cfg.pan_step_deg, cfg.tilts_deg, cfg.lifts_m)
        out: list[CentreRow] = []
        for st in stations:
            for lift in lifts:
                c = _Centre(st, float(lift), self._cam(st, float(lift), state), pans, tilts, state, self)
                out.append((c.cam_xyz, c.yaws, tilts, c.d, c.sig, (*st.rover, float(lift))))
        return out

    def _cam(self, st: Station, lift: float, state: PlannerState) -> tuple[float, float, float]:
        cam = camera_pose_from_rover(st.rover, (0.0, 0.0, lift), self.mast, state.ground_z_m).t
        return (float(cam[0]), float(cam[1]), float(cam[2]))


def boxed_start(state: PlannerState, cfg: NbvConfig) -> bool:
    """A start boxed in by a close edge (docs/algorithm.md §3): the rover has not left its start
    and the fitted edge passes within ``leave_start_edge_m`` of its centre."""
    if not state.at_start or cfg.leave_start_edge_m <= 0.0 or state.edge_xy is None:
        return False
    e = np.asarray(state.edge_xy, dtype=np.float64).reshape(-1, 2)
    e = e[np.isfinite(e).all(axis=1)]
    if e.shape[0] == 0:
        return False
    d = float(np.hypot(e[:, 0] - state.rover[0], e[:, 1] - state.rover[1]).min())
    return d <= cfg.leave_start_edge_m


class _Best:
    """The best candidate of a search, the best escape move of a rover boxed in by a close edge
    (``view_candidates``: no station along the edge path reachable) and the best move (a station
    some travel away). A boxed-in rover takes its best escape move whatever the rating of the
    views from where it stands: those cannot lead on along the edge, and a view from the same
    place again maps little (issue 30 item 1). A boxed-in start (:func:`boxed_start`) is left
    for the best move unless the best view from the start rates more than ``tol`` above it
    (docs/algorithm.md §3)."""

    def __init__(self) -> None:
        self.any: CandidateView | None = None
        self.escape: CandidateView | None = None
        self.move: CandidateView | None = None

    def offer(self, c: _Centre, cand: CandidateView) -> None:
        if self.any is None or cand.utility > self.any.utility:
            self.any = cand
        if c.st.escape and (self.escape is None or cand.utility > self.escape.utility):
            self.escape = cand
        if c.st.travel_m > 0.0 and (self.move is None or cand.utility > self.move.utility):
            self.move = cand

    def choice(self, stations: list[Station], path: F64, leave: bool = False,
               tol: float = 0.0) -> CandidateView | None:
        if self.escape is not None:
            return self.escape
        if self.any is not None and len(stations) == 1 and as_polyline(path).shape[0] >= 2:
            return replace(self.any, note=STUCK_NOTE)
        if leave and self.any is not None and self.move is not None and self.any is not self.move:
            return leave_or_stay(self.any, self.move, tol)
        return self.any


def leave_or_stay(stay: CandidateView, move: CandidateView, tol: float) -> CandidateView:
    """At a boxed-in start whose best view is from where it stands (``stay``): the best move,
    unless ``stay`` rates more than ``tol`` of its utility above it; then ``stay``, with the
    reason for the mission summary."""
    if move.utility >= stay.utility - tol * abs(stay.utility):
        return move
    return replace(stay, note=f"boxed-in start: the best view from the start rates {stay.utility:.0f}, more "
                              f"than {tol:.0%} above the best reachable station's ({move.utility:.0f})")


STUCK_NOTE = ("no move the geofence allows: every station along the edge path, straight back or ahead, "
              "and a turn in place to the path's heading is refused (the edge is too close)")


class _Centre:
    """One camera centre of a search: its pan/tilt poses' motion cost and localization sigma
    (§3.3, §3.5), which do not depend on the rating."""

    def __init__(self, st: Station, lift: float, cam_xyz: tuple[float, float, float], pans: F64,
                 tilts: F64, state: PlannerState, planner: InformationPlanner) -> None:
        cfg = planner.cfg
        self.st, self.lift, self.cam_xyz, self.name, self.cfg = st, lift, cam_xyz, planner.name, cfg
        self.yaws = st.rover[2] + pans
        pp, tt = np.meshgrid(pans, tilts, indexing="ij")
        self.pans, self.tilts = pp.ravel(), tt.ravel()
        poses = np.column_stack([np.tile(st.rover, (pp.size, 1)), self.pans, self.tilts,
                                 np.full(pp.size, lift)])
        current = np.array([*state.rover, *state.joints], dtype=np.float64)
        self.d = motion_cost(poses, current, cfg)
        rng = landmark_range(cam_xyz, self.yaws, tilts, state.landmarks_xyz, planner.camera)
        self.sig = localization_sigma(np.full(pp.size, st.travel_m), state.sigma_loc_m,
                                      rng.ravel(), cfg)

    def best(self, info_bits: F64, new_cells: F64, views: NDArray[np.intp] | None
             ) -> CandidateView:
        """The view of highest utility among ``views`` (flat pan-major indices; None: all),
        given their H and expected new cells."""
        k_all = np.arange(self.d.size) if views is None else views
        u = utility(info_bits, self.d[k_all], self.sig[k_all], self.cfg)
        j = int(np.argmax(u))
        k = int(k_all[j])
        return CandidateView(self.st.rover, (float(self.pans[k]), float(self.tilts[k]), self.lift),
                             float(info_bits[j]), float(new_cells[j]), float(self.d[k]),
                             float(self.sig[k]), float(u[j]), self.name)


def landmark_range(cam_xyz: tuple[float, float, float], yaws: F64, tilts: F64,
                   landmarks_xyz: F64, camera: CameraConfig) -> F64:
    """(P, T) range to the nearest landmark inside each view (inf if none)."""
    out = np.full((yaws.size, tilts.size), np.inf)
    lm = np.asarray(landmarks_xyz, dtype=np.float64).reshape(-1, 3)
    if lm.shape[0] == 0:
        return out
    for p, yaw in enumerate(yaws):
        for t, tilt in enumerate(tilts):
            pose = CameraPose.from_pan_tilt(*cam_xyz, float(yaw), float(tilt))
            vis = in_view(pose, camera, lm)
            if vis.any():
                out[p, t] = float(np.linalg.norm(lm[vis] - pose.t, axis=1).min())
    return out


def straighten(path: F64) -> F64:
    """Method 3's path: one straight segment (total least squares) spanning the path points."""
    xy = as_polyline(path)
    if xy.shape[0] < 2:
        return xy
    c = xy.mean(axis=0)
    _, _, vt = np.linalg.svd(xy - c, full_matrices=False)
    d = vt[0] if np.dot(vt[0], xy[-1] - xy[0]) >= 0 else -vt[0]
    s = (xy - c) @ d
    return np.vstack([c + s.min() * d, c + s.max() * d])
