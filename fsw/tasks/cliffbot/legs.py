"""A leg of the Cliff-bot's mission on its map: the way it drives, checked before it drives it
(docs/team.md, "The planner"), and the known place it drives to when the target's own ground
is not known yet (docs/team.md, "Approach: making the unknown known").

:class:`Route` is the mission's map as its legs use it, made again for every map: the map's
hazard layers (its rocks grown by a lattice spacing for the tethers' contacts), the planner's
margins from the map's error bound, each way between two places judged once
(:func:`fsw.core.team.face_planner.way_reason`), a leg's path planned with the edges the body
cannot pass cut (:meth:`Route.plan`), the test that the lengths held the body elsewhere
(:meth:`Route.elsewhere`) and the approach node (:meth:`Route.approach`).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage

from fsw.core.geometry import MapGrid
from fsw.core.team.climber_ground import ClimberConfig, disc, ground_layers
from fsw.core.team.face_planner import Margins, Plan, lattice_nodes_near, place_covariance, plan_targets, way_reason
from fsw.core.team.held_tension import LengthErrors
from fsw.core.team.tether import TetherConfig
from fsw.sections import CliffbotMissionConfig

F64 = NDArray[np.float64]
MAX_CUT_ROUNDS = 12  # a leg's plan, its impassable edges cut, planned again at most this often
APPROACH_CANDIDATES = 24  # known nodes nearest the target tried as the approach node, per plan
APPROACH_STEP_NODES = 1  # an approach node is nearer the target than where it stands by more than this many spacings
# a target's reasons that a look can change: its ground (or its tethers' ground) is not known, or
# no path is known (the ground between may be what is not known)
UNKNOWN_REASONS = ("unknown ground", "tether over unknown ground", "no safe path")


@dataclass
class Leg:
    goal: F64
    target: int | None  # index into the targets, None for the leg home
    waypoints: list[F64] = field(default_factory=list)
    length_m: float = 0.0
    via: F64 | None = None  # the known node it drives to first, to look at the target's ground
    looks: int = 0  # looks taken for this target (approach)
    idle: int = 0  # of those, looks since the approach last got nearer the target (its budget)
    nearest_m: float = math.inf  # the nearest an approach node has come to the target
    # a leg home that retraces the way it came: the winches' set-points, one per waypoint, in the
    # order driven (the lengths it held on the way out, last first); None: set-points from the map
    lengths: list[tuple[float, float]] | None = None
    guards: int = 0  # ways of this leg the tension guard stopped
    back_to: int | None = None  # backing off (the tension guard): the trail's index it drives back to


class Route:
    """The mission's map as its legs use it (module docstring)."""

    def __init__(self, z: F64, grid: MapGrid, error_bound_m: float, cfg: CliffbotMissionConfig,
                 tcfg: TetherConfig, ccfg: ClimberConfig, anchors: F64,
                 carried: NDArray[np.bool_] | None = None, carried_from: F64 | None = None,
                 refused: Sequence[tuple[F64, str]] = ()) -> None:
        self.z, self.grid, self.error_bound_m = z, grid, error_bound_m
        # cells known only by the plane under the body carried on beyond where its wheels stand
        # (CliffbotMission.set_map): no node a leg ends on or crosses counts them as known
        ok = carried is not None and carried.shape == z.shape
        self.carried = carried if ok else None
        self.carried_from = np.asarray(carried_from, float) if carried_from is not None else np.zeros(2)
        self.cfg, self.tcfg, self.ccfg, self.anchors = cfg, tcfg, ccfg, anchors
        # the body stands within a lattice spacing of the node whose lengths hold it (a way from
        # there is judged from where it stands, Route.elsewhere), so its footprint and its tethers'
        # contacts fall up to about that far from the node's: the nodes keep their footprints, and
        # the ways their tethers, a lattice spacing off the map's hazards and rocks
        ground = ground_layers(z, grid, ccfg, self.carried, anchors)
        grow = disc(int(round(ccfg.node_m / grid.cell)))
        self.ground = dataclasses.replace(ground, rock=ndimage.binary_dilation(ground.rock, structure=grow),
                                          hazard=ndimage.binary_dilation(ground.hazard, structure=grow))
        self.ways: dict[tuple[float, float, float, float, float], str] = {}  # way_reason per pair of places (leaving)
        self.nodes: dict[int, str] = {}  # the lattice's verdicts on this map (plan_targets' verdicts)
        # places where the winches' measured tensions stopped a way (the tension guard,
        # CliffbotMission.refused): the nodes round each are refused for the reason measured there,
        # and no way between waypoints passes nearer than guard_radius_m
        self.refused = [(np.asarray(xy, float).reshape(2), why) for xy, why in refused]
        for xy, why in self.refused:
            for k in lattice_nodes_near(grid, ccfg, xy, cfg.guard_radius_m):
                self.nodes[k] = why

    def errors(self) -> LengthErrors:
        """What parts the lengths that put the body at a place from the map's lengths there: the
        winches stop anywhere within ``length_tol_m`` of the set-point, and the map's heights,
        which the set-point's lengths come from, are within the codec's error bound of the
        ground's (each uniform; the map's shared by both tethers under the body); judged at
        ``margin_sigmas`` (:mod:`fsw.core.team.held_tension`); and the plane the map puts under
        the body leans up to ``plane_error_deg`` from the ground's."""
        return LengthErrors(self.cfg.length_tol_m, self.error_bound_m, self.cfg.margin_sigmas,
                            self.cfg.plane_error_deg)

    def margins(self) -> Margins:
        """The planner's margins. The winches put the body where the lengths hold it, within
        ``length_tol_m`` of a node's lengths and off by the map's error: the tethers must hold it
        (both tensions inside their limits, the statics re-solved where it settles) at every
        length error of :meth:`errors`, hard; the footprint's clearance from hazards is soft
        (paths keep ``track_margin_m`` clear where the ground leaves room, without calling a
        target the wheels can reach unreachable)."""
        return Margins(self.cfg.track_margin_m, errors=self.errors())

    def plan(self, start: F64, goal: F64) -> tuple[Plan, list[F64]]:
        """The leg from ``start`` (where it stands, held by its tethers: the way out of that node
        is planned) to ``goal`` and its waypoints; an edge the body cannot pass (the statics
        between its nodes) is cut and the leg planned again, at most ``MAX_CUT_ROUNDS`` times
        (then ``no safe path``)."""
        cut: list[tuple[F64, F64]] = []
        margins = self.margins()
        for _ in range(MAX_CUT_ROUNDS):
            plan = plan_targets(self.z, self.grid, self.anchors, start, goal[None, :], self.tcfg, self.ccfg,
                                margins, start_usable=True, blocked=cut, unseen=self.carried, ground=self.ground,
                                verdicts=self.nodes)
            path = plan.paths[0]
            if path is None:
                return plan, []
            wps, bad = self.waypoints(path)
            if not bad:
                return plan, wps
            cut += bad
        return dataclasses.replace(plan, paths=(None,), lengths_m=(math.inf,), reasons=("no safe path",)), []

    def waypoints(self, path: F64) -> tuple[list[F64], list[tuple[F64, F64]]]:
        """Every ``waypoint_every``-th node of the path, or every node where the way between
        would not hold (:func:`fsw.core.team.face_planner.way_reason` on its map, the planning
        limits): the winches move both lengths straight from one waypoint's lengths to the
        next's, and the body follows where the statics put it, not the path's line (near the lip
        the tensions change by tens of newtons over centimetres; above a ledge the ledge's
        lengths hold it on the face). Also every edge of the path the body cannot pass. A way from
        a node in a hazard (the path's way out of a hazard the body stands in, ``plan_targets``
        with ``start_usable``) is judged as leaving it (``way_reason(leaving=True)``)."""
        every = self.cfg.waypoint_every
        out: list[F64] = []
        bad: list[tuple[F64, F64]] = []
        iy, ix, _ = self.grid.cell_index(path[:, 0], path[:, 1])
        in_hazard = self.ground.hazard[iy, ix]
        i = 0
        while i < len(path) - 1:
            j = min(i + every, len(path) - 1)
            leaving = bool(in_hazard[i])
            if j > i + 1 and (self.near_refused(path[i], path[j]) or not self.passable(path[i], path[j], leaving)):
                j = i + 1
            if j == i + 1 and not self.passable(path[i], path[j], leaving):
                bad.append((path[i], path[j]))
            out.append(path[j])
            i = j
        return (out or [path[-1]]), bad

    def near_refused(self, a: F64, b: F64) -> bool:
        """Whether the straight way from ``a`` to ``b`` passes within ``guard_radius_m`` of a place
        the tension guard refused."""
        ab = np.asarray(b, float) - np.asarray(a, float)
        n2 = float(ab @ ab)
        for xy, _ in self.refused:
            t = 0.0 if n2 <= 0.0 else min(1.0, max(0.0, float((xy - a) @ ab) / n2))
            if float(np.hypot(*(a + t * ab - xy))) <= self.cfg.guard_radius_m:
                return True
        return False

    def passable(self, a: F64, b: F64, leaving: bool = False) -> bool:
        """Whether the body can go from ``a`` to ``b`` on its map in the planning limits
        (:func:`way_reason`, ``leaving`` as there; each pair judged once per map)."""
        key = (round(float(a[0]), 4), round(float(a[1]), 4), round(float(b[0]), 4), round(float(b[1]), 4),
               float(leaving))
        if key not in self.ways:
            self.ways[key] = way_reason(self.z, self.grid, self.anchors, a, b, self.tcfg, self.ccfg, self.ground,
                                        errors=self.errors(), leaving=leaving)
        return not self.ways[key]

    def elsewhere(self, est_xy: F64, est_cov: F64, wp: F64) -> tuple[bool, float, float]:
        """Whether the estimate says, beyond its uncertainty, that the waypoint's lengths hold the
        body more than a lattice spacing from it (what the check of the next way assumes): the
        offset past ``node_m`` along its direction over its standard deviation, the estimate's
        covariance plus the lengths' error carried to the place (``face_planner.place_covariance``),
        above ``margin_sigmas``. Returns (elsewhere, offset, its standard deviation)."""
        d = est_xy - wp
        off = float(np.hypot(*d))
        if off <= self.ccfg.node_m:
            return False, off, math.nan
        got = place_covariance(self.z, self.grid, self.anchors, wp, self.tcfg, self.ccfg, self.errors(), est_cov)
        if got is None:
            return True, off, math.nan
        u = d / off
        sd = math.sqrt(max(float(u @ got[0] @ u), 0.0))
        return off - self.ccfg.node_m > self.cfg.margin_sigmas * sd, off, sd

    def approach(self, start: F64, target: F64) -> tuple[F64, Plan, list[F64]] | None:
        """The known, safe, tether-feasible node nearest ``target`` (in the map's plane) that the
        body can drive to from ``start``, nearer the target than ``start`` by more than a
        lattice spacing (``APPROACH_STEP_NODES``): its place, the plan and the waypoints there;
        None when there is none. The step may be short: a steep face below a lip is seen only by
        a head out over the lip (the head is ``head_end_m`` ahead of the body), and the known
        ground round a start a few decimetres behind the lip often ends a decimetre or two
        nearer the target (a node is known when its whole footprint is); the node keeps every
        safety rule of any node.

        Candidates are the lattice nodes whose whole footprint is known and free of hazards
        (``Ground.known``, ``Ground.hazard``; never by the plane under its body carried on beyond
        where its wheels stand, ``carried``: the first step too, as any leg), the
        ``APPROACH_CANDIDATES`` nearest the target; they are planned together (:func:`plan_targets`
        with the leg's margins: each judged like any node, tethers and tension margins included)
        and the nearest with a path whose ways hold (:meth:`plan`) is the approach node. From
        there its head's scan covers the ground up to its camera's range round it: the nearest
        known ground to the target is where a look shows most of the target's unknown
        neighbourhood."""
        xy, d = self.known_nodes(target)
        here = float(np.hypot(start[0] - target[0], start[1] - target[1]))
        nearer = d < here - APPROACH_STEP_NODES * self.ccfg.node_m
        return self._nearest_driven(start, xy[nearer], np.argsort(d[nearer], kind="stable"))

    def vantage(self, start: F64, target: F64, rating: Callable[[F64], tuple[int, int]], apart_m: float
                ) -> tuple[F64, Plan, list[F64]] | None:
        """Where to look from next when no known node is nearer ``target`` than ``start``: of the
        known, safe, tether-feasible nodes no farther from the target than ``start`` by more than
        ``apart_m`` (along the known ground's edge, not back up), the one ``rating`` rates highest
        that the body can drive to, the nearer the target of two rated alike; None when none rates
        above (0, 0) or none can be driven to. A rating is (the unknown ground the next step needs
        that its head's scan would show from there and from no place it looked from, that which it
        would show from a place a new sight line away: :mod:`fsw.tasks.cliffbot.head_sight`), compared
        in that order. A look from one standing leaves blind spots its scan does not reach (the
        body's box hides the ground beside its middle, the ground just below the lip beside the
        head), and ground a scan should have shown may stay unknown (hidden by the ground itself):
        a look from another standing sees some of it. Candidates are planned as
        :meth:`approach`'s."""
        xy, d = self.known_nodes(target)
        far = d <= float(np.hypot(start[0] - target[0], start[1] - target[1])) + apart_m
        xy, d = xy[far], d[far]
        score = np.array([rating(p) for p in xy], float).reshape(-1, 2)
        worth = score.max(axis=1) > 0
        return self._nearest_driven(start, xy[worth], np.lexsort((d[worth], -score[worth, 1], -score[worth, 0])))

    def known_nodes(self, target: F64) -> tuple[F64, F64]:
        """The lattice nodes whose whole footprint is known and free of hazards (never by the
        plane carried on, ``carried``) and their distance to ``target`` in the map's plane."""
        g, grid = self.ground, self.grid
        stride = max(1, int(round(self.ccfg.node_m / grid.cell)))
        rows = np.arange(stride // 2, grid.ny, stride)
        cols = np.arange(stride // 2, grid.nx, stride)
        rr, cc = np.meshgrid(rows, cols, indexing="ij")
        ok = (g.known & ~g.hazard)[rr, cc]
        xy = np.column_stack([grid.x0 + (cc[ok] + 0.5) * grid.cell, grid.y0 + (rr[ok] + 0.5) * grid.cell])
        return xy, np.hypot(xy[:, 0] - target[0], xy[:, 1] - target[1])

    def _nearest_driven(self, start: F64, xy: F64, order: NDArray[np.intp]) -> tuple[F64, Plan, list[F64]] | None:
        """Of the nodes ``xy`` taken in ``order`` (best first), the first ``APPROACH_CANDIDATES``
        planned together with the leg's margins, then the first with a path whose ways hold
        (:meth:`plan`): its place, plan and waypoints; None when none."""
        if not len(xy):
            return None
        cand = xy[order[:APPROACH_CANDIDATES]]
        first = plan_targets(self.z, self.grid, self.anchors, start, cand, self.tcfg, self.ccfg, self.margins(),
                             start_usable=True, unseen=self.carried, ground=self.ground, verdicts=self.nodes)
        for k, path in enumerate(first.paths):
            if path is None:
                continue
            plan, wps = self.plan(start, cand[k])
            if plan.paths[0] is not None:
                return cand[k], plan, wps
        return None
