"""Views chosen for the team: next-view selection over both agents (docs/algorithm.md §3, §8).

Each agent offers candidate camera centres, each with a grid of pointing directions (world yaw x
tilt) and, per direction, its own motion cost and localization term (§3.3, §3.5):

* the RECON-bot's: its stations along the edge path with the mast's pan/tilt/lift grid, Eq 9 over
  wheels and mast (:func:`recon_centres`, from the information planner's own candidates);
* the Cliff-bot's: places on its planned paths (either way, within ``max_travel_m`` of where it
  stands, :func:`corridor_places`) and across its corridor (:func:`corridor_lattice`, on known
  ground where the tethers hold it), its head camera ``head_m`` along the ground's
  normal, every head pan and tilt; its motion is tether motion: the change of both paid-out
  lengths (winches, ``a_tether``; every place's tethers in one batch, ``tether_states``) plus the
  head's turn (:func:`cliffbot_centres`).

Every view is rated on the ONE shared map with §3.2-§3.5 (``nbv.rate_station``: expected
information with the interest function, minus motion and localization costs). An agent with a
face (``AgentViews.face``, ``face_rating.face_cells``) is rated on the face's own cells where
they lie (§8.2, "A model that sees the face": the gravity grid's prior puts the ground below a
lip at the lip's height) and on the gravity grid elsewhere, with a floor prior in front of the
face. The bits of the Cliff-bot's planned corridor (its path +- ``corridor_half_m``) are weighted
by ``corridor_weight`` (:func:`corridor_weights`, a task's focus region of §3.4: what the
receiver's task needs), so the RECON-bot favours what the Cliff-bot will drive on. The weight is
a factor on the bits, apart from the interest, which stays the probability term of
``h2(IF P_V / 2)`` (``nbv.cell_values``).

**Interest per agent** (:class:`AgentInterest`, §8.2): the interest function decays with the
misses of the agent that looked, and each agent is rated with its own. A miss says the agent's
P_V was wrong for that cell (its prior cannot see it), which says nothing of the other agent's
view from elsewhere (the Cliff-bot on the face sees what the RECON-bot's prior misses).

**Sequential greedy** (:func:`choose_team_views`): every agent not yet served is rated, the one
whose best view has the highest utility takes it (an agent with ``AgentViews.views`` above one is
served that many times, the views after its first from the same centre: the Cliff-bot's head
scan, ``TeamViewConfig.cliffbot_views``), and ``planned``, the probability that some
chosen view sees each cell, takes in that view's P_V; the next agent's views are rated by what
they add to the cycle's one measurement of each cell (``nbv.cell_values``: the marginal gain of a
submodular function of the cycle's views); repeat until every agent has its views. So the second
agent does not pay for, nor aim at, what the first is about to map. Each choice says who looked where
and why (:class:`TeamView`, ``why`` and :meth:`TeamView.event`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage

from fsw.core.geometry import CameraConfig, CameraPose, MapGrid
from fsw.core.planning.face_rating import (
    FaceCells,
    face_visibility,
    gravity_with_floor,
    rate_face_station,
    terrain_visibility,
)
from fsw.core.planning.info_planners import CentreRow
from fsw.core.planning.nbv import (
    MapLike,
    NbvConfig,
    focus_weights,
    info_n_max,
    predicted_visibility,
    rate_station,
    utility,
)
from fsw.core.planning.visibility import F64, Terrain, terrain_from_map
from fsw.core.team.standing_plane import surface_normal
from fsw.core.team.tether import TetherConfig, ZMap, tether_states
from fsw.framework.params import param


@dataclass(frozen=True)
class TeamViewConfig:
    """Team views (docs/algorithm.md §8): the corridor the RECON-bot favours, the Cliff-bot's
    view grid and what its motion costs."""

    corridor_half_m: float = param(1.0, lo=0.0, hi=20.0, units="m",
                                   doc="the Cliff-bot's corridor: its planned path +- this")
    corridor_weight: float = param(2.0, lo=1.0, hi=100.0,
                                   doc="both agents' weight of the bits on the Cliff-bot's corridor (§3.4)")
    head_m: float = param(0.45, lo=0.0, hi=3.0, units="m", doc="the Cliff-bot's camera above its ground")
    station_spacing_m: float = param(0.5, lo=0.05, hi=10.0, units="m",
                                     doc="the Cliff-bot's candidate places along its path")
    max_travel_m: float = param(3.0, lo=0.0, hi=100.0, units="m",
                                doc="farthest Cliff-bot place per cycle (along its path)")
    pan_step_deg: float = param(30.0, lo=5.0, hi=180.0, units="deg", doc="the Cliff-bot's head pan grid")
    tilts_deg: tuple[float, ...] = param((-75.0, -50.0, -25.0, 0.0, 25.0, 50.0), units="deg",
                                         doc="the Cliff-bot's head tilts (elevation of the axis)")
    a_tether: float = param(69.4, lo=0.0, hi=1e6, units="s^2/m^2",
                            doc="Eq 9 weight of the larger change of the paid-out lengths (1 / winch rate^2: "
                                "the mission's 0.12 m/s, [cliffbot_mission] max_rate_mps)")
    a_head: float = param(3.65, lo=0.0, hi=1e6, units="s^2/rad^2", doc="Eq 9 weight of the head's pan and tilt")
    face_prior_m: float = param(2.0, lo=0.0, hi=50.0, units="m",
                                doc="the face rating's plane continued this far down the dip past the face map")
    cliffbot_views: int = param(16, lo=1, hi=64,
                                doc="the Cliff-bot's views per imaging cycle, all from the place of its first: its "
                                    "head's scan (its flight takes a 16-view look in less time than the RECON-bot's "
                                    "median imaging step: docs/team.md, Team views)")


@dataclass(frozen=True)
class ViewCentre:
    """One camera centre of an agent and its pointing grid: ``yaws`` (P,) x ``tilts`` (T,), with
    each view's motion cost and localization sigma flat in pan-major order (P * T,)."""

    xyz: tuple[float, float, float]
    yaws: F64
    tilts: F64
    motion: F64
    sigma_loc_m: F64
    place: tuple[float, ...]  # RECON-bot (x, y, yaw, lift); Cliff-bot (x, y, l1, l2)


@dataclass(frozen=True)
class AgentViews:
    """An agent's candidates for one cycle. ``interest``: its weights of each cell's interest
    (None: the map's own)."""

    agent: str
    camera: CameraConfig
    centres: tuple[ViewCentre, ...]
    interest: F64 | None = None
    # the task's weight of each cell's bits (the corridor, focus regions; ``corridor_weights``); None: 1
    weight: F64 | None = None
    # (world yaw, tilt) to look along when no view is expected to map anything (the map's prior
    # cannot predict the ground: a face below unknown ground); None: the best utility regardless
    fallback: tuple[float, float] | None = None
    # the face as the rating sees it (``face_rating.face_cells``): its cells are rated on the face
    # grid, the gravity cells they stand for left out of the gravity rating; None: gravity grid only
    face: FaceCells | None = None
    # the views it takes in the cycle: the first from any of its centres, the rest from that
    # centre (a head's scan: they pay no motion, each pointing once, rated by utility with no
    # fallback, none once no pointing is expected to map a new cell), each chosen in the
    # sequential greedy
    views: int = 1
    # the rest of a scan (its views after the first): it ends when its best view expects no new cell
    scanning: bool = False


@dataclass(frozen=True)
class TeamView:
    """One agent's choice in a cycle: who looks where and why."""

    agent: str
    order: int  # 0: chose first
    place: tuple[float, ...]
    xyz: tuple[float, float, float]
    yaw: float  # world yaw of the optical axis (rad)
    tilt: float  # its elevation (rad)
    info_bits: float
    expected_new_cells: float
    motion: float
    utility: float
    discounted_cells: float  # expected cells of this view the earlier choices will see (sum P_V * planned)
    corridor_cells: float  # expected new cells inside the Cliff-bot's corridor
    why: str
    # P_V of every map cell as the view was rated (an agent with a face: its face cells' P_V on the
    # gravity cells they cover): the p_visible its measurement's misses are recorded with (§3.4),
    # so a view expected to map cells it cannot see loses their interest like any other view
    p_visible: F64 | None = field(default=None, repr=False, compare=False)

    def pose(self) -> CameraPose:
        return CameraPose.from_pan_tilt(*self.xyz, self.yaw, self.tilt)

    def event(self) -> dict[str, object]:
        """The view as an event's fields (``TEAM_VIEW``)."""
        return {"agent": self.agent, "order": self.order, "xyz": [round(v, 3) for v in self.xyz],
                "yaw_deg": round(math.degrees(self.yaw), 1), "tilt_deg": round(math.degrees(self.tilt), 1),
                "expected_new_cells": round(self.expected_new_cells, 1), "info_bits": round(self.info_bits, 1),
                "why": self.why}


def corridor_mask(grid: MapGrid, path_xy: F64, half_m: float) -> NDArray[np.bool_]:
    """The cells whose centres lie within ``half_m`` of the polyline ``path_xy`` (K, 2): the
    path drawn at a quarter cell, then a Euclidean distance transform."""
    xy = np.asarray(path_xy, float).reshape(-1, 2)
    out = np.zeros(grid.shape, bool)
    if xy.shape[0] == 0:
        return out
    pts = [xy[:1]]
    for a, b in zip(xy[:-1], xy[1:], strict=True):
        k = max(1, int(math.ceil(float(np.linalg.norm(b - a)) / (0.25 * grid.cell))))
        pts.append(a + (b - a) * np.linspace(0.0, 1.0, k + 1)[1:, None])
    p = np.concatenate(pts)
    iy, ix, inside = grid.cell_index(p[:, 0], p[:, 1])
    if not inside.any():
        return out
    line = np.ones(grid.shape, bool)
    line[iy[inside], ix[inside]] = False
    return np.asarray(ndimage.distance_transform_edt(line) * grid.cell <= half_m, bool)


def corridor_weights(corridor: NDArray[np.bool_], cfg: TeamViewConfig, base: F64 | None = None) -> F64:
    """The task's weight of each cell's bits (§3.4, ``nbv.cell_values``): ``base`` (e.g. the task's
    focus weights; None: 1) times ``corridor_weight`` on the Cliff-bot's corridor. A weight, not an
    interest: it leaves the interest's share of P_V as it is."""
    w = np.ones(corridor.shape) if base is None else np.asarray(base, float)
    return np.where(corridor, w * cfg.corridor_weight, w)


@dataclass
class AgentInterest:
    """The interest function IF per agent (§3.4, §8.2; module docstring): starts at 1; a view's
    cells expected visible (P_V > 0) that got no point decay the looking agent's interest by
    ``exp(-beta P_V)`` (the map's rule, ``[map] interest_beta``), and only that agent's."""

    shape: tuple[int, int]
    beta: float = 1.0
    by_agent: dict[str, F64] = field(default_factory=dict)

    def of(self, agent: str) -> F64:
        """The agent's interest of every cell (ones for an agent that has not looked yet)."""
        return self.by_agent.setdefault(agent, np.ones(self.shape))

    def record(self, agent: str, p_visible: F64, hit: NDArray[np.bool_]) -> int:
        """Decay ``agent``'s interest where its view expected cells (``p_visible``) and got no
        point (``hit`` False); the number of cells decayed. A bad ``p_visible`` (shape, NaN,
        outside [0, 1]) is refused with a ValueError and changes nothing."""
        pv = np.asarray(p_visible, float)
        hit = np.asarray(hit, bool)
        if pv.shape != tuple(self.shape) or hit.shape != tuple(self.shape):
            raise ValueError(f"p_visible and hit must have shape {tuple(self.shape)}, got {pv.shape} and {hit.shape}")
        if not np.isfinite(pv).all() or pv.min(initial=0.0) < 0.0 or pv.max(initial=0.0) > 1.0:
            raise ValueError("p_visible must lie in [0, 1]")
        empty = ~hit & (pv > 0.0)
        mine = self.of(agent)
        mine[empty] *= np.exp(-self.beta * pv[empty])
        return int(empty.sum())


def recon_centres(centres: Sequence[CentreRow]) -> tuple[ViewCentre, ...]:
    """The RECON-bot's centres from the information planner's candidates: (camera xyz, world yaws,
    tilts, Eq 9 cost, sigma_loc, (x, y, yaw, lift)) each (``InformationPlanner.centres``)."""
    return tuple(ViewCentre(xyz, np.asarray(y, float), np.asarray(t, float), np.asarray(d, float),
                            np.asarray(s, float), place) for xyz, y, t, d, s, place in centres)


def corridor_places(path_xy: F64, now_xy: F64, spacing_m: float, max_travel_m: float) -> F64:
    """Places every ``spacing_m`` along the polyline ``path_xy`` (K, 2), either way along it, no
    farther than ``max_travel_m`` in a straight line from ``now_xy`` (K', 2); the corridor's
    places where the Cliff-bot may stop to look."""
    xy = np.asarray(path_xy, float).reshape(-1, 2)
    if xy.shape[0] == 0:
        return np.zeros((0, 2))
    seg = np.linalg.norm(np.diff(xy, axis=0), axis=1)
    run = np.concatenate([[0.0], np.cumsum(seg)])
    s = np.arange(0.0, run[-1] + 1e-9, spacing_m)
    pts = np.column_stack([np.interp(s, run, xy[:, 0]), np.interp(s, run, xy[:, 1])])
    pts = pts[np.linalg.norm(pts - np.asarray(now_xy, float), axis=1) <= max_travel_m]
    if len(pts) == 0:
        return pts
    _, first = np.unique(np.round(pts / max(spacing_m / 4.0, 1e-6)).astype(np.int64), axis=0, return_index=True)
    return np.asarray(pts[np.sort(first)], float)  # an out-and-back route passes each place twice


def corridor_lattice(path_xy: F64, now_xy: F64, spacing_m: float, max_travel_m: float, across_m: float) -> F64:
    """Places off the path but inside the corridor: the nodes of a square lattice of ``spacing_m``
    through ``now_xy`` that lie within ``across_m`` of the polyline ``path_xy`` (K, 2), farther
    than half a spacing from it (:func:`corridor_places` has those), and no farther than
    ``max_travel_m`` in a straight line from ``now_xy`` (K', 2)."""
    xy = np.asarray(path_xy, float).reshape(-1, 2)
    now = np.asarray(now_xy, float).reshape(2)
    if xy.shape[0] == 0 or across_m <= 0.5 * spacing_m or spacing_m <= 0.0:
        return np.zeros((0, 2))
    k = np.arange(-math.floor(max_travel_m / spacing_m), math.floor(max_travel_m / spacing_m) + 1) * spacing_m
    pts = now + np.stack(np.meshgrid(k, k, indexing="ij"), axis=-1).reshape(-1, 2)
    pts = pts[np.linalg.norm(pts - now, axis=1) <= max_travel_m + 1e-9]
    a, b = (xy[:-1], xy[1:]) if xy.shape[0] > 1 else (xy, xy)
    ab = b - a
    t = np.clip(np.einsum("pkd,kd->pk", pts[:, None, :] - a[None], ab) / np.maximum((ab**2).sum(axis=1), 1e-12),
                0.0, 1.0)
    d = np.linalg.norm(pts[:, None, :] - (a[None] + t[..., None] * ab[None]), axis=-1).min(axis=1)
    return np.asarray(pts[(d <= across_m) & (d > 0.5 * spacing_m)], float)


def cliffbot_centres(z: ZMap, grid: MapGrid, anchors: F64, path_xy: F64, now_xy: F64,
                     now_head: tuple[float, float], tcfg: TetherConfig, cfg: TeamViewConfig,
                     sigma_loc_m: float = 0.02, stay: bool = True, both_ways: bool = False,
                     known: NDArray[np.bool_] | None = None, free_slope_deg: float = 25.0
                     ) -> tuple[ViewCentre, ...]:
    """The Cliff-bot's candidate centres: where it stands (unless ``stay`` is False: its task moves
    it on) and places every ``station_spacing_m`` along its planned path ``path_xy`` up to
    ``max_travel_m`` ahead of where it stands (``both_ways``: anywhere on the path within
    ``max_travel_m`` of it, :func:`corridor_places`, and anywhere in its corridor, the path
    +- ``corridor_half_m``, on a lattice of the same spacing, :func:`corridor_lattice`), each known
    on the map (``z``; NaN unknown). A place off the path is kept only on ground the map knows
    (``known``, the shared map's mapped cells; None: ``z`` finite) where the tethers hold the
    Cliff-bot (their statics hold, or the ground is no steeper than ``free_slope_deg``: it stands).
    Motion (Eq 9 over the winches and the head): ``sqrt(a_tether max(|dl1|, |dl2|)^2 + a_head
    (dpan^2 + dtilt^2))`` (both winches run at once, paced to arrive together) from the tether
    lengths where it stands (all places' tethers in one batch, ``tether_states``)."""
    now = np.asarray(now_xy, float).reshape(2)
    xy = np.asarray(path_xy, float).reshape(-1, 2)
    if both_ways:
        ahead = corridor_places(xy, now, cfg.station_spacing_m, cfg.max_travel_m)
        ahead = ahead[np.linalg.norm(ahead - now, axis=1) > 1e-6]
        off = corridor_lattice(xy, now, cfg.station_spacing_m, cfg.max_travel_m, cfg.corridor_half_m)
        off = off[np.linalg.norm(off - now, axis=1) > 1e-6]
        iy, ix, inside = grid.cell_index(off[:, 0], off[:, 1])
        zk = np.isfinite(np.asarray(z, float)) if known is None else np.asarray(known, bool)
        off = off[inside & zk[np.where(inside, iy, 0), np.where(inside, ix, 0)]]
        places = [now, *ahead]
        on_path = len(places)
        places += list(off)
    else:
        places = [now]
        on_path = 0
        if xy.shape[0] >= 1:
            start = int(np.argmin(np.linalg.norm(xy - now, axis=1)))
            run = 0.0
            last = xy[start]
            for p in xy[start + 1:]:
                run += float(np.linalg.norm(p - last))
                last = p
                if run > cfg.max_travel_m:
                    break
                if run >= cfg.station_spacing_m * len(places):
                    places.append(p)
        on_path = len(places)
    states = tether_states(z, grid, anchors, np.array(places), tcfg)
    here = states[0]
    if here is None:
        return ()
    l_now = np.asarray(here.lengths_m)
    pans = np.radians(np.arange(-180.0, 180.0, cfg.pan_step_deg))
    tilts = np.radians(np.asarray(cfg.tilts_deg, float))
    pp, tt = np.meshgrid(pans, tilts, indexing="ij")
    turn = np.sqrt(cfg.a_head * ((np.angle(np.exp(1j * (pp.ravel() - now_head[0])))) ** 2
                                 + (tt.ravel() - now_head[1]) ** 2))
    out = []
    first = 0 if stay or len(places) == 1 else 1
    for k, (p, st) in enumerate(zip(places[first:], states[first:], strict=True), start=first):
        n = surface_normal(z, grid, p, 0.3)
        iy, ix, inside = grid.cell_index(p[:1], p[1:2])
        if st is None or n is None or not inside[0]:
            continue
        if k >= on_path and not (st.statics.ok or st.statics.tilt_deg <= free_slope_deg):
            continue  # off the path, where the tethers would not hold it
        zg = float(np.asarray(z)[iy[0], ix[0]])
        dl = np.asarray(st.lengths_m) - l_now
        # both winches run at once, paced to arrive together (the mission's rates): the move
        # takes the larger change over the rate
        motion = np.sqrt(cfg.a_tether * float(np.max(np.abs(dl))) ** 2 + turn**2)
        cam = np.array([p[0], p[1], zg]) + cfg.head_m * n
        out.append(ViewCentre((float(cam[0]), float(cam[1]), float(cam[2])), pans.copy(), tilts.copy(), motion,
                              np.full(motion.size, sigma_loc_m), (float(p[0]), float(p[1]), *st.lengths_m)))
    return tuple(out)


def choose_team_views(emap: MapLike, agents: Sequence[AgentViews], cfg: NbvConfig,
                      corridor: NDArray[np.bool_] | None = None, terrain: Terrain | None = None
                      ) -> tuple[list[TeamView], F64]:
    """Sequential greedy over the agents (module docstring): the views in the order chosen, and
    ``planned``, the probability that some chosen view sees each cell, ``1 - prod (1 - P_V)``."""
    terrain = terrain if terrain is not None else terrain_from_map(emap.z, emap.var, emap.grid, cfg.visibility)
    n_max = info_n_max(emap, cfg)
    planned = np.zeros(emap.grid.shape)
    left = [a for a in agents if a.centres]
    floors = {a.agent: gravity_with_floor(a.face, emap, cfg.visibility) for a in left if a.face is not None}
    chosen: list[TeamView] = []
    first: TeamView | None = None
    while left:
        # the agents move at once: a cycle lasts as long as its slowest move, so an agent pays
        # only for the motion beyond the longest of the views already chosen
        paid = max((v.motion for v in chosen), default=0.0)
        rated = [_best(emap, terrain if a.face is None else floors[a.agent], a, n_max, cfg, planned if chosen else None,
                       paid) for a in left]
        k = int(np.argmax([r[0] for r in rated]))
        u, a, c, j, bits, new = rated[k]
        if a.scanning and new < 1.0:  # no pointing left is expected to map a new cell: the scan ends
            left.pop(k)
            continue
        blind = a.fallback is not None and new < 1.0
        if blind and a.fallback is not None:
            c = a.centres[0]
            dy = np.angle(np.exp(1j * (np.repeat(c.yaws, c.tilts.size) - a.fallback[0])))
            dt = np.tile(c.tilts, c.yaws.size) - a.fallback[1]
            j = int(np.argmin(dy**2 + dt**2))
            u = float(utility(np.zeros(1), c.motion[j:j + 1], c.sigma_loc_m[j:j + 1], cfg)[0])
        yaw, tilt = float(c.yaws[j // c.tilts.size]), float(c.tilts[j % c.tilts.size])
        pose = CameraPose.from_pan_tilt(*c.xyz, yaw, tilt)
        if a.face is None:
            pv = predicted_visibility(emap, pose, a.camera, cfg.visibility)
        else:  # on the terrain it was rated on; the face cells' P_V stands for the gravity cells they cover
            pv = np.maximum(np.where(a.face.owned, 0.0, terrain_visibility(floors[a.agent], pose, a.camera,
                                                                            cfg.visibility)),
                            face_visibility(a.face, pose, a.camera, cfg.visibility, emap.grid))
        fresh = pv * (emap.n == 0)
        discounted = float((fresh * np.minimum(planned, 1.0)).sum())
        in_corr = float(fresh[corridor].sum()) if corridor is not None else 0.0
        why = _why(a.agent, len(chosen), bits, new, float(c.motion[j]), discounted, in_corr, first)
        if blind:
            why = (f"{a.agent}: no view is expected to map anything on this map; it looks along its "
                   f"path (yaw {math.degrees(yaw):.0f} deg, tilt {math.degrees(tilt):.0f} deg)")
        view = TeamView(a.agent, len(chosen), c.place, c.xyz, yaw, tilt, bits, new, float(c.motion[j]), u,
                        discounted, in_corr, why, np.clip(pv, 0.0, 1.0))
        chosen.append(view)
        first = first or view
        planned = 1.0 - (1.0 - planned) * (1.0 - np.clip(pv, 0.0, 1.0))  # some chosen view sees the cell
        if a.views > 1:  # the rest of its scan, from where this view is taken: no motion, never the same
            # pointing twice, each the best by what it adds (no fallback: the scan looks round)
            taken = np.zeros(c.motion.shape, bool)
            taken[j] = True
            rest = replace(c, motion=np.where(taken | ~np.isfinite(c.motion), np.inf, 0.0))
            left[k] = replace(a, centres=(rest,), views=a.views - 1, fallback=None, scanning=True)
        else:
            left.pop(k)
    return chosen, planned


def _best(emap: MapLike, terrain: Terrain, a: AgentViews, n_max: int, cfg: NbvConfig,
          planned: F64 | None, paid: float = 0.0) -> tuple[float, AgentViews, ViewCentre, int, float, float]:
    """The agent's best view: (utility, agent, centre, flat view index, H, expected new cells)."""
    interest = a.interest if a.interest is not None else np.asarray(emap.interest, float)
    gravity_interest = interest if a.face is None else np.where(a.face.owned, 0.0, interest)
    best: tuple[float, AgentViews, ViewCentre, int, float, float] | None = None
    for c in a.centres:
        r = rate_station(terrain, c.xyz, c.yaws, c.tilts, emap.n, n_max, gravity_interest, a.camera,
                         cfg.visibility, planned, weight=a.weight)
        bits, new = r.info_bits.ravel(), r.expected_new_cells.ravel()
        if a.face is not None:
            f = rate_face_station(a.face, c.xyz, c.yaws, c.tilts, n_max, interest, a.camera, cfg.visibility,
                                  planned, a.weight)
            bits, new = bits + f.info_bits.ravel(), new + f.expected_new_cells.ravel()
        with np.errstate(invalid="ignore"):
            u = utility(bits, np.maximum(c.motion - paid, 0.0), c.sigma_loc_m, cfg)
        u = np.where(np.isfinite(c.motion), u, -np.inf)  # a pointing it cannot take (taken in its scan)
        j = int(np.argmax(u))
        if best is None or float(u[j]) > best[0]:
            best = (float(u[j]), a, c, j, float(bits[j]), float(new[j]))
    assert best is not None  # agents without centres are left out by the caller
    return best


def _why(agent: str, order: int, bits: float, new: float, motion: float, discounted: float, corridor: float,
         first: TeamView | None) -> str:
    cost = "tether and head motion" if agent == "cliffbot" else "wheel and mast motion"
    text = (f"{agent} {'first' if order == 0 else 'next'}: {bits:.0f} bit, {new:.0f} new cells expected "
            f"({corridor:.0f} in the Cliff-bot's corridor), {cost} {motion:.1f}")
    if first is not None:
        text += f"; after {first.agent}'s view, {discounted:.0f} of its cells left to that view"
    return text


def focus_and_corridor(emap: MapLike, regions: tuple[tuple[float, ...], ...], corridor: NDArray[np.bool_],
                       cfg: TeamViewConfig) -> F64:
    """The task's weights of the bits: the focus regions (``[nbv] focus_regions``) and the
    Cliff-bot's corridor (:func:`corridor_weights`)."""
    return corridor_weights(corridor, cfg, focus_weights(emap.grid, regions) if regions else None)
