"""Judging a team mission on the truth (docs/team.md, "Running a team mission").

Whatever drives the two flight programs (:mod:`hil_sim.team.team_run`), the verdict on a
team mission comes from here and only from the TRUTH:

* :func:`judge_pose`: the violations at one true pose of the Cliff-bot (a tension outside
  its limits on steep ground, a tether contact on a rock, the footprint on a hazard cell of
  the true ground's layers); the bench calls it after every step;
* :func:`fix_error`: a RECON-bot fix against the Cliff-bot's true pose (position error,
  heading error, NEES against the fix's own covariance);
* :func:`truth_verdict`: the brute-force reference on the TRUE ground under the same tether
  limits: every node of the planner's lattice judged (``fsw.core.team.face_planner.node_reasons``:
  the same verdict the flight planner gives a node), then an exhaustive shortest-path search
  (Dijkstra over the whole usable lattice, ``scipy.sparse.csgraph``) from the Cliff-bot's start,
  the way along each edge of a path found judged as the mission drives it
  (``face_planner.way_reason``: the lengths moved straight, the body settled, judged at every
  place, ending at the next node) and an edge that fails removed and the search run again until
  the path holds or none is left: each target's reason (``""`` when reachable) and its
  shortest path length. With the winches' length tolerance (:func:`winch_errors`, one of the
  tether limits: a winch stops anywhere within ``length_tol_m`` of its set-point) each node of
  a path and each way is also judged as the flight planner judges them under that error
  (``face_planner.node_held_reason``, ``way_reason(errors=...)``: the body settled at the
  lengths off by each error, the statics re-solved there), the truth's ground having no map
  error; without it, at the exact lengths;
* :func:`unknown_cells_entered`: the distinct cells of the true path the received map did
  not know; :func:`unknown_at_entry`: the cells the true path entered that the Cliff-bot's map
  did not know from a sensor WHEN it entered them (what the bench records step by step, and
  what the summary counts when the driver recorded it: a cell its camera showed later was
  still unknown ground when it drove onto it);
* :func:`judge_team`: all of it for one mission, from a :class:`TeamOutcome` (what the driver
  observed), as a :class:`TeamVerdict` whose :meth:`TeamVerdict.section` is the summary's
  ``team`` section.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from fsw.core.geometry import MapGrid, wrap_angle
from fsw.core.team.climber_ground import ClimberConfig, Ground
from fsw.core.team.face_planner import USABLE, node_held_reason, node_reasons, way_reason
from fsw.core.team.held_tension import LengthErrors
from fsw.core.team.tether import TetherConfig, TetherState, ZMap
from fsw.core.team.tether_settle import settle
from hil_sim.world.world import World

F64 = NDArray[np.float64]
CHI2_95_6DOF = 12.5916  # the chi-square 95 % bound of 6 degrees of freedom
Cell = tuple[int, int]


@dataclass(frozen=True)
class FixError:
    """One fix judged against the truth."""

    range_m: float  # from the RECON-bot's camera to the Cliff-bot (NaN when not known)
    err_cm: float  # position error
    err_deg: float  # heading error (absolute)
    nees: float  # 6-dof normalised estimation error squared, against the fix's covariance


def fix_error(est_t: F64, est_rotvec_err: F64, est_dyaw_rad: float, cov: F64, true_t: F64,
              range_m: float = math.nan) -> FixError:
    """A fix against the truth: ``est_rotvec_err`` is ``log(R_est R_true^T)``, the error vector
    is ``[rotation error, position error]`` in the fix's covariance order."""
    e = np.concatenate([np.asarray(est_rotvec_err, float), np.asarray(est_t, float) - np.asarray(true_t, float)])
    try:
        nees = float(e @ np.linalg.solve(np.asarray(cov, float), e))
    except np.linalg.LinAlgError:
        nees = math.inf
    dyaw = math.degrees(wrap_angle(est_dyaw_rad))
    return FixError(range_m, 100 * float(np.linalg.norm(e[3:])), abs(dyaw), nees if math.isfinite(nees) else math.inf)


def judge_pose(state: TetherState, xy: F64, truth: Ground, grid: MapGrid, tcfg: TetherConfig,
               ccfg: ClimberConfig) -> tuple[list[str], Cell | None]:
    """The violations at one true pose (kinds of ``hil_sim.team.cliffbot_rig.VIOLATIONS``
    except ``slack`` and ``spool``, which the bench sees before a pose exists) and the
    hazard cell the footprint's centre is on, if any. ``tension``: where the plane the
    Cliff-bot stands on is steeper than ``free_slope_deg`` (its wheels alone do not hold it),
    a tension outside ``[T_min, T_max]``."""
    found: list[str] = []
    t1, t2 = state.statics.tensions_n
    iy, ix, inside = grid.cell_index(np.array([xy[0]]), np.array([xy[1]]))
    steep = state.statics.tilt_deg > ccfg.free_slope_deg  # the plane it stands on, as the planner judges
    if steep and not (tcfg.t_min_n <= min(t1, t2) and max(t1, t2) <= tcfg.t_max_n):
        found.append("tension")
    for p in state.paths:
        if len(p.contacts):
            cy, cx, ok = grid.cell_index(p.contacts[:, 0], p.contacts[:, 1])
            if (ok & truth.rock[np.clip(cy, 0, grid.ny - 1), np.clip(cx, 0, grid.nx - 1)]).any():
                found.append("tether_on_rock")
                break
    cell: Cell | None = None
    if inside[0] and truth.hazard[iy[0], ix[0]]:
        found.append("wheel_on_hazard")
        cell = (int(iy[0]), int(ix[0]))
    return found, cell


@dataclass(frozen=True)
class TruthReach:
    """What the truth allows: per target its reason (``""``: reachable) and shortest length."""

    reasons: tuple[str, ...]
    lengths_m: tuple[float, ...]  # 3-D length over the lattice (inf when unreachable)
    nodes: int  # lattice nodes judged
    usable: int  # of them usable


_TRUTH_CACHE: dict[bytes, TruthReach] = {}  # a few seconds per scene: each scene judged once per process


class _SettleMemo:
    """:func:`fsw.core.team.tether_settle.settle` on one ground, each pair of lengths from each place
    worked out once. The truth judges the same ground at the exact lengths and under the
    winches' tolerance (``safer-hil experiment team``, a mission's judge beside a check at the
    exact lengths), and each judges the ways of its paths: a way at both follows the same steps
    from the same places (``way_reason`` settles before it judges the tolerance), so the second
    gets the first's answers (settle is a function of its arguments)."""

    def __init__(self, z: F64, grid: MapGrid, anchors: F64, tcfg: TetherConfig) -> None:
        self._ground = (z, grid, anchors, tcfg)
        self._got: dict[tuple[float, float, float, float], tuple[F64, TetherState] | None] = {}

    def __call__(self, z: ZMap, grid: MapGrid, anchors: F64, lengths: tuple[float, float], guess_xy: F64,
                 cfg: TetherConfig) -> tuple[F64, TetherState] | None:
        mz, mgrid, manchors, mcfg = self._ground
        if not (z is mz and grid == mgrid and anchors is manchors and cfg == mcfg):
            return settle(z, grid, anchors, lengths, guess_xy, cfg)
        key = (float(lengths[0]), float(lengths[1]), float(guess_xy[0]), float(guess_xy[1]))
        if key not in self._got:
            self._got[key] = settle(z, grid, anchors, lengths, guess_xy, cfg)
        got = self._got[key]
        return None if got is None else (got[0].copy(), got[1])


@dataclass(frozen=True)
class _TruthGround:
    """What the truth's verdicts on one ground share, whatever the errors they judge under:
    the lattice's verdicts and the ground's layers (``node_reasons``), the settled places."""

    z: F64
    anchors: F64
    rows: NDArray[np.intp]
    cols: NDArray[np.intp]
    base: list[str]
    ground: Ground
    settle_at: _SettleMemo


_GROUND_CACHE: dict[bytes, _TruthGround] = {}  # the last few grounds judged in this process


def winch_errors(length_tol_m: float, margin_sigmas: float) -> LengthErrors:
    """The length errors the truth judges under: the winches' own (each stops within
    ``length_tol_m`` of its set-point), at the flight's ``margin_sigmas``, with no map error
    (the truth's lengths are the true ground's). The flight planner's error model
    (:mod:`fsw.core.team.held_tension`) with the map's part zero."""
    return LengthErrors(length_tol_m, 0.0, margin_sigmas)


def truth_verdict(world: World, grid: MapGrid, anchors: F64, tcfg: TetherConfig,
                  ccfg: ClimberConfig, errors: LengthErrors | None = None) -> TruthReach:
    """The brute-force planner on the TRUE ground (module docstring); ``errors``: the length
    errors every node of a path and every way must be held at (:func:`winch_errors`; None:
    the exact lengths)."""
    import hashlib

    if world.team is None:
        raise ValueError("the scenario has no team (use a cliff-team scenario)")
    z = np.asarray(world.ground_on_grid(grid), np.float64)
    anchors = np.asarray(anchors, float)
    ground_key = hashlib.sha256(b"".join([z.tobytes(), anchors.tobytes(), repr((grid, tcfg, ccfg)).encode()])).digest()
    key = hashlib.sha256(b"".join([
        ground_key, np.asarray(world.team.cliffbot_start_xy, float).tobytes(),
        np.asarray(world.team.targets_xyz, float).tobytes(), repr(errors).encode()])).digest()
    if key not in _TRUTH_CACHE:
        if len(_TRUTH_CACHE) >= 8:
            _TRUTH_CACHE.pop(next(iter(_TRUTH_CACHE)))
        if ground_key not in _GROUND_CACHE:
            if len(_GROUND_CACHE) >= 2:
                _GROUND_CACHE.pop(next(iter(_GROUND_CACHE)))
            rows, cols, base, g = node_reasons(z, grid, anchors, tcfg, ccfg)
            _GROUND_CACHE[ground_key] = _TruthGround(z, anchors, rows, cols, base, g,
                                                     _SettleMemo(z, grid, anchors, tcfg))
        _TRUTH_CACHE[key] = _brute_force(world, _GROUND_CACHE[ground_key], grid, tcfg, ccfg, errors)
    return _TRUTH_CACHE[key]


def _brute_force(world: World, truth: _TruthGround, grid: MapGrid, tcfg: TetherConfig,
                 ccfg: ClimberConfig, errors: LengthErrors | None) -> TruthReach:
    """Dijkstra over the usable lattice, each path found judged and its failing parts removed
    (module docstring). A node's held check under ``errors`` is made when a path first passes
    it (a node that fails loses its edges, and the search is run again): the same verdicts as
    judging every node first, at the cost of the nodes the paths reach."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import dijkstra

    assert world.team is not None
    z, anchors, rows, cols, base, g = truth.z, truth.anchors, truth.rows, truth.cols, truth.base, truth.ground
    ny, nx = len(rows), len(cols)
    usable = np.array([r == USABLE for r in base]).reshape(ny, nx)
    nz = np.nan_to_num(np.asarray(z, np.float64)[np.ix_(rows, cols)])
    px = np.broadcast_to(grid.x0 + (cols + 0.5) * grid.cell, (ny, nx))
    py = np.broadcast_to((grid.y0 + (rows + 0.5) * grid.cell)[:, None], (ny, nx))
    pts = np.stack([px, py, nz], axis=-1).reshape(-1, 3)
    idx = np.arange(ny * nx).reshape(ny, nx)
    src, dst = [], []
    for dr, dc in ((0, 1), (1, 0), (1, 1), (1, -1)):  # each undirected 8-neighbour pair once
        a = idx[0:ny - dr, max(0, -dc):nx - max(0, dc)]
        b = idx[dr:ny, max(0, dc):nx - max(0, -dc)]
        ok = usable.ravel()[a.ravel()] & usable.ravel()[b.ravel()]
        src.append(a.ravel()[ok])
        dst.append(b.ravel()[ok])
    s0, d0 = np.concatenate(src), np.concatenate(dst)
    s_, d_ = np.concatenate([s0, d0]), np.concatenate([d0, s0])  # both directions: a way is directed
    w = np.linalg.norm(pts[s_] - pts[d_], axis=1)
    edge = {(int(p), int(q)): i for i, (p, q) in enumerate(zip(s_, d_, strict=True))}
    alive = np.ones(len(s_), bool)
    ways: dict[int, str] = {}
    stride = max(1, int(round(ccfg.node_m / grid.cell)))

    def node_of(xy: F64) -> int | None:  # the planner's rounding (face_planner.plan_targets)
        iy, ix, inside = grid.cell_index(np.array([xy[0]]), np.array([xy[1]]))
        if not inside[0]:
            return None
        cy = min(ny - 1, max(0, int(round((int(iy[0]) - rows[0]) / stride))))
        cx = min(nx - 1, max(0, int(round((int(ix[0]) - cols[0]) / stride))))
        return cy * nx + cx

    held = errors is not None and errors.any
    held_why: dict[int, str] = {}

    def reason(k: int) -> str:
        """The node's verdict: ``node_reasons``', and where usable, held at the lengths' errors."""
        if base[k] != USABLE or not held or errors is None:
            return base[k]
        if k not in held_why:
            held_why[k] = node_held_reason(z, grid, anchors, pts[k, :2], tcfg, ccfg, errors) or USABLE
        return held_why[k]

    def way_ok(e: int) -> bool:
        if e not in ways:
            ways[e] = way_reason(z, grid, anchors, pts[s_[e], :2], pts[d_[e], :2], tcfg, ccfg, g, errors=errors,
                                 settle_at=truth.settle_at)
        return not ways[e]

    targets = np.asarray(world.team.targets_xyz[:, :2], float)
    start = node_of(np.asarray(world.team.cliffbot_start_xy, float))
    n_usable = int(usable.sum())
    if start is None or reason(start) != USABLE:
        why = "off the map" if start is None else reason(start)
        return TruthReach(tuple(f"start: {why}" for _ in targets), tuple(math.inf for _ in targets),
                          ny * nx, n_usable)
    why_not: list[str] = []
    lengths: list[float] = []
    for t in targets:
        k = node_of(t)
        if k is None or reason(k) != USABLE:
            why_not.append("off the map" if k is None else reason(k))
            lengths.append(math.inf)
            continue
        while True:  # the shortest path, its failing ways removed, until it holds or none is left
            graph = coo_matrix((w[alive], (s_[alive], d_[alive])), shape=(ny * nx, ny * nx)).tocsr()
            dist, pred = dijkstra(graph, directed=True, indices=start, return_predecessors=True)
            if not math.isfinite(float(dist[k])):
                why_not.append("no safe path")
                lengths.append(math.inf)
                break
            chain = [k]
            while chain[-1] != start:
                chain.append(int(pred[chain[-1]]))
            weak = [n for n in chain if reason(n) != USABLE]
            if weak:  # a node not held at the lengths' errors: no way enters or leaves it
                alive[np.isin(s_, weak) | np.isin(d_, weak)] = False
                continue
            bad = [e for e in (edge[(p, q)] for q, p in zip(chain[:-1], chain[1:], strict=True)) if not way_ok(e)]
            if not bad:
                why_not.append("")
                lengths.append(float(dist[k]))
                break
            alive[bad] = False
    return TruthReach(tuple(why_not), tuple(lengths), ny * nx, n_usable)


def came_home(events: Sequence[Sequence[Any]]) -> bool:
    """Whether a mission's events (time, name, text) hold its ``HOME``: it reached its start."""
    return any(len(e) > 1 and e[1] == "HOME" for e in events)


def unknown_cells_entered(path: Sequence[tuple[float, float]], z: NDArray[np.floating], grid: MapGrid) -> int:
    """Distinct map cells the Cliff-bot's true path moved onto that its map does not know
    (the start, where it stands before any move, is not counted)."""
    if len(path) < 2:
        return 0
    p = np.asarray(path[1:], float)
    iy, ix, inside = grid.cell_index(p[:, 0], p[:, 1])
    zz = np.asarray(z)
    cells = {(int(a), int(b)) for a, b, ok in zip(iy, ix, inside, strict=True)
             if not ok or not math.isfinite(float(zz[a, b]))}
    return len(cells)


def unknown_at_entry(points: NDArray[np.floating], known: NDArray[np.bool_] | None, grid: MapGrid) -> set[Cell]:
    """The cells of ``points`` (N, 2, in the map's frame: the true positions the Cliff-bot just
    moved to) that ``known`` (the Cliff-bot's map at that moment: a height from a sensor, not
    the plane under its body carried on; None: no map yet) does not hold."""
    p = np.asarray(points, float).reshape(-1, 2)
    iy, ix, inside = grid.cell_index(p[:, 0], p[:, 1])
    out: set[Cell] = set()
    for a, b, ok in zip(iy, ix, inside, strict=True):
        if not ok or known is None or known.shape != grid.shape or not bool(known[a, b]):
            out.add((int(a), int(b)))
    return out


def path_length_m(path: Sequence[tuple[float, float]]) -> float:
    """The horizontal length of a path."""
    if len(path) < 2:
        return 0.0
    return float(np.sum(np.linalg.norm(np.diff(np.asarray(path, float), axis=0), axis=1)))


@dataclass(frozen=True)
class TeamOutcome:
    """What the driver of a team mission observed (its flight programs' and bench's records)."""

    reached: Sequence[bool]  # per target, from the Cliff-bot's mission
    map_reasons: Sequence[str]  # per target, the mission's reason not ("" when planned)
    true_path: Sequence[tuple[float, float]]  # the Cliff-bot's true positions, from its start
    violations: Mapping[str, int]  # the bench's counts by kind (judge_pose, slack, spool)
    hazard_cells: frozenset[Cell]  # distinct true hazard cells entered
    fixes: Sequence[FixError] = ()
    fixes_used: int = 0
    fixes_refused: int = 0
    link_bytes_down: int = 0  # RECON-bot -> Cliff-bot air bytes in the team phase
    link_bytes_up: int = 0
    link_bad_packets: int = 0
    can_bad_frames: int = 0
    final_state: str = ""
    safe_reason: str = ""
    events: Sequence[Sequence[Any]] = ()
    sim_s: float = 0.0
    looks: Sequence[int] = ()  # per target, the looks the mission took to approach it (docs/team.md)
    # the cells entered that its map did not know then (unknown_at_entry, step by step); None: not
    # recorded, the path is judged against the final map (unknown_cells_entered)
    unknown_at_entry: frozenset[Cell] | None = None


@dataclass(frozen=True)
class TeamVerdict:
    """One team mission judged on the truth."""

    outcome: TeamOutcome
    truth_reasons: tuple[str, ...]
    unknown_cells_entered: int
    extra: Mapping[str, Any] = field(default_factory=dict)

    @property
    def targets(self) -> int:
        return len(self.truth_reasons)

    @property
    def targets_reached(self) -> int:
        return int(sum(bool(r) for r in self.outcome.reached))

    @property
    def reachable_by_truth(self) -> int:
        return sum(1 for r in self.truth_reasons if not r)

    @property
    def missed(self) -> list[int]:
        """Targets the truth finds reachable that the mission did not reach."""
        got = list(self.outcome.reached) + [False] * self.targets
        return [k for k, r in enumerate(self.truth_reasons) if not r and not got[k]]

    @property
    def tether_violations(self) -> int:
        return int(sum(self.outcome.violations.values()))

    @property
    def nees_within(self) -> float | None:
        fx = self.outcome.fixes
        return (sum(f.nees <= CHI2_95_6DOF for f in fx) / len(fx)) if fx else None

    def section(self) -> dict[str, Any]:
        """The summary's ``team`` section (docs/team.md lists its keys)."""
        o, fx = self.outcome, self.outcome.fixes
        out: dict[str, Any] = {
            "targets": self.targets,
            "targets_reached": self.targets_reached,
            "targets_reachable_by_truth": self.reachable_by_truth,
            "targets_unreachable_by_truth": self.targets - self.reachable_by_truth,
            "truth_reasons": list(self.truth_reasons),
            "map_reasons": list(o.map_reasons),
            "reached": [bool(r) for r in o.reached],
            "target_looks": [int(n) for n in o.looks],
            "reachable_missed": self.missed,
            "tether_violations": self.tether_violations,
            "violations": dict(o.violations),
            "hazard_cells_entered": len(o.hazard_cells),
            "unknown_cells_entered": self.unknown_cells_entered,
            "fix_errors_cm": [round(f.err_cm, 3) for f in fx],
            "fix_errors_deg": [round(f.err_deg, 3) for f in fx],
            "fix_ranges_m": [round(f.range_m, 2) if math.isfinite(f.range_m) else None for f in fx],
            "fix_nees": [round(f.nees, 3) if math.isfinite(f.nees) else None for f in fx],
            "fix_nees_within_chi2_95": self.nees_within,
            "fixes_used": o.fixes_used,
            "fixes_refused": o.fixes_refused,
            "link_bytes_down": o.link_bytes_down,
            "link_bytes_up": o.link_bytes_up,
            "link_bad_packets": o.link_bad_packets,
            "can_bad_frames": o.can_bad_frames,
            "final_state": o.final_state,
            "safe_reason": o.safe_reason,
            "events": [list(e) for e in o.events],
            "path_m": round(path_length_m(o.true_path), 3),
            "back_home": came_home(o.events),
            "home_off_m": (round(float(np.hypot(*np.subtract(o.true_path[-1], o.true_path[0]))), 3)
                           if o.true_path else 0.0),
            "sim_s": round(o.sim_s, 3),
        }
        out.update(self.extra)
        return out


def judge_team(world: World, grid: MapGrid, received_z: NDArray[np.floating], anchors: F64,
               tcfg: TetherConfig, ccfg: ClimberConfig, outcome: TeamOutcome,
               errors: LengthErrors | None = None) -> TeamVerdict:
    """One team mission judged on the truth: the brute-force reachability (under ``errors``,
    :func:`truth_verdict`), the cells of the true path the Cliff-bot's map did not know (when it
    entered them, if the driver recorded it; else on ``received_z``), and the bench's violations."""
    truth = truth_verdict(world, grid, anchors, tcfg, ccfg, errors)
    unknown = (len(outcome.unknown_at_entry) if outcome.unknown_at_entry is not None
               else unknown_cells_entered(outcome.true_path, received_z, grid))
    return TeamVerdict(outcome, truth.reasons, unknown,
                       {"truth_lengths_m": [round(x, 3) if math.isfinite(x) else None for x in truth.lengths_m],
                        "truth_nodes": truth.nodes, "truth_usable_nodes": truth.usable})
