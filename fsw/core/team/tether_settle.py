"""Forward kinematics of the tethers: where the Cliff-bot rests at given paid-out lengths (docs/algorithm.md §8).

Given the paid-out lengths ``l1, l2``, the Cliff-bot rests where both tethers are taut:
``L_i(p) = l_i`` for ``p`` on the ground, with ``L_i`` the taut tether's length of
:mod:`fsw.core.team.tether` (the statics of one place). :func:`settle` solves the two
equations for ``(x, y)`` by Gauss-Newton from a guess (the previous pose), with a Nelder-Mead
search where Gauss-Newton stalls; :func:`settle_many` settles many pairs of lengths in batches
at a bounded cost.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from fsw.core.geometry import MapGrid
from fsw.core.team.tether import F64, TetherConfig, TetherState, ZMap, tether_state, tether_states
from fsw.core.team.tether_batch import vector_norm


def settle(z: ZMap, grid: MapGrid, anchors: F64, lengths: tuple[float, float], guess_xy: F64,
           cfg: TetherConfig, iterations: int = 30, tol_m: float = 1e-3) -> tuple[F64, TetherState] | None:
    """Forward kinematics: where both tethers, paid out to ``lengths``, are taut on the ground.

    Gauss-Newton on ``L_i(x, y) = l_i`` from ``guess_xy`` (the last pose): the Jacobian by
    central differences of the tether lengths at one map cell, each step halved until the
    residual shrinks. On a rough face steeper than about 75 degrees the lengths are rough
    functions of ``(x, y)`` at the scale of a cell (a centimetre across the face is several
    up it) and Gauss-Newton can cycle; then a Nelder-Mead search on the largest length
    residual from the best place seen (:func:`_settle_search`) decides, with the same
    acceptance. None when neither finds both tethers taut within it (the lengths cannot both
    be taut: the Cliff-bot would hang on one tether)."""
    xy = np.asarray(guess_xy, float).copy()
    h = grid.cell
    target = np.asarray(lengths, float)
    probes = np.array([[h, 0.0], [-h, 0.0], [0.0, h], [0.0, -h]])
    known: TetherState | None = None  # the state at ``xy`` when the last step's trial computed it
    accept = 10 * tol_m + 0.25 * h
    best: tuple[float, F64] = (math.inf, xy.copy())
    for _ in range(iterations):
        st = known if known is not None else tether_state(z, grid, anchors, xy, cfg)
        known = None
        if st is None:
            return None
        r = np.asarray(st.lengths_m) - target
        if float(np.max(np.abs(r))) < best[0]:
            best = (float(np.max(np.abs(r))), xy.copy())
        if np.max(np.abs(r)) < tol_m:
            return xy, st
        jac = np.empty((2, 2))
        around = tether_states(z, grid, anchors, xy + probes, cfg)  # x + h, x - h, y + h, y - h
        for k in range(2):
            hi, lo = around[2 * k], around[2 * k + 1]
            if hi is None or lo is None:
                return None
            jac[:, k] = (np.asarray(hi.lengths_m) - np.asarray(lo.lengths_m)) / (2 * h)
        if abs(np.linalg.det(jac)) < 1e-9:
            return None
        step = np.linalg.solve(jac, r)
        n = vector_norm(step)
        if n > 0.5:  # a damped step: the ground under the Cliff-bot is only known locally
            step *= 0.5 / n
        # Backtracking: a contact appearing or vanishing makes the lengths kink, and a full
        # Gauss-Newton step can cycle across the kink; halve it until the residual shrinks.
        xy, known = _backtrack(z, grid, anchors, xy, step, target, vector_norm(r), cfg)
    st = known if known is not None else tether_state(z, grid, anchors, xy, cfg)
    if st is not None and np.max(np.abs(np.asarray(st.lengths_m) - target)) < accept:
        return xy, st
    return _settle_search(z, grid, anchors, target, best[1], cfg, accept)


_HALVINGS = 0.5 ** np.arange(7)  # settle's step and its six halvings (exact: powers of two)


def _backtrack(z: ZMap, grid: MapGrid, anchors: F64, xy: F64, step: F64, target: F64, r_norm: float,
               cfg: TetherConfig) -> tuple[F64, TetherState | None]:
    """:func:`settle`'s backtracking step from ``xy``: the step, halved until the residual at
    ``xy - step`` is below ``r_norm`` (at most six times; after the sixth the step is halved
    once more and taken), and the state there. Every trial place is worked out in one
    :func:`tether_states` batch (the same values as one at a time), the last one included: on
    a rough face most steps are halved a few times, and a batch costs about as much as two
    places one at a time."""
    places = xy - _HALVINGS[:, None] * step  # the trials, then the place taken when none shrinks
    states = tether_states(z, grid, anchors, places, cfg)
    for k in range(len(places) - 1):
        trial = states[k]
        if trial is not None and vector_norm(np.asarray(trial.lengths_m) - target) < r_norm:
            return places[k], trial
    return places[-1], states[-1]


def _settle_search(z: ZMap, grid: MapGrid, anchors: F64, target: F64, xy0: F64, cfg: TetherConfig,
                   accept_m: float) -> tuple[F64, TetherState] | None:
    """Nelder-Mead (``scipy.optimize``) on ``max_i |L_i(x, y) - l_i|`` from ``xy0``, its first
    simplex a quarter cell wide; the place found when it is within ``accept_m``."""
    from scipy.optimize import minimize

    def worst(p: F64) -> float:
        st = tether_state(z, grid, anchors, p, cfg)
        return float(np.max(np.abs(np.asarray(st.lengths_m) - target))) if st is not None else math.inf

    d = 0.25 * grid.cell
    res = minimize(worst, xy0, method="Nelder-Mead",
                   options={"xatol": 1e-4, "fatol": 1e-4, "maxfev": 120,
                            "initial_simplex": np.array([xy0, xy0 + [d, 0.0], xy0 + [0.0, d]])})
    xy = np.asarray(res.x, float)
    st = tether_state(z, grid, anchors, xy, cfg)
    if st is not None and float(np.max(np.abs(np.asarray(st.lengths_m) - target))) < accept_m:
        return xy, st
    return None


@dataclass(frozen=True)
class SettledMany:
    """What :func:`settle_many` found for each pair of lengths: ``places[i]`` the place and its
    state where both tethers are taut (None: they cannot both be, as :func:`settle`'s None),
    ``unsettled[i]`` True where its budget ended with neither (the place is not decided)."""

    places: list[tuple[F64, TetherState] | None]
    unsettled: NDArray[np.bool_]


FULL_STEPS = 6  # settle_many's first pass: Gauss-Newton steps taken whole (damped only)
SETTLE_MANY_ITERATIONS = 30  # its second pass, backtracking, as many steps as :func:`settle`
_BACKTRACK = 6  # halvings of a step that does not shrink the residual, as :func:`settle`'s
SEARCH_RADII = (4.0, 2.0, 1.0, 0.5, 0.25, 0.125, 0.0625)  # the compass search's steps, in map cells, each tried twice
_COMPASS = np.array([[1.0, 0.0], [-1.0, 0.0], [0.0, 1.0], [0.0, -1.0],
                     [0.7071, 0.7071], [-0.7071, 0.7071], [0.7071, -0.7071], [-0.7071, -0.7071]])


def settle_many(z: ZMap, grid: MapGrid, anchors: F64, lengths: F64, guesses_xy: F64, cfg: TetherConfig,
                iterations: int = SETTLE_MANY_ITERATIONS, tol_m: float = 1e-3) -> SettledMany:
    """:func:`settle` of many pairs of lengths ``lengths`` (M, 2), each from its guess
    ``guesses_xy`` (M, 2), in batches and at a bounded cost. Each Gauss-Newton step evaluates
    every place still going and its four Jacobian probes in one :func:`tether_states` batch and
    solves all the 2 x 2 steps at once. Three stages, each for the places the last left going:

    1. ``FULL_STEPS`` whole steps (damped only: a full step can jump a kink of the lengths, a
       contact appearing or vanishing, that a backtracking step stops at);
    2. from the best place each reached, ``iterations`` steps each halved until the residual
       shrinks (at most ``_BACKTRACK`` times, one batch per halving, as :func:`settle`'s); a
       place no halving improves is stuck and stops;
    3. where the best place is not within :func:`settle`'s acceptance (``10 tol_m`` plus a
       quarter cell), the compass search that stands for :func:`settle`'s Nelder-Mead
       (:func:`_compass_search`: on a rough face the lengths are rough functions of the place
       at the scale of a cell and Gauss-Newton stalls).

    A place off the known ground or with a singular Jacobian in stage 2 is None (the lengths
    cannot both be taut there), as :func:`settle`'s; one within ``tol_m`` is settled, and the
    others at their best place when it is within the acceptance. The rest are *unsettled*
    (``SettledMany.unsettled``): undecided, for the caller to refuse. A place costs at most
    ``5 (FULL_STEPS + 1) + 5 (iterations + 1) + _BACKTRACK iterations + 16 len(SEARCH_RADII)``
    tether states, whatever the ground."""
    target = np.asarray(lengths, float).reshape(-1, 2)
    guesses = np.asarray(guesses_xy, float).reshape(-1, 2)
    out = _Batch(len(target))
    _gauss_newton(z, grid, anchors, target, guesses, cfg, np.arange(len(target)), FULL_STEPS, 0, tol_m, out)
    again = np.flatnonzero(out.going)
    # from the best place the whole steps reached (their guess where they reached none)
    start = np.where(np.isfinite(out.best_res)[:, None], out.best_xy, guesses)
    _gauss_newton(z, grid, anchors, target, start, cfg, again, iterations, _BACKTRACK, tol_m, out)
    accept = 10 * tol_m + 0.25 * grid.cell
    _compass_search(z, grid, anchors, target, cfg, np.flatnonzero(out.going & (out.best_res >= accept)), out)
    unsettled = out.going.copy()  # the budget ended: settled where its best place is within acceptance
    for i in np.flatnonzero(out.going):
        st = out.best_st[i]
        if out.best_res[i] < accept and st is not None:
            out.places[int(i)] = (out.best_xy[i].copy(), st)
            unsettled[i] = False
    return SettledMany(out.places, unsettled)


class _Batch:
    """The state of :func:`settle_many`'s places: what each found, whether it is still going,
    the best place each reached."""

    def __init__(self, m: int) -> None:
        self.places: list[tuple[F64, TetherState] | None] = [None] * m
        self.going = np.ones(m, bool)  # neither settled nor refused yet
        self.best_res = np.full(m, math.inf)
        self.best_xy = np.zeros((m, 2))
        self.best_st: list[TetherState | None] = [None] * m


def _gauss_newton(z: ZMap, grid: MapGrid, anchors: F64, target: F64, guesses: F64, cfg: TetherConfig,
                  which: NDArray[np.intp], iterations: int, backtrack: int, tol_m: float, out: _Batch) -> None:
    """``iterations`` batched Gauss-Newton steps of the places ``which`` from their guesses
    (:func:`settle_many`), each step halved at most ``backtrack`` times until the residual
    shrinks (0: whole steps, a pass whose places that leave the known ground or meet a singular
    Jacobian are left going, for the backtracking pass to decide); records in ``out``."""
    xy = guesses.copy()
    h = grid.cell
    probes = np.array([[0.0, 0.0], [h, 0.0], [-h, 0.0], [0.0, h], [0.0, -h]])
    active = np.asarray(which, np.intp)
    whole = backtrack == 0
    for it in range(iterations + 1):
        if not len(active):
            return
        states = tether_states(z, grid, anchors, (xy[active, None, :] + probes).reshape(-1, 2), cfg)
        lens = _lengths_of(states).reshape(len(active), 5, 2)
        on = np.isfinite(lens).all(axis=(1, 2))
        out.going[active[~on]] = not whole  # off the known ground: None, as settle's
        centre = [states[5 * j] for j in np.flatnonzero(on)]
        active, lens = active[on], lens[on]
        r = lens[:, 0] - target[active]
        worst = np.max(np.abs(r), axis=1)
        for j in np.flatnonzero(worst < out.best_res[active]):
            i = int(active[j])
            out.best_res[i], out.best_xy[i], out.best_st[i] = worst[j], xy[i].copy(), centre[j]
        done = worst < tol_m
        for j in np.flatnonzero(done):
            st = centre[j]
            if st is not None:  # its lengths are finite: it has a state
                out.places[int(active[j])] = (xy[active[j]].copy(), st)
        out.going[active[done]] = False
        if it == iterations:
            return
        active, lens, r = active[~done], lens[~done], r[~done]
        jac = np.stack([lens[:, 1] - lens[:, 2], lens[:, 3] - lens[:, 4]], axis=2) / (2 * h)  # dL_i/dx_k
        singular = np.abs(np.linalg.det(jac)) < 1e-9
        out.going[active[singular]] = not whole  # None, as settle's
        active, jac, r = active[~singular], jac[~singular], r[~singular]
        if not len(active):
            return
        step = np.linalg.solve(jac, r[:, :, None])[:, :, 0]
        n = np.linalg.norm(step, axis=1)
        step *= np.where(n > 0.5, 0.5 / np.maximum(n, 1e-300), 1.0)[:, None]  # damped as settle's steps
        if backtrack:
            step, stuck = _backtracked(z, grid, anchors, xy[active], step, target[active], r, cfg, backtrack)
            xy[active] -= step
            active = active[~stuck]  # no step shrinks its residual: left going, judged at its best place
        else:
            xy[active] -= step


def _compass_search(z: ZMap, grid: MapGrid, anchors: F64, target: F64, cfg: TetherConfig,
                    which: NDArray[np.intp], out: _Batch) -> None:
    """The search :func:`settle` makes where Gauss-Newton stalls (its Nelder-Mead on the largest
    length residual), batched and bounded: from the best place each of ``which`` reached, eight
    compass points at each radius of ``SEARCH_RADII`` (twice each), one :func:`tether_states`
    batch per move for all of them, each place moving to its best point when that lowers its
    residual; records the best place in ``out``."""
    active = np.asarray(which, np.intp)
    for radius in SEARCH_RADII:
        for _ in range(2):
            if not len(active):
                return
            pts = out.best_xy[active, None, :] + radius * grid.cell * _COMPASS
            states = tether_states(z, grid, anchors, pts.reshape(-1, 2), cfg)
            worst = np.max(np.abs(_lengths_of(states).reshape(len(active), 8, 2) - target[active, None, :]), axis=2)
            worst = np.where(np.isfinite(worst), worst, np.inf)
            pick = np.argmin(worst, axis=1)
            for j in np.flatnonzero(worst[np.arange(len(active)), pick] < out.best_res[active]):
                i, k = int(active[j]), int(pick[j])
                out.best_res[i], out.best_xy[i], out.best_st[i] = worst[j, k], pts[j, k].copy(), states[8 * j + k]


def _lengths_of(states: list[TetherState | None]) -> F64:
    """Both lengths of each state (N, 2), NaN where there is none."""
    out = np.full((len(states), 2), np.nan)
    for k, s in enumerate(states):
        if s is not None:
            out[k] = s.lengths_m
    return out


def _backtracked(z: ZMap, grid: MapGrid, anchors: F64, xy: F64, step: F64, target: F64, r: F64,
                 cfg: TetherConfig, halvings: int) -> tuple[F64, NDArray[np.bool_]]:
    """Each place's step, halved until the residual at ``xy - step`` shrinks (one batch per
    halving, of the places still halving; :func:`settle`'s backtracking, batched), and whether
    none of the ``halvings`` trials shrank it (the place is stuck: :func:`settle` would step on
    by the last halved step, find the same step from there and stall until its budget ends)."""
    step = step.copy()
    r_norm = np.linalg.norm(r, axis=1)
    halving = np.arange(len(xy))
    for _ in range(halvings):
        trial = _lengths_of(tether_states(z, grid, anchors, xy[halving] - step[halving], cfg))
        shrank = np.isfinite(trial).all(axis=1) & (np.linalg.norm(trial - target[halving], axis=1) < r_norm[halving])
        halving = halving[~shrank]
        if not len(halving):
            break
        step[halving] *= 0.5
    stuck = np.zeros(len(xy), bool)
    stuck[halving] = True
    return step, stuck
