"""Geofence: no motion command may take a wheel across the cliff edge (docs/algorithm.md §2).

A motion command goes from rover pose A to pose B ``(x, y, yaw)``. The rover is taken to
move as the motion task drives a ``goto`` (:func:`goto_legs`): turn in place toward B (or
away from it, to back up, when that is the smaller turn), drive straight, turn to B's yaw;
each leg sampled every ``sample_step_m`` / ``sample_step_deg``. (A turn in place swings the
corners of the rover: close to the edge it is the turn, not the drive, that comes nearest.)
Each wheel's contact patch (a rectangle
``wheel_diameter_m`` long and ``wheel_width_m`` wide at the wheel centre) sweeps the union
of the convex hulls of consecutive samples. The command is allowed only if every swept
wheel patch stays on the safe side of the fitted edge and at least ``margin_m`` away from
it. The edge is taken to continue straight for ``extend_m`` past the ends the map saw
(``EdgeModel.barrier``). The test is exact for polygons: a swept patch that keeps
``margin_m`` from the barrier lies wholly on one side of it, and the side of one of its
points (``EdgeModel.signed_distance``) is the side of all. The verdict names the reason, the
wheel and the clearance.

Unknown ground (``require_known_ground``): every swept wheel patch must also lie on ground the
flight software knows (``fsw.core.edge.known_ground``: mapped cells, small stereo holes filled, or
ground the rover has stood on); a move over unmapped ground is refused, naming the wheel. A
wheel off the map grid can never be on known ground (no view maps it): even the edge-only
check (``known_ground=False``, a planner's station) refuses a station whose wheels would rest
there (a turn on the way that clips the grid's border is left to the mission's check). The
rover's footprint where it stands (``set_edge(model, stand)``) is safe ground: the edge's
straight continuation past the ends the map saw stops short of it, and (with known ground
required) at unknown ground, which no wheel may enter anyway: a hooked end of a glimpsed edge
then no longer swings its continuation through the blind zone beside the rover.

Without a fitted edge (the edge search): the flow of docs/algorithm.md §2 finds the edge before
the rover drives along it. When the views from the start do not reach the drop (an edge
1.5-2 m away hides the pit floor behind its lip), no edge can be fitted, yet the rover must
move to see it (``explore_without_edge``): a move is then allowed when every swept wheel patch
keeps ``margin_m`` from every mapped cell more than a step below the rover's ground (the drop
cells of the edge extraction, ``fsw.core.edge.edge``; ``set_drop``) and, as always, stays on known
ground and on the map grid. Unknown ground, where a drop may hide, is never driven over: the
mission looks at it first, and what the look maps as lower ground joins the drop cells. With
no drop map either, the geofence refuses (unless ``allow_without_edge``).

Unmapped ground nearby (with known ground required, edge or no edge): the frontier of the map
is a lip as often as not (a steep face is hidden below it, so no drop cell is mapped near it,
no edge is fitted there, or only past a fitted edge's open end, and the last mapped cell
straddles the lip), and known ground reaches ``known_fill_m`` past that cell. So every swept
wheel patch also keeps ``margin_m`` from unmapped ground (the mapped cells with holes up to
``known_fill_m`` closed, not grown; ground stood on is known). A rover already closer than
that may make a move along which no wheel patch comes closer to unmapped ground than it is at
the start. The mission looks at that ground first (``unknown_points``).

Pose drift (``drift_k``): the check is made on the pose estimate, and dead reckoning drifts
as the rover drives (a heading error bends the path; ``fsw.core.localization.odometry``). For the ground
checks (unknown ground, off the map, near a mapped drop), each swept wheel patch is widened by
``drift_k`` times the growth of the position sigma from the start of the move to that
sample (``fsw.core.localization.odometry.drift_sigma``, from the heading sigma at the start,
``set_drift``): a long drive must keep farther from ground the map has not seen than a short
one. Only the growth: where the rover stands its footprint is known ground, so a rover is
never boxed in by its own standing uncertainty (a registered view resets it: ``fsw.core.localization.nav_fix``).

Recovery (``recover_inside_margin``): a new edge fit can put the rover, standing still,
inside the margin (a longer or re-shaped edge, or its straight continuation past a fresh end,
now passes close by). Refusing every move would box the rover in for good, so a rover that
stands inside the margin, with every wheel still on the safe side, may make a move that ends
outside the margin and whose swept wheels never come closer to the edge on the way than they
are at its start: it can back away, never closer. A rover whose wheels touch the fitted edge
where it stands (the fit is off by a wheel's width: the rover stands on safe ground) may make
a move that ends outside the margin along which no wheel centre comes closer to the edge.
Such a verdict says "recovering".
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np
import shapely
from numpy.typing import NDArray
from shapely.geometry.base import BaseGeometry

from fsw.core.edge.edge import EdgeModel, EdgeSegments
from fsw.core.edge.known_ground import KnownGround, Pose3, StoodOn, rover_footprint
from fsw.core.geometry import MapGrid, RoverConfig, wrap_angle
from fsw.core.localization.odometry import drift_sigma
from fsw.core.motion.motion_profile import MotionConfig
from fsw.framework.params import param

F64 = NDArray[np.float64]

WHEELS = ("front_left", "front_right", "rear_left", "rear_right")
RECOVERY_TOL_M = 1e-4  # a recovering move may come this much closer than its start (sampling round-off)


@dataclass(frozen=True)
class GeofenceConfig:
    """Geofence parameters (config ``[geofence]``)."""

    margin_m: float = param(0.15, lo=0.0, hi=5.0, units="m", doc="wheel to edge clearance")
    wheel_width_m: float = param(0.12, lo=0.01, hi=1.0, units="m")
    extend_m: float = param(
        1.0, lo=0.0, hi=100.0, units="m", doc="the edge is taken to go on this far past its ends"
    )
    sample_step_m: float = param(0.05, lo=0.001, hi=1.0, units="m")
    sample_step_deg: float = param(5.0, lo=0.1, hi=90.0, units="deg")
    allow_without_edge: bool = param(False, doc="allow motion before any edge is mapped")
    recover_inside_margin: bool = param(
        True, doc="a rover already inside the margin may move out of it, never coming closer to the edge"
    )
    require_known_ground: bool = param(
        True, doc="refuse moves whose wheels would cross ground the map has not measured"
    )
    known_fill_m: float = param(
        0.06, lo=0.0, hi=1.0, units="m",
        doc="ground within this of a measured cell counts as known (stereo holes, view borders)"
    )
    explore_without_edge: bool = param(
        True, doc="no edge fitted yet: allow moves on known ground keeping margin_m from every mapped drop cell"
    )
    drift_k: float = param(
        2.0, lo=0.0, hi=10.0, units="sigma",
        doc="ground checks: wheel patches widened by this many sigmas of the pose drift grown along the move",
    )


@dataclass(frozen=True)
class Verdict:
    """The geofence's answer to one motion command."""

    allowed: bool
    reason: str
    clearance_m: float  # smallest wheel-to-edge distance; negative beyond it (inf: no edge)
    wheel: str = ""  # the wheel closest to the edge


class Geofence:
    """Checks motion commands against the current edge model."""

    def __init__(self, cfg: GeofenceConfig, rover: RoverConfig) -> None:
        self.cfg = cfg
        self.rover = rover
        self._edge: EdgeModel | None = None
        self._barrier: BaseGeometry | None = None
        # the edge's barrier as segments, for the known ground of version key (see _edge_side)
        self._segments: tuple[tuple[int, int], EdgeSegments] | None = None
        self.stood = StoodOn()  # the ground stood on: known to ``known`` and ``mapped`` alike
        self.known = KnownGround(cfg.known_fill_m, self.stood)
        self.clear = KnownGround(0.0)  # cells at least margin_m from any mapped drop cell
        # measured cells, small holes closed, not grown (a lip may lie past them)
        self.mapped = KnownGround(0.0, self.stood)
        self.rejections = 0
        self._drift: tuple[float, MotionConfig] | None = None  # heading sigma now, the odometry model

    def set_drift(self, sigma_yaw_rad: float, motion: MotionConfig | None) -> None:
        """The heading sigma of the pose estimate now and the odometry's drift model (None:
        no widening), for the ground checks (module docstring, "Pose drift")."""
        ok = motion is not None and math.isfinite(sigma_yaw_rad) and self.cfg.drift_k > 0.0
        self._drift = (max(sigma_yaw_rad, 0.0), motion) if ok and motion is not None else None

    def set_edge(self, model: EdgeModel | None, stand: Pose3 | None = None) -> None:
        """Use a new edge fit (None or an empty fit: no edge known); ``stand``: the rover's
        pose now (its footprint is safe ground, and known ground from now on)."""
        if stand is not None:
            self.known.stood_on(self.footprint(stand))
        if model is None or model.empty:
            self._edge = self._barrier = None
            self._segments = None
        else:
            if stand is not None:
                model = dataclasses.replace(model, stand=self.footprint(stand))
            if self.cfg.require_known_ground and self.known.ready:
                # The straight continuation guards ground the map saw; unknown ground is
                # refused to every wheel anyway, so the continuation ends where it begins.
                # Past the (shortened) ends the fit says nothing; unknown ground is refused there.
                model = dataclasses.replace(model, stop_at=lambda q: ~self.known.known_xy(q),
                                            open_ends=True)
            self._edge = model
            self._barrier = model.barrier(self.cfg.extend_m)
            self._segments = None
            shapely.prepare(self._barrier)

    def _edge_side(self, xy: F64) -> F64:
        """``EdgeModel.signed_distance`` of points to the edge extended by ``extend_m``. Its
        continuation stops at unknown ground (``set_edge``), so it is that of the known ground
        now: the segments are kept while the known ground stays as it was."""
        assert self._edge is not None
        key = self.known.version
        if self._segments is None or self._segments[0] != key:
            self._segments = key, self._edge.segments(self.cfg.extend_m)
        return self._segments[1].signed_distance(xy)

    def set_map(self, grid: MapGrid, n: NDArray[np.int32]) -> None:
        """The map's measurement counts: where the ground is known."""
        self.known.set_map(grid, n)
        mapped = np.asarray(np.asarray(n) >= 1, dtype=np.uint8)
        r = int(round(self.cfg.known_fill_m / grid.cell))
        if r > 0 and mapped.any():  # holes closed; the border not grown (cv2 pads a closing neutrally)
            k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
            mapped = np.asarray(cv2.morphologyEx(mapped, cv2.MORPH_CLOSE, k), dtype=np.uint8)
        self.mapped.set_map(grid, mapped.astype(np.int32))

    def set_drop(self, grid: MapGrid, drop: NDArray[np.bool_]) -> None:
        """The mapped drop cells (``fsw.core.edge.edge.EdgeCells.drop``): while no edge is fitted,
        wheels keep ``margin_m`` from them."""
        near: NDArray[np.uint8] = np.asarray(drop, dtype=np.uint8)
        r = int(math.ceil(self.cfg.margin_m / grid.cell))
        if r > 0 and near.any():
            disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
            near = np.asarray(cv2.dilate(near, disc), dtype=np.uint8)
        self.clear.set_map(grid, near == 0)

    def footprint(self, pose: Pose3) -> BaseGeometry:
        return rover_footprint(pose, self.rover, self.cfg.wheel_width_m)

    def wheel_centres(self, poses: F64) -> F64:
        """(S, 4, 2) wheel centres for (S, 3) poses, in the order of ``WHEELS``."""
        hx, hy = self.rover.wheelbase_m / 2.0, self.rover.track_m / 2.0
        local = np.array([[hx, hy], [hx, -hy], [-hx, hy], [-hx, -hy]])
        return _transform(local[None, :, :], poses)

    def swept_wheels(self, a: tuple[float, float, float], b: tuple[float, float, float],
                     drift: bool = False) -> list[BaseGeometry]:
        """The area each wheel patch sweeps from pose ``a`` to pose ``b`` (``drift``: widened
        by the pose drift grown along the move, for the ground checks)."""
        poses = self._samples(a, b)
        hl, hw = self.rover.wheel_diameter_m / 2.0, self.cfg.wheel_width_m / 2.0
        patch = np.array([[hl, hw], [hl, -hw], [-hl, -hw], [-hl, hw]])
        centres = self.wheel_centres(poses)  # (S, 4, 2)
        yaw = poses[:, 2]
        c, s = np.cos(yaw), np.sin(yaw)
        rot = np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)  # (S, 2, 2)
        corners = centres[:, :, None, :] + np.einsum("sij,kj->ski", rot, patch)[:, None]
        grow = self._drift_growth(poses) if drift else None
        out = []
        for w in range(len(WHEELS)):
            cw = corners[:, w]  # (S, 4, 2)
            pairs = np.concatenate([cw[:-1], cw[1:]], axis=1) if len(cw) > 1 else cw
            hulls = shapely.convex_hull(shapely.multipoints(pairs))
            if grow is not None:
                hulls = shapely.buffer(hulls, grow[1:] if len(cw) > 1 else grow[:1], quad_segs=2)
            out.append(shapely.union_all(hulls))
        return out

    def _drift_growth(self, poses: F64) -> F64 | None:
        """``drift_k`` times the position sigma grown from the first sample to each one."""
        if self._drift is None or len(poses) < 2:
            return None
        sigma_yaw, motion = self._drift
        step = np.hypot(np.diff(poses[:, 0]), np.diff(poses[:, 1]))
        turn = np.abs(np.diff(np.unwrap(poses[:, 2])))
        path, turned = np.r_[0.0, np.cumsum(step)], np.r_[0.0, np.cumsum(turn)]
        grow = self.cfg.drift_k * drift_sigma(0.0, sigma_yaw, path, turned, motion)
        return grow if grow[-1] > 1e-4 else None

    def check(self, a: tuple[float, float, float], b: tuple[float, float, float],
              known_ground: bool = True) -> Verdict:
        """Allow or reject the motion from ``a`` to ``b``; the reason says why.
        ``known_ground=False`` checks the edge alone (a planner's station that the mission
        will look at before it drives there), and that no wheel comes to rest off the map
        grid (ground no look can map)."""
        pa, pb = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
        if pa.shape != (3,) or pb.shape != (3,) or not (np.isfinite(pa).all()
                                                        and np.isfinite(pb).all()):
            self.rejections += 1
            return Verdict(False, "rejected: poses must be finite (x, y, yaw) triples",
                           float("nan"))
        if self._edge is None or self._barrier is None:
            if self.cfg.allow_without_edge:
                return Verdict(True, "allowed: no cliff edge mapped", math.inf)
            if self.cfg.explore_without_edge and self.clear.ready and self.known.ready:
                return self._clear_of_drops(self.swept_wheels(tuple(pa), tuple(pb), drift=True), tuple(pa),
                                            tuple(pb), known_ground)
            self.rejections += 1
            return Verdict(False, "rejected: no cliff edge mapped yet", math.inf)
        swept = self.swept_wheels(tuple(pa), tuple(pb))
        dist = np.array([self._barrier.distance(g) for g in swept])
        for w, geom in enumerate(swept):
            if dist[w] > 0.0:  # wholly on one side: test one point of each part
                parts = getattr(geom, "geoms", [geom])
                reps = shapely.get_coordinates([p.representative_point() for p in parts])
                if (self._edge_side(reps) < 0).any():
                    self.rejections += 1
                    return Verdict(False, f"rejected: wheel {WHEELS[w]} is beyond the edge",
                                   -float(dist[w]), WHEELS[w])
        w = int(np.argmin(dist))
        clear = float(dist[w])
        if clear < self.cfg.margin_m and self.cfg.recover_inside_margin:
            start, end = (min(self._barrier.distance(g) for g in self.swept_wheels(p, p))
                          for p in (tuple(pa), tuple(pb)))
            away = clear >= start - RECOVERY_TOL_M if clear > 0.0 else (
                start == 0.0 and self._backs_away(tuple(pa), tuple(pb)))
            if away and end >= self.cfg.margin_m:
                unknown = self._ground_refusal(self._drifted(swept, pa, pb, known_ground), tuple(pa), tuple(pb),
                                               known_ground)
                if unknown is not None:
                    self.rejections += 1
                    return Verdict(False, unknown, clear, WHEELS[w])
                return Verdict(True, f"allowed: recovering out of the margin: clearance {clear:.3f} m on the "
                               f"way, never below the start's {start:.3f} m; {end:.3f} m at the end "
                               f"(wheel {WHEELS[w]})", clear, WHEELS[w])
        if clear < self.cfg.margin_m:
            self.rejections += 1
            where = "crosses the edge" if clear == 0.0 else (
                f"comes within {clear:.3f} m of the edge")
            return Verdict(False, f"rejected: wheel {WHEELS[w]} {where} "
                           f"(margin {self.cfg.margin_m:.2f} m)", clear, WHEELS[w])
        unknown = self._ground_refusal(self._drifted(swept, pa, pb, known_ground), tuple(pa), tuple(pb),
                                               known_ground)
        if unknown is not None:
            self.rejections += 1
            return Verdict(False, unknown, clear, WHEELS[w])
        return Verdict(True, f"allowed: clearance {clear:.3f} m (wheel {WHEELS[w]})",
                       clear, WHEELS[w])

    def _drifted(self, swept: list[BaseGeometry], a: F64, b: F64,
                 known_ground: bool = True) -> list[BaseGeometry]:
        """``swept`` widened by the drift for the ground checks (itself without a drift model,
        or for a planner's station: its ground check looks at the end pose only)."""
        if self._drift is None or not known_ground:
            return swept
        return self.swept_wheels(tuple(a), tuple(b), drift=True)

    def _clear_of_drops(self, swept: list[BaseGeometry], a: Pose3, b: Pose3, known_ground: bool) -> Verdict:
        """No edge fitted yet: every swept wheel patch ``margin_m`` from every mapped drop cell,
        then the ground checks of a move with an edge."""
        grid = self.clear.grid
        assert grid is not None

        def near_drop(geom: BaseGeometry) -> int:  # on-grid cells within margin_m of a drop
            pts = self.clear.unknown_points(geom)
            return int(grid.cell_index(pts[:, 0], pts[:, 1])[2].sum()) if len(pts) else 0

        refusal = _wheel_refusal(swept, near_drop, "rejected: no cliff edge mapped yet; wheel {wheel} would "
                                 f"come within {self.cfg.margin_m:.2f} m of a drop ({{n}} cells)")
        refusal = refusal or self._ground_refusal(swept, a, b, known_ground)
        if refusal is not None:
            self.rejections += 1
            return Verdict(False, refusal, math.inf)
        return Verdict(True, "allowed: no cliff edge mapped yet; every wheel keeps "
                       f"{self.cfg.margin_m:.2f} m from the mapped drop", math.inf)

    def _unmapped_near(self, geom: BaseGeometry) -> F64:
        """(N, 2) centres of the on-grid unmapped cells (``self.mapped``; ground stood on is
        known) within ``margin_m`` of ``geom``."""
        grid = self.mapped.grid
        pts = self.mapped.unknown_points(shapely.buffer(geom, self.cfg.margin_m, quad_segs=4))
        if grid is None or len(pts) == 0:
            return np.zeros((0, 2))
        return pts[grid.cell_index(pts[:, 0], pts[:, 1])[2]]

    def _near_unmapped(self, a: Pose3, b: Pose3) -> str | None:
        """The refusal if a swept wheel patch comes within ``margin_m`` of unmapped ground (a
        hidden lip may lie there: past the ends of a fitted edge, or with none fitted), or closer
        than its patch at the start ``a`` is (a rover already that close may move along or away,
        never closer), else None. The patches are not widened by the drift (the known-ground
        check is): the comparison with the start is like for like."""
        if not (self.cfg.require_known_ground and self.mapped.ready):
            return None
        swept, start = self.swept_wheels(a, b), self.swept_wheels(a, a)
        for w, geom in enumerate(swept):
            pts = self._unmapped_near(geom)
            if len(pts) == 0:
                continue
            near = float(shapely.distance(geom, shapely.points(pts)).min())
            here = self._unmapped_near(start[w])
            was = float(shapely.distance(start[w], shapely.points(here)).min()) if len(here) else math.inf
            if near < min(self.cfg.margin_m, was - RECOVERY_TOL_M):
                return (f"rejected: wheel {WHEELS[w]} would come within {near:.3f} m "
                        f"of unknown ground (margin {self.cfg.margin_m:.2f} m: a lip may be hidden there)")
        return None

    def _backs_away(self, a: Pose3, b: Pose3) -> bool:
        """For a rover whose wheels already touch the fitted edge where it stands (a fit error
        the size of a wheel: the rover stands on safe ground): every wheel centre's signed
        distance to the edge never decreases along the move."""
        assert self._edge is not None
        centres = self.wheel_centres(self._samples(a, b))  # (S, 4, 2)
        sd = self._edge_side(centres.reshape(-1, 2))
        sd = sd.reshape(centres.shape[:2])
        return bool((np.diff(sd, axis=0) >= -RECOVERY_TOL_M).all())

    def unknown_points(self, a: Pose3, b: Pose3) -> F64:
        """(N, 2) centres of the unknown map cells the wheels would sweep from ``a`` to ``b``."""
        swept = self.swept_wheels(a, b, drift=True)
        pts = [self.known.unknown_points(g) for g in swept]
        if self.cfg.require_known_ground and self.mapped.ready:
            pts += [self._unmapped_near(g) for g in swept]  # the ground within the margin too
        return np.concatenate(pts) if pts else np.zeros((0, 2))

    def _unknown_ground(self, swept: list[BaseGeometry]) -> str | None:
        """The refusal if a swept wheel patch covers unmapped ground, else None."""
        if not (self.cfg.require_known_ground and self.known.ready):
            return None
        return _wheel_refusal(swept, self.known.unknown_cells,
                              "rejected: wheel {wheel} would cross unknown ground ({n} unmapped cells)")

    def _ground_refusal(self, swept: list[BaseGeometry], a: Pose3, b: Pose3, known_ground: bool) -> str | None:
        """The mission's check (``known_ground``): every swept wheel patch on the grid, on
        known ground and ``margin_m`` from unmapped ground (``_near_unmapped``). A planner's
        station (edge only): its wheels must not REST off the grid (no look can ever map that
        ground); a turn on the way that clips the grid's border is the mission's check to
        refuse, or to drive part of the way."""
        if known_ground:
            return self._off_map(swept) or self._unknown_ground(swept) or self._near_unmapped(a, b)
        return self._off_map(self.swept_wheels(b, b))

    def _off_map(self, swept: list[BaseGeometry]) -> str | None:
        """The refusal if a swept wheel patch leaves the map grid (ground no view can make
        known: the edge check of a planner's station refuses it too), else None."""
        if not (self.cfg.require_known_ground and self.known.ready):
            return None
        return _wheel_refusal(swept, self.known.off_map_cells,
                              "rejected: wheel {wheel} would leave the map ({n} cells off the grid)")

    def _samples(self, a: tuple[float, float, float], b: tuple[float, float, float]
                 ) -> F64:
        """Poses along the move as the motion task drives it (:func:`goto_legs`)."""
        legs = goto_legs(a, b)
        parts = [self._linear(p, q) for p, q in zip(legs[:-1], legs[1:], strict=True)]
        return np.concatenate([parts[0]] + [p[1:] for p in parts[1:]])

    def _linear(self, a: tuple[float, float, float], b: tuple[float, float, float]
                ) -> F64:
        dyaw = wrap_angle(b[2] - a[2])
        dist = math.hypot(b[0] - a[0], b[1] - a[1])
        n = max(1, math.ceil(dist / self.cfg.sample_step_m),
                math.ceil(abs(math.degrees(dyaw)) / self.cfg.sample_step_deg))
        s = np.linspace(0.0, 1.0, n + 1)
        return np.column_stack([a[0] + s * (b[0] - a[0]), a[1] + s * (b[1] - a[1]),
                                a[2] + s * dyaw])


def _wheel_refusal(swept: list[BaseGeometry], count: Callable[[BaseGeometry], int], reason: str) -> str | None:
    """``reason`` (with ``{wheel}`` and ``{n}``) for the first wheel whose swept patch has
    ``count`` > 0 bad cells, else None."""
    for w, geom in enumerate(swept):
        n = count(geom)
        if n:
            return reason.format(wheel=WHEELS[w], n=n)
    return None


def goto_legs(a: Pose3, b: Pose3) -> list[Pose3]:
    """The poses a ``goto`` from ``a`` to ``b`` passes through, as the motion task drives it
    (``fsw.tasks.motion``: turn in place toward the target, or away from it and back up when
    that is the smaller turn; drive straight; turn to the final yaw)."""
    dist = math.hypot(b[0] - a[0], b[1] - a[1])
    if dist < 1e-6:
        return [a, b]
    turn = math.remainder(math.atan2(b[1] - a[1], b[0] - a[0]) - a[2], math.tau)
    if abs(turn) > math.pi / 2:
        turn = math.remainder(turn - math.pi, math.tau)
    h = a[2] + turn
    return [a, (a[0], a[1], h), (b[0], b[1], h), b]


def _transform(local: F64, poses: F64) -> F64:
    """Body-frame points (1, K, 2) to world for each pose (S, 3) -> (S, K, 2)."""
    c, s = np.cos(poses[:, 2])[:, None], np.sin(poses[:, 2])[:, None]
    x = poses[:, 0:1] + c * local[..., 0] - s * local[..., 1]
    y = poses[:, 1:2] + s * local[..., 0] + c * local[..., 1]
    return np.stack([x, y], axis=-1)
