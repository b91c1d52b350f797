"""Whether the tethers hold the Cliff-bot where its lengths are off by what the planner must
tolerate (docs/algorithm.md §8, "Tension under the lengths' error"; docs/team.md, "The
planner", its margins).

The mission drives a node by paying out the two tether lengths its map gives there, and the
body rests where the TRUE ground and the winches' TRUE lengths put it. Two errors part them:

* the winches stop anywhere within ``length_tol_m`` of a set-point, each on its own (uniform:
  variance ``tol^2 / 3`` per tether, independent);
* the map's heights are within the codec's error bound ``e`` of the ground's. The error that
  moves the body is the height under it, which BOTH tethers share: raising the attachment by
  ``dz`` shortens tether ``i`` by ``u_iz dz`` (``u_i`` its unit pull), so the map adds
  ``e^2 / 3 * s s^T`` with ``s_i = -u_iz`` to the lengths' covariance. On a face where both
  tethers pull up alike it moves the body along the fall line (both lengths alike), which
  changes the tensions little; added independently to each tether it would move the body
  across, which splits the weight differently between them.

:func:`length_covariance` is that 2 x 2 covariance. :func:`length_offsets` are ``n`` length
errors on the ``z``-sigma ellipse of it (on the polygon circumscribing the ellipse, so any
linear function of the error reaches at least its ``z``-sigma value at one of them).
:func:`held_reason` settles the body at the node's lengths plus each offset
(:func:`fsw.core.team.tether_settle.settle_many`, one batch) and judges the statics where it comes to
rest: a place that is not held (the lengths cannot both be taut: ``slack``) or whose tension
leaves ``[T_min, T_max]`` where the ground is steeper than ``free_slope_deg`` is the node's
reason. Unlike a linear margin (the tension's gradient times where the body may be), this
follows the body over a contact appearing, the lip's kink, a ledge, where the tensions are far
from linear in the lengths. Its cost is kept to a linear margin's where the tensions are far
from their limits: a place whose tensions keep ``SCREEN`` (3) times their largest linear change
over the offsets inside the limits is held without settling (:func:`held_at`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from fsw.core.geometry import MapGrid
from fsw.core.team.tether import TetherConfig, TetherState, ZMap, statics_many, tether_states
from fsw.core.team.tether_settle import settle_many

F64 = NDArray[np.float64]
OFFSETS = 8  # length errors round the ellipse judged per place
SCREEN = 3.0  # a place whose tensions keep this many times their linear change inside the limits is held
_PROBES = np.array([[1.0, 0.0], [-1.0, 0.0], [0.0, 1.0], [0.0, -1.0]])  # central differences, in cells


@dataclass(frozen=True)
class LengthErrors:
    """What parts the lengths a set-point holds the body at from the map's lengths there."""

    length_tol_m: float = 0.0  # the winches stop within this of a set-point (each its own)
    map_error_m: float = 0.0  # the map's heights within this of the ground's (shared under the body)
    z: float = 2.326  # the ellipse's size in standard deviations (one-sided 99 %)
    plane_error_deg: float = 0.0  # the plane the map puts under the body leans up to this from the ground's

    @property
    def any(self) -> bool:
        return self.length_tol_m > 0.0 or self.map_error_m > 0.0 or self.plane_error_deg > 0.0


def length_covariance(st: TetherState, err: LengthErrors) -> F64:
    """The covariance (2 x 2, m^2) of the lengths that hold the body at the place of ``st``
    against the map's lengths there (module docstring): the winches' own errors plus the map's
    height error under the body, shared by both tethers through ``s_i = -u_iz``."""
    s = np.array([-st.paths[0].pull[2], -st.paths[1].pull[2]], float)
    return (err.length_tol_m ** 2 / 3.0) * np.eye(2) + (err.map_error_m ** 2 / 3.0) * np.outer(s, s)


def length_offsets(cov: F64, z: float, n: int = OFFSETS) -> F64:
    """``n`` length errors (n, 2) on the polygon circumscribing the ``z``-sigma ellipse of
    ``cov``: ``z / cos(pi / n) * C (cos t_k, sin t_k)`` with ``C`` the Cholesky factor of
    ``cov`` (continuous in ``cov``, so a way's offsets move smoothly from one end's to the
    other's)."""
    c = np.linalg.cholesky(np.asarray(cov, float) + 1e-12 * np.eye(2))
    t = 2.0 * math.pi * np.arange(n) / n
    return (z / math.cos(math.pi / n)) * (np.column_stack([np.cos(t), np.sin(t)]) @ c.T)


def statics_reason(st: TetherState | None, tcfg: TetherConfig, free_slope_deg: float) -> str:
    """Why the body is not held at a place it settled at (``""``: it is): no place
    (``slack``: the lengths cannot both be taut), or where the plane it stands on is steeper
    than ``free_slope_deg``, a tension outside ``[T_min, T_max]``."""
    if st is None:
        return "slack"
    if st.statics.tilt_deg <= free_slope_deg:
        return ""
    t1, t2 = st.statics.tensions_n
    if not (math.isfinite(t1) and math.isfinite(t2)) or min(t1, t2) < tcfg.t_min_n:
        return "slack"
    if max(t1, t2) > tcfg.t_max_n:
        return "over-tension"
    return ""


def leaned_reason(st: TetherState, tcfg: TetherConfig, free_slope_deg: float, lean_deg: float) -> str:
    """Why the body resting where ``st`` puts it may not be held when the plane it stands on
    leans up to ``lean_deg`` from the map's (``""``: it is held at every such lean). The map's
    plane under the footprint comes from heights that are least sure where the ground is
    steep, and the tensions split the body's weight by that plane's fall line: a tether that
    carries little on the map's plane can go slack on the ground's. The equilibrium is solved
    again, with the same pulls, for the plane's normal turned by ``lean_deg`` toward and away
    from the fall line and to either side of it (the normal recovered from the equilibrium,
    ``N n = m g e_z - T1 u1 - T2 u2``); a lean steeper than ``free_slope_deg`` must keep both
    tensions inside their limits."""
    if lean_deg <= 0.0 or st.statics.tilt_deg + lean_deg <= free_slope_deg:
        return ""
    u1, u2 = st.paths[0].pull, st.paths[1].pull
    t1, t2 = st.statics.tensions_n
    force = np.array([0.0, 0.0, tcfg.mass_kg * tcfg.gravity_mps2]) - t1 * u1 - t2 * u2
    if not (math.isfinite(st.statics.normal_n) and st.statics.normal_n > 1e-9) or not np.isfinite(force).all():
        return ""  # (no plane to lean: the statics' own verdict stands)
    n = force / float(np.linalg.norm(force))
    across = np.cross(n, [0.0, 0.0, 1.0])  # horizontal, across the fall line
    if float(np.linalg.norm(across)) < 1e-9:
        across = np.array([1.0, 0.0, 0.0])
    across /= float(np.linalg.norm(across))
    down = np.cross(across, n)
    a = math.radians(lean_deg)
    leaned = np.array([math.cos(a) * n + math.sin(a) * d for d in (across, -across, down, -down)])
    judged = statics_many(np.repeat(u1[None], 4, axis=0), np.repeat(u2[None], 4, axis=0), leaned, tcfg)
    for s in judged:
        if s.tilt_deg > free_slope_deg and not s.ok and s.reason in ("slack", "over-tension"):
            return s.reason
    return ""


NOT_HELD = "tension not held"  # an offset whose bounded settling ended undecided: refused


def held_at(z: ZMap, grid: MapGrid, anchors: F64, xy: F64, st: TetherState, offsets: F64, tcfg: TetherConfig,
            free_slope_deg: float) -> str:
    """Why the tethers may not hold the body that rests at ``xy`` (its state ``st``) when its
    lengths are off by each of ``offsets`` (n, 2) (``""``: they hold it at every one).

    The lengths' Jacobian and the tensions' gradient at ``xy`` (central differences over a map
    cell, one batch) predict where each offset moves the body and how each tension changes
    there. Where both tensions keep ``SCREEN`` times the largest predicted change inside their
    limits, no offset can take them out unless the statics are that far from linear over a few
    centimetres, and the place is held; elsewhere the body is settled at every offset from its
    predicted place in one bounded batch (:func:`fsw.core.team.tether_settle.settle_many`) and the
    statics re-solved where it rests (:func:`statics_reason`). An offset whose settling ends
    undecided (neither taut within the acceptance nor shown slack within the batch's steps) is
    :data:`NOT_HELD`: a place the check cannot show held is refused, never accepted. The first
    offset's reason, in the offsets' order, is the answer."""
    h = grid.cell
    lengths = np.asarray(st.lengths_m, float) + offsets
    around = tether_states(z, grid, anchors, np.asarray(xy, float) + _PROBES * h, tcfg)
    guesses = np.repeat(np.asarray(xy, float)[None, :], len(offsets), axis=0)
    if all(a is not None for a in around):
        ls = np.array([a.lengths_m for a in around if a is not None])
        ts = np.array([a.statics.tensions_n for a in around if a is not None])
        jl = np.column_stack([ls[0] - ls[1], ls[2] - ls[3]]) / (2 * h)  # dL_i/dx_k
        jt = np.column_stack([ts[0] - ts[1], ts[2] - ts[3]]) / (2 * h)  # dT_i/dx_k
        if np.isfinite(jl).all() and np.isfinite(jt).all() and abs(np.linalg.det(jl)) > 1e-9:
            moves = offsets @ np.linalg.inv(jl).T  # each offset's place, predicted
            change = moves @ jt.T  # each offset's tensions, predicted (n, 2)
            t = np.asarray(st.statics.tensions_n, float)
            drop = np.maximum(0.0, -change.min(axis=0))
            rise = np.maximum(0.0, change.max(axis=0))
            if np.all(t - tcfg.t_min_n >= SCREEN * drop) and np.all(tcfg.t_max_n - t >= SCREEN * rise):
                return ""
            guesses = guesses + moves
    got = settle_many(z, grid, anchors, lengths, guesses, tcfg)
    for place, unsettled in zip(got.places, got.unsettled, strict=True):
        why = NOT_HELD if unsettled else statics_reason(None if place is None else place[1], tcfg, free_slope_deg)
        if why:
            return why
    return ""


def held_reason(z: ZMap, grid: MapGrid, anchors: F64, xy: F64, st: TetherState, tcfg: TetherConfig,
                free_slope_deg: float, err: LengthErrors) -> str:
    """Why the tethers may not hold the body at the node ``xy`` (its state ``st`` on the map)
    when its lengths are off by the errors ``err`` allows (``""``: they hold it at every offset
    of :func:`length_offsets`; :func:`held_at`) or when the plane under it leans as ``err``
    allows (:func:`leaned_reason`)."""
    return leaned_reason(st, tcfg, free_slope_deg, err.plane_error_deg) or held_at(
        z, grid, anchors, xy, st, length_offsets(length_covariance(st, err), err.z), tcfg, free_slope_deg)
